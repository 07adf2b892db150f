//! Data-parallel training over several processes (ranks): the [`ProcessGroup`] that the training
//! loop talks to, and the few collective operations it needs, built on it.
//!
//! Every rank holds the whole network and Adam's state. The batch of step `s` is still a pure
//! function of `(seed, s)`; rank `r` of `n` makes only its part of it ([`batch_part`]: contiguous
//! samples, in rank order). Each rank divides its part's loss terms by the counts of the whole
//! batch (disocclusion pixels, pairs of them, guided pixels: [`sum_over_ranks`] of each rank's
//! counts), so that the parts' losses and gradients add up to the whole batch's. The gradients are
//! summed by a ring all-reduce that adds in a fixed order ([`all_reduce_sum`]), and every rank
//! applies the same Adam step to the same parameters. So a run is deterministic for a given number
//! of ranks, and differs from a one-rank run of the same global batch only by the order of
//! floating-point sums.
//!
//! One process is [`SingleProcess`], for which every operation here returns at once without
//! touching the data: training without MPI computes exactly what it computed before data
//! parallelism existed. With the `mpi` feature, `MpiGroup` (in `distributed/mpi_group.rs`) is a
//! job started by `mpirun`, `mpiexec` or `srun`.

use std::ops::Range;
use std::time::Duration;

use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};
use ivp_core::nn::optim::Adam;

#[cfg(feature = "mpi")]
mod mpi_group;
#[cfg(feature = "mpi")]
pub use mpi_group::MpiGroup;

/// The ranks of a training job, as one of them sees them. Every rank calls the operations in the
/// same order with buffers of the same lengths (collective operations, as MPI's).
pub trait ProcessGroup {
    /// This process's number, `0 .. size()`; rank 0 reads and writes the run folder.
    fn rank(&self) -> usize;
    /// The number of processes.
    fn size(&self) -> usize;
    /// Sends `send` to rank `to` while receiving `receive.len()` values from rank `from`: one
    /// exchange of the ring all-reduce (every rank calls it at once, without deadlock).
    fn send_receive(&self, send: &[f32], to: usize, receive: &mut [f32], from: usize);
    /// Every rank's `values` (of one length on every rank), concatenated in rank order, on every rank.
    fn all_gather(&self, values: &[f64]) -> Vec<f64>;
    /// Rank 0's `bytes` on every rank (of one length on every rank).
    fn broadcast(&self, bytes: &mut [u8]);
    /// Time spent in the operations above so far, waiting for the other ranks included.
    fn time_spent(&self) -> TimeSpent {
        TimeSpent::default()
    }
}

/// Where a rank's time in exchanges went.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TimeSpent {
    /// In [`ProcessGroup::send_receive`]: the gradient all-reduce, waiting for a rank that is
    /// still in its backward pass included.
    pub all_reduce: Duration,
    /// In the other operations: small sums, flags, validation scores, the state at the start,
    /// waiting for slower ranks included (a step's first exchange absorbs its data's delays).
    pub other: Duration,
}

/// A job of one process: nothing to exchange.
#[derive(Clone, Copy, Debug, Default)]
pub struct SingleProcess;

impl ProcessGroup for SingleProcess {
    fn rank(&self) -> usize {
        0
    }

    fn size(&self) -> usize {
        1
    }

    fn send_receive(&self, send: &[f32], _to: usize, receive: &mut [f32], _from: usize) {
        receive.copy_from_slice(send);
    }

    fn all_gather(&self, values: &[f64]) -> Vec<f64> {
        values.to_vec()
    }

    fn broadcast(&self, _bytes: &mut [u8]) {}
}

#[derive(Debug, thiserror::Error)]
pub enum DistributedError {
    #[error(
        "--batch {batch} cannot be split over {ranks} ranks: it is the global batch of a step, and every rank \
         needs at least one sample of it"
    )]
    BatchTooSmall { batch: usize, ranks: usize },
    #[error("MPI: {0}")]
    Mpi(String),
    #[error(transparent)]
    Tensor(#[from] candle_core::Error),
}

