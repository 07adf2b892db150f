//! The ranks of an MPI job (feature `mpi`): `mpirun -np N ivp train ...`, `srun ivp train ...`.

use std::cell::Cell;
use std::time::{Duration, Instant};

use ::mpi::environment::Universe;
use ::mpi::point_to_point::send_receive_into;
use ::mpi::topology::SimpleCommunicator;
use ::mpi::traits::{Communicator, CommunicatorCollectives, Root};
use ::mpi::Threading;

use super::{DistributedError, ProcessGroup, TimeSpent};

/// Variables that MPI launchers set in the processes they start: Open MPI's `mpirun`, MPICH's and
/// Intel MPI's Hydra (`mpiexec`), Slurm's `srun` with PMI-2 or PMIx.
const LAUNCHER_VARIABLES: [&str; 4] = ["OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE"];

/// `MPI_COMM_WORLD` of the job this process was started in.
pub struct MpiGroup {
    world: SimpleCommunicator,
    /// Finalises MPI when dropped, after `world` (fields drop in order).
    _universe: Universe,
    spent: Cell<TimeSpent>,
}

impl MpiGroup {
    /// Joins the job this process was launched into; `None` when no MPI launcher started it, so
    /// that a plain `ivp train` stays a single process and never initialises MPI.
    pub fn join() -> Result<Option<Self>, DistributedError> {
        if !LAUNCHER_VARIABLES.iter().any(|v| std::env::var_os(v).is_some()) {
            // srun without an MPI plugin starts every task as a job of its own: each would train
            // the whole run into the same folder.
            let tasks = std::env::var("SLURM_STEP_NUM_TASKS").ok().and_then(|n| n.parse::<usize>().ok());
            if let Some(n @ 2..) = tasks {
                return Err(DistributedError::Mpi(format!(
                    "srun started {n} tasks without MPI's process management: run `srun --mpi=pmix` (or pmi2), or \
                     mpirun inside the allocation"
                )));
            }
            return Ok(None);
        }
        // Only the main thread calls MPI; the sample workers and rayon's threads never do.
        let (universe, threading) = ::mpi::initialize_with_threading(Threading::Funneled)
            .ok_or_else(|| DistributedError::Mpi("MPI is initialised already".into()))?;
        if threading < Threading::Funneled {
            tracing::warn!(?threading, "the MPI library does not promise MPI_THREAD_FUNNELED");
        }
        let world = universe.world();
        Ok(Some(Self { world, _universe: universe, spent: Cell::default() }))
    }

    /// Sets rayon's global pool to this machine's cores shared among its ranks, unless the pool
    /// was set already (`--threads`). The cores are those this process may run on: Open MPI binds
    /// each rank to one core by default for 2 ranks, to a socket for more.
    pub fn share_cores_among_local_ranks(&self) {
        let local_ranks = self.world.split_shared(self.world.rank()).size().max(1) as usize;
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let threads = (cores / local_ranks).max(1);
        if rayon::ThreadPoolBuilder::new().num_threads(threads).build_global().is_ok() {
            tracing::info!(threads, local_ranks, cores, "threads per rank");
        }
    }

    /// Ends every process of the job at once: for a rank that cannot go on while the others may be
    /// waiting for it in a collective operation. The launcher reports which rank aborted.
    pub fn abort(&self, code: i32) -> ! {
        self.world.abort(code)
    }

    fn timed<T>(&self, slot: fn(&mut TimeSpent) -> &mut Duration, operation: impl FnOnce() -> T) -> T {
        let start = Instant::now();
        let result = operation();
        let mut spent = self.spent.get();
        *slot(&mut spent) += start.elapsed();
        self.spent.set(spent);
        result
    }
}

impl ProcessGroup for MpiGroup {
    fn rank(&self) -> usize {
        self.world.rank() as usize
    }

    fn size(&self) -> usize {
        self.world.size() as usize
    }

    fn send_receive(&self, send: &[f32], to: usize, receive: &mut [f32], from: usize) {
        let (to, from) = (self.world.process_at_rank(to as i32), self.world.process_at_rank(from as i32));
        self.timed(|t| &mut t.all_reduce, || send_receive_into(send, &to, receive, &from));
    }

    fn all_gather(&self, values: &[f64]) -> Vec<f64> {
        let mut all = vec![0.0; values.len() * self.size()];
        self.timed(|t| &mut t.other, || self.world.all_gather_into(values, &mut all[..]));
        all
    }

    fn broadcast(&self, bytes: &mut [u8]) {
        self.timed(|t| &mut t.other, || self.world.process_at_rank(0).broadcast_into(bytes));
    }

    fn time_spent(&self) -> TimeSpent {
        self.spent.get()
    }
}
