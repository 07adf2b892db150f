//! `ivp bench train|infer`: the time of one training step and of one inference on random inputs,
//! the same cases as `shared/bench/torch_reference.py`, printed with the same JSON keys so that the
//! two can be compared line by line.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use anyhow::Result;
use candle_core::{Device, Tensor};
use ivp_core::nn::loss::LossWeights;
use ivp_core::nn::model::{named_parameters, IvpNet, ModelConfig, NetInput, Variant};
use ivp_core::nn::ops::profile;
use ivp_core::nn::optim::{Adam, AdamConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::Serialize;

use crate::distributed::SingleProcess;
use crate::guide::Guide;
use crate::machine::Machine;
use crate::train::training_step;

/// One benchmark's result: the keys of `torch_reference.py`, plus where the time went.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub case: String,
    pub median_ms: f64,
    pub min_ms: f64,
    pub runs: usize,
    pub threads: usize,
    /// The CPU the times were measured on.
    pub machine: Machine,
    pub width_mult: f64,
    pub ivp: &'static str,
    /// Milliseconds per run by operator (ivp's own operators; "other" is everything else), when
    /// profiling was asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub profile: Option<BTreeMap<String, f64>>,
}

/// The training-step case: forward, sampler, losses, backward and Adam at a batch of `batch`
/// crops of `crop` x `crop`.
#[derive(Clone, Copy, Debug)]
pub struct TrainCase {
    pub batch: usize,
    pub crop: usize,
    pub runs: usize,
    pub width_mult: f64,
    pub profile: bool,
}

/// The inference case: one dense forward pass and sampling at `height` x `width`, padded to a
/// multiple of 16 as the reference does.
#[derive(Clone, Copy, Debug)]
pub struct InferCase {
    pub height: usize,
    pub width: usize,
    pub runs: usize,
    pub width_mult: f64,
    pub profile: bool,
}

/// Random inputs distributed as the reference's: prior ~ 3 N(0, 1), depth ~ U(0, 10), holes with
/// probability `hole_fraction`, warped ~ U(0, 1) outside the holes, ground truth ~ U(0, 1).
struct RandomInputs {
    prior: Tensor,
    depth: Tensor,
    mask: Tensor,
    warped: Tensor,
    truth: Tensor,
}

impl RandomInputs {
    fn new(b: usize, h: usize, w: usize, hole_fraction: f64, seed: u64) -> Result<Self> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let n = b * h * w;
        let prior: Vec<f32> = (0..2 * n).map(|_| 3.0 * rng.sample::<f32, _>(StandardNormal)).collect();
        let depth: Vec<f32> = (0..n).map(|_| rng.random_range(0.0..10.0)).collect();
        let mask: Vec<f32> = (0..n).map(|_| f32::from(rng.random_bool(hole_fraction))).collect();
        let mut warped: Vec<f32> = (0..3 * n).map(|_| rng.random_range(0.0..1.0)).collect();
        for (i, v) in warped.iter_mut().enumerate() {
            let (img, px) = (i / (3 * h * w), i % (h * w));
            *v *= 1.0 - mask[img * h * w + px];
        }
        let truth: Vec<f32> = (0..3 * n).map(|_| rng.random_range(0.0..1.0)).collect();
        let t = |v: Vec<f32>, c: usize| Tensor::from_vec(v, (b, c, h, w), &Device::Cpu);
        Ok(Self {
            prior: t(prior, 2)?,
            depth: t(depth, 1)?,
            mask: t(mask, 1)?,
            warped: t(warped, 3)?,
            truth: t(truth, 3)?,
        })
    }

    fn net_input(&self) -> NetInput<'_> {
        NetInput {
            prior: &self.prior,
            warped_depth: &self.depth,
            mask: &self.mask,
            warped: &self.warped,
            last: None,
            last_warped: None,
        }
    }
}