/// Items `0 .. total` split over `size` ranks: rank `rank`'s contiguous part, in rank order, the
/// first `total % size` ranks taking one more than the others.
pub fn even_part(total: usize, rank: usize, size: usize) -> Range<usize> {
    let (base, extra) = (total / size, total % size);
    let start = rank * base + rank.min(extra);
    start..start + base + usize::from(rank < extra)
}

/// The samples of a global batch of `batch` that this rank makes and trains on.
pub fn batch_part(batch: usize, group: &dyn ProcessGroup) -> Result<Range<usize>, DistributedError> {
    if batch < group.size() {
        return Err(DistributedError::BatchTooSmall { batch, ranks: group.size() });
    }
    Ok(even_part(batch, group.rank(), group.size()))
}

/// Element-wise sums of every rank's `values`, added in rank order: the same bits on every rank.
pub fn sum_over_ranks(group: &dyn ProcessGroup, values: &[f64]) -> Vec<f64> {
    if group.size() == 1 {
        return values.to_vec();
    }
    let all = group.all_gather(values);
    let mut ranks = all.chunks_exact(values.len());
    let mut sums = ranks.next().expect("rank 0's values").to_vec();
    for rank in ranks {
        sums.iter_mut().zip(rank).for_each(|(s, v)| *s += v);
    }
    sums
}

/// Whether `flag` is set on any rank (the same answer on every rank).
pub fn any_rank(group: &dyn ProcessGroup, flag: bool) -> bool {
    if group.size() == 1 {
        return flag;
    }
    group.all_gather(&[f64::from(u8::from(flag))]).iter().any(|&f| f != 0.0)
}

/// Sums `buffer` over the ranks in place, with the same bits on every rank: a ring all-reduce.
///
/// The buffer is cut into one chunk per rank. Reduce-scatter: chunk `c` starts at rank `c` and
/// travels once round the ring, each rank adding its own values to the partial sum it receives,
/// so after `n - 1` exchanges rank `r` holds chunk `r + 1` summed in the fixed order
/// `((x_c + x_{c+1}) + x_{c+2}) + ...`. All-gather: the summed chunks travel round the ring again
/// and are copied as they are. Each rank sends and receives `2 (n - 1) / n` times the buffer,
/// whatever `n` (bandwidth-optimal), in `2 (n - 1)` exchanges with its two neighbours.
pub fn all_reduce_sum(group: &dyn ProcessGroup, buffer: &mut [f32]) {
    let (n, rank) = (group.size(), group.rank());
    if n == 1 {
        return;
    }
    let len = buffer.len();
    let chunk = |c: usize| even_part(len, c % n, n);
    let (next, previous) = ((rank + 1) % n, (rank + n - 1) % n);
    let mut received = vec![0f32; chunk(0).len()];
    for k in 0..n - 1 {
        let (send, receive) = (chunk(rank + n - k), chunk(rank + 2 * n - k - 1));
        let received = &mut received[..receive.len()];
        group.send_receive(&buffer[send], next, received, previous);
        buffer[receive].iter_mut().zip(received.iter()).for_each(|(x, partial)| *x += partial);
    }
    for k in 0..n - 1 {
        let (send, receive) = (chunk(rank + 1 + n - k), chunk(rank + n - k));
        let received = &mut received[..receive.len()];
        group.send_receive(&buffer[send], next, received, previous);
        buffer[receive].copy_from_slice(received);
    }
}

