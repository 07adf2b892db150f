//! The all-reduce of one training step, timed alone (feature `mpi`; numbers in SCALING.md):
//!
//! ```sh
//! cargo build --release -p ivp-train --features mpi --example allreduce
//! mpirun -np 2 target/release/examples/allreduce [WIDTH_MULT ...] [--repeats 30]
//! ```
//!
//! For each width multiplier, sums a buffer of the network's parameter count over the ranks with
//! ivp's fixed-order ring ([`all_reduce_sum`], what training runs every step) and, for comparison,
//! with the MPI library's own `MPI_Allreduce` (whose algorithm depends on the message size and
//! promises no fixed order). Rank 0 prints the time per call (median, min, max over the repeats).

use std::time::Instant;

use ivp_core::nn::model::{named_parameters, IvpNet, ModelConfig, Variant};
use ivp_train::distributed::{all_reduce_sum, MpiGroup, ProcessGroup};
use mpi::collective::SystemOperation;
use mpi::topology::SimpleCommunicator;
use mpi::traits::CommunicatorCollectives;

fn main() -> anyhow::Result<()> {
    let group = MpiGroup::join()?.ok_or_else(|| anyhow::anyhow!("start it with mpirun or srun"))?;
    let world = SimpleCommunicator::world();
    let mut repeats = 30;
    let mut widths = Vec::new();
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        match arg.as_str() {
            "--repeats" => repeats = args.next().unwrap_or_default().parse()?,
            w => widths.push(w.parse::<f64>()?),
        }
    }
    if widths.is_empty() {
        widths = vec![0.25, 1.0];
    }
    if group.rank() == 0 {
        println!("{} ranks, {repeats} repeats; milliseconds per all-reduce: median (min - max)", group.size());
        println!("| width | parameters | message | ring (ivp) | MPI_Allreduce |");
        println!("|---|---|---|---|---|");
    }
    for width_mult in widths {
        let (_, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, width_mult), 0)?;
        let count: usize = named_parameters(&varmap).iter().map(|(_, v)| v.elem_count()).sum();
        let values: Vec<f32> = (0..count).map(|i| (i % 1000) as f32 * 1e-3).collect();
        let time = |reduce: &dyn Fn(&mut Vec<f32>)| -> (f64, f64, f64) {
            let mut times: Vec<f64> = (0..repeats + 1)
                .map(|_| {
                    let mut buffer = values.clone();
                    world.barrier();
                    let start = Instant::now();
                    reduce(&mut buffer);
                    1e3 * start.elapsed().as_secs_f64()
                })
                .skip(1) // the first call sets up connections
                .collect();
            times.sort_by(f64::total_cmp);
            (times[times.len() / 2], times[0], times[times.len() - 1])
        };
        let ring = time(&|buffer| all_reduce_sum(&group, buffer));
        let library = time(&|buffer| {
            let mut sum = vec![0f32; buffer.len()];
            world.all_reduce_into(&buffer[..], &mut sum[..], SystemOperation::sum());
            *buffer = sum;
        });
        if group.rank() == 0 {
            let show = |(median, min, max): (f64, f64, f64)| format!("{median:.2} ({min:.2} - {max:.2})");
            println!(
                "| {width_mult} | {count} | {:.2} MB | {} | {} |",
                4.0 * count as f64 / 1e6,
                show(ring),
                show(library)
            );
        }
    }
    Ok(())
}