pub fn bench_train(case: &TrainCase) -> Result<BenchReport> {
    let config = ModelConfig::new(Variant::Full, case.width_mult);
    let (net, varmap) = IvpNet::seeded(config, 0)?;
    let mut optimizer = Adam::new(named_parameters(&varmap), AdamConfig::default())?;
    let inputs = RandomInputs::new(case.batch, case.crop, case.crop, 0.1, 0)?;
    let weights = LossWeights::default();
    let (times, profile) = timed_runs(2, case.runs, case.profile, || {
        training_step(&net, &mut optimizer, &inputs.net_input(), &inputs.truth, &weights, Guide::NONE, &SingleProcess)?;
        Ok(())
    })?;
    Ok(report(format!("train b{} crop{}", case.batch, case.crop), &times, case.width_mult, profile))
}

pub fn bench_infer(case: &InferCase) -> Result<BenchReport> {
    let config = ModelConfig::new(Variant::Full, case.width_mult);
    // As PyTorch's `no_grad`: no graph is recorded.
    let net = IvpNet::seeded(config, 0)?.0.detached();
    let (ph, pw) = (case.height.div_ceil(16) * 16, case.width.div_ceil(16) * 16);
    let inputs = RandomInputs::new(1, ph, pw, 0.05, 0)?;
    let (times, profile) = timed_runs(1, case.runs, case.profile, || {
        net.forward(&inputs.net_input())?;
        Ok(())
    })?;
    let case_name = format!("infer {}x{} (padded {ph}x{pw}), dense", case.height, case.width);
    Ok(report(case_name, &times, case.width_mult, profile))
}

/// Milliseconds per run by operator.
pub(crate) type OperatorTimes = BTreeMap<String, f64>;

/// Runs `f` `warmup` times, then `runs` times under the clock (and the operator profile if asked).
fn timed_runs(
    warmup: usize,
    runs: usize,
    with_profile: bool,
    mut f: impl FnMut() -> Result<()>,
) -> Result<(Vec<Duration>, Option<OperatorTimes>)> {
    for _ in 0..warmup {
        f()?;
    }
    profile::set_enabled(with_profile);
    profile::take();
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        f()?;
        times.push(start.elapsed());
    }
    profile::set_enabled(false);
    let operators = profile::take();
    let breakdown = with_profile.then(|| operator_breakdown(&operators, &times));
    Ok((times, breakdown))
}

/// Milliseconds per run of each operator recorded over `times`, and `other`: the rest of the
/// runs' time.
pub(crate) fn operator_breakdown(
    operators: &BTreeMap<&'static str, profile::OperatorTime>,
    times: &[Duration],
) -> OperatorTimes {
    let per_run = |d: Duration| d.as_secs_f64() * 1e3 / times.len().max(1) as f64;
    let mut ms: OperatorTimes = operators.iter().map(|(k, v)| (k.to_string(), per_run(v.total))).collect();
    let listed: f64 = ms.values().sum();
    ms.insert("other".into(), per_run(times.iter().sum()) - listed);
    ms
}

fn report(case: String, times: &[Duration], width_mult: f64, profile: Option<BTreeMap<String, f64>>) -> BenchReport {
    let mut ms: Vec<f64> = times.iter().map(|t| t.as_secs_f64() * 1e3).collect();
    ms.sort_by(f64::total_cmp);
    let median = if ms.len() % 2 == 1 { ms[ms.len() / 2] } else { (ms[ms.len() / 2 - 1] + ms[ms.len() / 2]) / 2.0 };
    let round = |x: f64| (x * 10.0).round() / 10.0;
    BenchReport {
        case,
        median_ms: round(median),
        min_ms: round(ms[0]),
        runs: ms.len(),
        threads: rayon::current_num_threads(),
        machine: Machine::this(),
        width_mult,
        ivp: env!("CARGO_PKG_VERSION"),
        profile: profile.map(|p| p.into_iter().map(|(k, v)| (k, round(v))).collect()),
    }
}