/// Replaces the gradients of `params` in `grads` by their sums over the ranks: the gradient of
/// the whole batch's loss, when each rank's loss is its part of it. All of them travel in one
/// buffer (one all-reduce a step), in the order of `params` (the same on every rank); parameters
/// without a gradient have none on any rank (every rank runs the same network).
pub fn sum_gradients(
    group: &dyn ProcessGroup,
    grads: &mut GradStore,
    params: &[(String, Var)],
) -> Result<(), DistributedError> {
    if group.size() == 1 {
        return Ok(());
    }
    let with_gradient: Vec<(&Var, Tensor)> =
        params.iter().filter_map(|(_, var)| grads.get(var.as_tensor()).map(|g| (var, g.clone()))).collect();
    let mut buffer = Vec::with_capacity(with_gradient.iter().map(|(_, g)| g.elem_count()).sum());
    for (_, g) in &with_gradient {
        buffer.extend(g.flatten_all()?.to_vec1::<f32>()?);
    }
    all_reduce_sum(group, &mut buffer);
    let mut offset = 0;
    for (var, g) in with_gradient {
        let n = g.elem_count();
        let summed = Tensor::from_slice(&buffer[offset..offset + n], g.shape(), g.device())?;
        grads.insert(var.as_tensor(), summed);
        offset += n;
    }
    Ok(())
}

/// Rank 0's `bytes` (given on rank 0 alone) on every rank, whatever their length.
pub fn broadcast_from_root(group: &dyn ProcessGroup, bytes: Option<Vec<u8>>) -> Vec<u8> {
    let mut bytes = bytes.unwrap_or_default();
    if group.size() == 1 {
        return bytes;
    }
    let mut length = (bytes.len() as u64).to_le_bytes();
    group.broadcast(&mut length);
    bytes.resize(u64::from_le_bytes(length) as usize, 0);
    group.broadcast(&mut bytes);
    bytes
}

/// The values of f32 tensors, one after the other, as little-endian bytes: what ranks exchange.
pub fn f32_bytes(tensors: &[Tensor]) -> candle_core::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    for t in tensors {
        bytes.extend(t.flatten_all()?.to_vec1::<f32>()?.iter().flat_map(|v| v.to_le_bytes()));
    }
    Ok(bytes)
}

/// The next tensor of [`f32_bytes`]'s output, shaped like `like`; `bytes` moves past it.
pub fn tensor_from_f32_bytes(bytes: &mut &[u8], like: &Tensor) -> candle_core::Result<Tensor> {
    let (head, rest) = bytes.split_at(4 * like.elem_count());
    *bytes = rest;
    let floats: Vec<f32> = head.chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes"))).collect();
    Tensor::from_vec(floats, like.shape(), like.device())
}

/// Gives every rank rank 0's parameters, Adam state and `step` (the step the run starts at), and
/// returns that step: rank 0 alone reads the run folder (a fresh run or a checkpoint), the others
/// start from exactly its state.
pub fn share_training_state(
    group: &dyn ProcessGroup,
    optimizer: &mut Adam,
    step: u64,
) -> Result<u64, DistributedError> {
    if group.size() == 1 {
        return Ok(step);
    }
    let (moments, adam_steps) = optimizer.state();
    let moment = |kind: &str, name: &str| moments[&format!("adam.{kind}.{name}")].clone();
    let tensors: Vec<Tensor> = optimizer
        .parameters()
        .iter()
        .flat_map(|(name, var)| [var.as_tensor().clone(), moment("m", name), moment("v", name)])
        .collect();
    let mut bytes = f32_bytes(&tensors)?;
    bytes.extend(adam_steps.to_le_bytes());
    bytes.extend(step.to_le_bytes());
    group.broadcast(&mut bytes);
    if group.rank() == 0 {
        return Ok(step);
    }

    let (mut values, counters) = bytes.split_at(bytes.len() - 16);
    let mut received = std::collections::HashMap::new();
    for (name, var) in optimizer.parameters() {
        var.set(&tensor_from_f32_bytes(&mut values, var.as_tensor())?)?;
        received.insert(format!("adam.m.{name}"), tensor_from_f32_bytes(&mut values, var.as_tensor())?);
        received.insert(format!("adam.v.{name}"), tensor_from_f32_bytes(&mut values, var.as_tensor())?);
    }
    let counter = |i: usize| u64::from_le_bytes(counters[8 * i..8 * i + 8].try_into().expect("8 bytes"));
    optimizer.load_state(&received, counter(0))?;
    Ok(counter(1))
}

#[cfg(test)]
pub(crate) mod tests {
    use std::sync::mpsc::{channel, Receiver, Sender};

    use candle_core::Device;
    use ivp_core::nn::optim::AdamConfig;

    use super::*;

    /// `size` ranks as threads of one process, exchanging over channels: the collective operations
    /// tested without MPI.
    pub(crate) struct ThreadGroup {
        rank: usize,
        /// To each rank (itself included).
        to: Vec<Sender<Vec<u8>>>,
        /// From each rank.
        from: Vec<Receiver<Vec<u8>>>,
    }

    impl ThreadGroup {
        pub(crate) fn new(size: usize) -> Vec<ThreadGroup> {
            let mut to: Vec<Vec<Sender<Vec<u8>>>> = (0..size).map(|_| Vec::new()).collect();
            let mut from: Vec<Vec<Receiver<Vec<u8>>>> = (0..size).map(|_| Vec::new()).collect();
            for sends in to.iter_mut() {
                for receives in from.iter_mut() {
                    let (tx, rx) = channel();
                    sends.push(tx);
                    receives.push(rx);
                }
            }
            to.into_iter().zip(from).enumerate().map(|(rank, (to, from))| ThreadGroup { rank, to, from }).collect()
        }

        /// Runs `work` on every rank, each in its own thread; the results in rank order.
        pub(crate) fn run<T: Send>(size: usize, work: impl Fn(&ThreadGroup) -> T + Sync) -> Vec<T> {
            std::thread::scope(|scope| {
                let work = &work;
                let handles: Vec<_> =
                    ThreadGroup::new(size).into_iter().map(|group| scope.spawn(move || work(&group))).collect();
                handles.into_iter().map(|h| h.join().expect("a rank panicked")).collect()
            })
        }

        fn send(&self, to: usize, bytes: Vec<u8>) {
            self.to[to].send(bytes).expect("the receiving rank is gone");
        }

        fn receive(&self, from: usize) -> Vec<u8> {
            self.from[from].recv().expect("the sending rank is gone")
        }
    }

    impl ProcessGroup for ThreadGroup {
        fn rank(&self) -> usize {
            self.rank
        }

        fn size(&self) -> usize {
            self.to.len()
        }

        fn send_receive(&self, send: &[f32], to: usize, receive: &mut [f32], from: usize) {
            self.send(to, send.iter().flat_map(|v| v.to_le_bytes()).collect());
            let bytes = self.receive(from);
            assert_eq!(bytes.len(), 4 * receive.len(), "message of another length than expected");
            for (r, b) in receive.iter_mut().zip(bytes.chunks_exact(4)) {
                *r = f32::from_le_bytes(b.try_into().unwrap());
            }
        }

        fn all_gather(&self, values: &[f64]) -> Vec<f64> {
            let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            for to in 0..self.size() {
                self.send(to, bytes.clone());
            }
            (0..self.size())
                .flat_map(|from| self.receive(from))
                .collect::<Vec<u8>>()
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().unwrap()))
                .collect()
        }

        fn broadcast(&self, bytes: &mut [u8]) {
            if self.rank == 0 {
                for to in 1..self.size() {
                    self.send(to, bytes.to_vec());
                }
            } else {
                bytes.copy_from_slice(&self.receive(0));
            }
        }
    }

    #[test]
    fn even_parts_cover_everything_once_in_rank_order() {
        for (total, size) in [(16, 2), (16, 3), (5, 5), (7, 4), (0, 3), (1, 1)] {
            let parts: Vec<Range<usize>> = (0..size).map(|r| even_part(total, r, size)).collect();
            assert_eq!(parts.iter().flat_map(|p| p.clone()).collect::<Vec<_>>(), (0..total).collect::<Vec<_>>());
            let lengths: Vec<usize> = parts.iter().map(|p| p.len()).collect();
            assert!(lengths.iter().max().unwrap() - lengths.iter().min().unwrap() <= 1, "{lengths:?}");
        }
        let ranks = ThreadGroup::new(3);
        assert!(matches!(batch_part(2, &ranks[0]), Err(DistributedError::BatchTooSmall { batch: 2, ranks: 3 })));
    }

    #[test]
    fn the_ring_sums_in_a_fixed_order_with_the_same_bits_on_every_rank() {
        // Values of very different magnitudes, so that the order of the additions shows in the bits.
        let values = |rank: usize, len: usize| -> Vec<f32> {
            (0..len)
                .map(|i| ((i * 7 + rank * 13) % 11) as f32 * 10f32.powi((rank as i32 * 3 + i as i32) % 9 - 4))
                .collect()
        };
        for size in [2, 3, 4, 5] {
            for len in [1, size - 1, size, 17, 1000] {
                let sums = ThreadGroup::run(size, |group| {
                    let mut buffer = values(group.rank(), len);
                    all_reduce_sum(group, &mut buffer);
                    buffer
                });
                assert!(sums.iter().all(|s| s == &sums[0]), "ranks differ: {size} ranks, {len} values");
                // Chunk c of the ring is added in the order c, c + 1, ..., c + n - 1.
                let expected: Vec<f32> = (0..len)
                    .map(|i| {
                        let c = (0..size).find(|&c| even_part(len, c, size).contains(&i)).unwrap();
                        (1..size).fold(values(c, len)[i], |sum, k| sum + values((c + k) % size, len)[i])
                    })
                    .collect();
                assert_eq!(sums[0], expected, "{size} ranks, {len} values");
            }
        }
    }

    #[test]
    fn small_sums_and_flags_agree_on_every_rank() {
        let results = ThreadGroup::run(3, |group| {
            let r = group.rank() as f64;
            (sum_over_ranks(group, &[r, 1.0, -0.0]), any_rank(group, group.rank() == 2), any_rank(group, false))
        });
        for (sums, any, none) in results {
            assert_eq!(sums, vec![3.0, 3.0, 0.0]);
            assert!(any && !none);
        }
        assert_eq!(sum_over_ranks(&SingleProcess, &[-0.0]), vec![-0.0], "one rank's values are returned as they are");
        let texts =
            ThreadGroup::run(3, |group| broadcast_from_root(group, (group.rank() == 0).then(|| b"rank 0".to_vec())));
        assert!(texts.iter().all(|t| t == b"rank 0"));
    }

    #[test]
    fn every_rank_starts_from_rank_0s_state() {
        let states = ThreadGroup::run(3, |group| {
            // Each rank starts from other values; rank 0's count as the run's.
            let r = group.rank() as f32;
            let var = |name: &str, v: Vec<f32>| (name.to_string(), Var::from_vec(v, 2, &Device::Cpu).unwrap());
            let params = [var("a", vec![r, 2.0 * r]), var("b", vec![1.0 + r, -r])];
            let mut adam = Adam::new(params.clone(), AdamConfig::default()).unwrap();
            let grads = (params[0].1.as_tensor().sqr().unwrap().sum_all().unwrap()
                + (params[1].1.as_tensor() * 3.0).unwrap().sum_all().unwrap())
            .unwrap()
            .backward()
            .unwrap();
            for _ in 0..=group.rank() {
                adam.step(&grads).unwrap();
            }
            let step = share_training_state(group, &mut adam, 40 + group.rank() as u64).unwrap();
            let (moments, adam_steps) = adam.state();
            let mut moments: Vec<(String, Vec<f32>)> =
                moments.into_iter().map(|(k, t)| (k, t.to_vec1().unwrap())).collect();
            moments.sort_by(|a, b| a.0.cmp(&b.0));
            let values: Vec<Vec<f32>> = params.iter().map(|(_, v)| v.as_tensor().to_vec1().unwrap()).collect();
            (step, adam_steps, values, moments)
        });
        assert!(states.iter().all(|s| s == &states[0]), "{states:?}");
        assert_eq!((states[0].0, states[0].1), (40, 1));
    }
}
