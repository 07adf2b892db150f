//! The evaluation harness: every method predicts the same targets of the same clips from the same
//! warps, and is scored as ALGORITHMS.md §7 says (8-bit predictions, D- metrics on disocclusions, TC).
//! Each scored target is handed to a [`FrameObserver`] (the HTML report keeps crops of it), so a
//! report shows the predictions and numbers scored here, not a second computation of them.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use indicatif::ProgressBar;
use ivp_core::geometry::FrameView;
use ivp_core::inference::{Coverage, ModelInfiller, PriorScale, Scale};
use ivp_core::infill::{classical_infiller, InfillContext, InfillRules, Infiller, CLASSICAL_METHODS};
use ivp_core::metrics::{score_frame, tc_track_variances, FrameScores, TcSequence};
use ivp_core::{relative_pose, warp_forward, RgbImage, VectorField, Warp};
use ivp_data::{find_clips, read_rgb, Clip, Frame};
use serde::Serialize;

use crate::checkpoint::load_model;
use crate::machine::Machine;
use crate::progress::progress_bar;

/// The targets of a 12-frame clip (ALGORITHMS.md §5).
pub const DEFAULT_TARGETS: [usize; 3] = [6, 8, 10];

/// The first frame that can be a target: target `t` is predicted from frames `t - 3 ..= t - 1`.
pub const FIRST_TARGET: usize = 3;

/// A method scored by the harness.
pub enum Method {
    /// Runs inside ivp.
    Internal(Box<dyn Infiller>),
    /// Frames predicted by another tool, read from `DIR/<clip name>/<t:04>.png`.
    External { name: String, dir: PathBuf },
}

impl Method {
    pub fn name(&self) -> &str {
        match self {
            Method::Internal(m) => m.name(),
            Method::External { name, .. } => name,
        }
    }
}

/// The methods of an evaluation as the command line names them.
pub struct MethodSpecs<'a> {
    /// Classical methods and `models` names, in the order of the table.
    pub names: &'a [String],
    /// Trained models: `NAME=FILE`, or `FILE` scored as `ivp`.
    pub models: &'a [String],
    /// Iterations of the models' test-time infilling (ALGORITHMS.md §6.5).
    pub iterations: usize,
    /// The rules around the models' passes (thin runs, far blur).
    pub rules: InfillRules,
    /// Frames predicted by another tool: `NAME=DIR`.
    pub externals: &'a [String],
    /// How the models cover a frame (sparse tiles, or dense).
    pub coverage: Coverage,
    /// The scale the models run at.
    pub scale: Scale,
    /// The scale the models' temporal prior is measured at.
    pub prior_scale: PriorScale,
}

/// The methods `specs` names: those of `names` in their order, then the models `names` leaves
/// out, then the external methods. Two methods of the same name would make the table ambiguous.
pub fn build_methods(specs: &MethodSpecs<'_>) -> Result<Vec<Method>> {
    let mut models = load_models(specs)?;
    let mut methods = Vec::new();
    for name in specs.names.iter().map(|m| m.trim()).filter(|m| !m.is_empty()) {
        methods.push(named_method(name, &mut models)?);
    }
    methods.extend(models.into_iter().map(|m| Method::Internal(Box::new(m))));
    for spec in specs.externals {
        methods.push(external_method(spec)?);
    }
    ensure_unique_names(&methods)?;
    Ok(methods)
}

/// The name and file of a `--model` argument: `NAME=FILE`, or `FILE` named `ivp`.
pub fn model_spec(spec: &str) -> (String, PathBuf) {
    match spec.split_once('=') {
        Some((name, file)) => (name.to_string(), PathBuf::from(file)),
        None => ("ivp".to_string(), PathBuf::from(spec)),
    }
}

fn load_models(specs: &MethodSpecs<'_>) -> Result<Vec<ModelInfiller>> {
    specs
        .models
        .iter()
        .map(|spec| {
            let (name, file) = model_spec(spec);
            ensure!(specs.iterations > 0, "--iterations must be at least 1");
            let (net, _) = load_model(&file)?;
            Ok(ModelInfiller::new(name, net, specs.iterations)
                .with_coverage(specs.coverage)
                .with_scale(specs.scale)
                .with_prior_scale(specs.prior_scale)
                .with_rules(specs.rules))
        })
        .collect()
}

/// A classical method, or the model of that name (taken out of `models`).
fn named_method(name: &str, models: &mut Vec<ModelInfiller>) -> Result<Method> {
    if let Some(m) = classical_infiller(name) {
        return Ok(Method::Internal(m));
    }
    if let Some(i) = models.iter().position(|m| m.name() == name) {
        return Ok(Method::Internal(Box::new(models.remove(i))));
    }
    if name == "ivp" {
        bail!("method `ivp` needs a trained model: add --model FILE");
    }
    bail!("unknown method `{name}`: choose among {} or a --model name", CLASSICAL_METHODS.join(", "))
}

fn external_method(spec: &str) -> Result<Method> {
    let Some((name, dir)) = spec.split_once('=') else {
        bail!("--external takes NAME=DIR, got `{spec}`");
    };
    let dir = PathBuf::from(dir);
    ensure!(dir.is_dir(), "--external {name}: {} is not a folder", dir.display());
    Ok(Method::External { name: name.to_string(), dir })
}

fn ensure_unique_names(methods: &[Method]) -> Result<()> {
    let mut names: Vec<&str> = methods.iter().map(|m| m.name()).collect();
    names.sort_unstable();
    if let Some(w) = names.windows(2).find(|w| w[0] == w[1]) {
        bail!("method `{}` is given twice", w[0]);
    }
    Ok(())
}

/// The scores of one method over a dataset.
#[derive(Clone, Debug, Serialize)]
pub struct MethodReport {
    #[serde(skip)]
    pub name: String,
    pub uses_ground_truth: bool,
    pub mse: f64,
    pub d_mse: Option<f64>,
    pub ssim: f64,
    pub d_ssim: Option<f64>,
    /// `None` when no track survived (ALGORITHMS.md §7).
    pub tc: Option<f64>,
    pub tc_tracks: usize,
    /// `None` for external methods: their time is not ours to measure. Warm: the run's first
    /// frame is warped and predicted once untimed before it is timed.
    pub ms_per_frame: Option<f64>,
    pub ms_by_stage: BTreeMap<String, f64>,
    pub frames: usize,
    pub d_frames: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct EvalReport {
    /// Clips evaluated, relative to the dataset folder.
    pub clips: Vec<String>,
    pub targets: Vec<usize>,
    #[serde(serialize_with = "serialize_methods")]
    pub methods: Vec<MethodReport>,
    /// Every frame's D-MSE per method, in the order evaluated: the pooled figures hide the frame
    /// where a method loses.
    pub per_frame: Vec<FrameRecord>,
    /// Where `ms_per_frame` was measured: the CPU, and the threads of the run.
    pub machine: Machine,
    pub threads: usize,
}

/// The scores of one target frame.
#[derive(Clone, Debug, Serialize)]
pub struct FrameRecord {
    pub clip: String,
    pub target: usize,
    pub disocclusion_pixels: usize,
    /// D-MSE by method name (`None` without disocclusions).
    pub d_mse: BTreeMap<String, Option<f64>>,
}

fn serialize_methods<S: serde::Serializer>(methods: &[MethodReport], s: S) -> Result<S::Ok, S::Error> {
    use serde::ser::SerializeMap;
    let mut map = s.serialize_map(Some(methods.len()))?;
    for m in methods {
        map.serialize_entry(&m.name, m)?;
    }
    map.end()
}

/// Running sums of one method's scores.
#[derive(Default)]
struct Accumulator {
    mse: f64,
    ssim: f64,
    d_mse: f64,
    d_ssim: f64,
    frames: usize,
    d_frames: usize,
    tc_variances: Vec<f64>,
    stage_time: BTreeMap<&'static str, Duration>,
    timed_frames: usize,
}

impl Accumulator {
    fn add(&mut self, s: &FrameScores) {
        self.mse += s.mse;
        self.ssim += s.ssim;
        self.frames += 1;
        if let (Some(dm), Some(ds)) = (s.d_mse, s.d_ssim) {
            self.d_mse += dm;
            self.d_ssim += ds;
            self.d_frames += 1;
        }
    }

    fn report(self, name: &str, uses_ground_truth: bool, timed: bool) -> MethodReport {
        let per = |x: f64, n: usize| if n == 0 { f64::NAN } else { x / n as f64 };
        let per_frame_ms = |d: Duration| d.as_secs_f64() * 1e3 / self.timed_frames.max(1) as f64;
        let ms_by_stage: BTreeMap<String, f64> =
            self.stage_time.iter().map(|(k, d)| (k.to_string(), per_frame_ms(*d))).collect();
        let tc_tracks = self.tc_variances.len();
        MethodReport {
            name: name.to_string(),
            uses_ground_truth,
            mse: per(self.mse, self.frames),
            d_mse: (self.d_frames > 0).then(|| per(self.d_mse, self.d_frames)),
            ssim: per(self.ssim, self.frames),
            d_ssim: (self.d_frames > 0).then(|| per(self.d_ssim, self.d_frames)),
            tc: (tc_tracks > 0).then(|| self.tc_variances.iter().sum::<f64>() / tc_tracks as f64),
            tc_tracks,
            ms_per_frame: timed.then(|| ms_by_stage.values().sum()),
            ms_by_stage: if timed { ms_by_stage } else { BTreeMap::new() },
            frames: self.frames,
            d_frames: self.d_frames,
        }
    }
}

/// The name of a clip in reports and in external folders: its path relative to the dataset, or
/// its own folder name when the dataset is the clip.
pub fn clip_name(data: &Path, clip: &Path) -> String {
    match clip.strip_prefix(data) {
        Ok(rel) if !rel.as_os_str().is_empty() => rel.to_string_lossy().replace('\\', "/"),
        _ => clip.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "clip".into()),
    }
}

/// Warps frame `t - 1` into view `t`: the warp every method of every target starts from.
pub fn warp_to_target(clip: &Clip, last: &Frame, t: usize) -> Warp {
    let transform = relative_pose(clip.pose(t - 1), clip.pose(t));
    warp_forward(&last.image, &last.depth, clip.intrinsics(), &transform)
}

/// What every method predicts target `t` of `clip` from: frames `t - 3` and `t - 1` (`frames`),
/// the warp of `t - 1` into view `t`, and the target frame for the methods that read it.
pub fn target_context<'a>(
    clip: &'a Clip,
    frames: [&'a Frame; 2],
    t: usize,
    warp: &'a Warp,
    ground_truth: Option<&'a RgbImage>,
) -> InfillContext<'a> {
    let [before_last, last] = frames;
    let view = |frame: &'a Frame, i: usize| FrameView { image: &frame.image, depth: &frame.depth, pose: clip.pose(i) };
    InfillContext {
        intrinsics: clip.intrinsics(),
        last: view(last, t - 1),
        before_last: Some(view(before_last, t - 3)),
        target_pose: clip.pose(t),
        warped: warp,
        ground_truth,
    }
}

/// Checks that `targets` can be predicted in a clip of `len` frames: each needs `t - 3 .. t`.
pub fn check_targets(clip: &Clip, targets: &[usize]) -> Result<()> {
    for &t in targets {
        if t < FIRST_TARGET || t >= clip.len() {
            bail!(
                "{}: target {t} needs frames {}..={t}, but the clip has frames 0..={}",
                clip.path().display(),
                t.saturating_sub(3),
                clip.len().saturating_sub(1)
            );
        }
    }
    Ok(())
}

/// True when the targets are every other frame (`t, t+2, t+4, ...`), the pattern TC is defined on.
fn tc_applies(targets: &[usize], clip_len: usize) -> bool {
    !targets.is_empty()
        && targets.windows(2).all(|w| w[1] == w[0] + 2)
        && targets[0] >= 1
        && targets[targets.len() - 1] + 1 < clip_len
}

/// What one target frame left once every method predicted it: the inputs to a report that shows
/// more than the scores (`ivp eval --report`). The record holds the scores the table pools.
pub struct FrameOutputs<'a> {
    pub record: &'a FrameRecord,
    /// The warp every method started from (its holes say where the disocclusions are).
    pub warp: &'a Warp,
    pub truth: &'a RgbImage,
    /// Per method, in the order of the methods: the 8-bit prediction that was scored.
    pub predictions: &'a [RgbImage],
    /// Per method: the vectors it filled the disocclusions with, for the methods that fill by vectors.
    pub vectors: &'a [Option<VectorField>],
}

/// Sees every target frame of an evaluation as soon as it is scored (and only then: keeping every
/// frame of a dataset would take memory in proportion to the dataset).
pub trait FrameObserver {
    fn observe(&mut self, frame: &FrameOutputs<'_>);
}

/// The observer of a plain evaluation: it keeps nothing.
impl FrameObserver for () {
    fn observe(&mut self, _: &FrameOutputs<'_>) {}
}

/// Scores every method on every target of every clip under `data`.
pub fn evaluate(data: &Path, targets: &[usize], methods: &[Method], progress: bool) -> Result<EvalReport> {
    evaluate_observed(data, targets, methods, progress, &mut ())
}

/// [`evaluate`], handing every scored target frame to `observer`.
pub fn evaluate_observed(
    data: &Path,
    targets: &[usize],
    methods: &[Method],
    progress: bool,
    observer: &mut dyn FrameObserver,
) -> Result<EvalReport> {
    if methods.is_empty() {
        bail!("no method to evaluate");
    }
    let clip_dirs = find_clips(data)?;
    let clips: Vec<Clip> = clip_dirs.iter().map(Clip::open).collect::<Result<_, _>>()?;
    for clip in &clips {
        check_targets(clip, targets)?;
    }
    let mut sorted_targets = targets.to_vec();
    sorted_targets.sort_unstable();
    sorted_targets.dedup();

    let bar = progress_bar(progress, (clips.len() * sorted_targets.len()) as u64, "evaluating");
    let mut acc: Vec<Accumulator> = methods.iter().map(|_| Accumulator::default()).collect();
    let mut names = Vec::new();
    let mut per_frame = Vec::new();
    for clip in &clips {
        let name = clip_name(data, clip.path());
        bar.set_message(name.clone());
        let mut sink = Sink { acc: &mut acc, per_frame: &mut per_frame, observer: &mut *observer };
        evaluate_clip(clip, &name, &sorted_targets, methods, &mut sink, &bar)?;
        names.push(name);
    }
    bar.finish_and_clear();

    let reports = methods
        .iter()
        .zip(acc)
        .map(|(m, a)| match m {
            Method::Internal(inf) => a.report(inf.name(), inf.uses_ground_truth(), true),
            Method::External { name, .. } => a.report(name, false, false),
        })
        .collect();
    Ok(EvalReport {
        clips: names,
        targets: sorted_targets,
        methods: reports,
        per_frame,
        machine: Machine::this(),
        threads: rayon::current_num_threads(),
    })
}

/// Writes `report` as JSON to `path` (atomically), creating its folder.
pub fn write_json(path: &Path, report: &EvalReport) -> Result<()> {
    let json = serde_json::to_string_pretty(report)?;
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    ivp_data::write_atomically(path, json.as_bytes())?;
    Ok(())
}

/// What one target of one clip leaves for TC.
struct TargetOutcome {
    warp: Warp,
    predictions: Vec<RgbImage>,
}

/// Where the outcomes of a clip's targets go.
struct Sink<'a> {
    acc: &'a mut [Accumulator],
    per_frame: &'a mut Vec<FrameRecord>,
    observer: &'a mut dyn FrameObserver,
}

fn evaluate_clip(
    clip: &Clip,
    name: &str,
    targets: &[usize],
    methods: &[Method],
    sink: &mut Sink<'_>,
    bar: &ProgressBar,
) -> Result<()> {
    let acc = &mut *sink.acc;
    let first = targets[0] - 3;
    let last = (targets[targets.len() - 1] + 1).min(clip.len() - 1);
    let frames: BTreeMap<usize, Frame> =
        (first..=last).map(|i| Ok((i, clip.load_frame(i)?))).collect::<Result<_, ivp_data::DataError>>()?;

    let mut outcomes = BTreeMap::new();
    for &t in targets {
        let (before_last, last_frame, truth) = (&frames[&(t - 3)], &frames[&(t - 1)], &frames[&t]);
        // Times are of warm runs: the run's first target is warped and predicted once untimed
        // first, since it pays one-off costs (at 1080p the recipe's model took 590 ms on it
        // against about 140 on the next ones: memory mapped for the first time).
        let warm_up = acc.iter().all(|a| a.timed_frames == 0);
        if warm_up {
            warp_to_target(clip, last_frame, t);
        }
        let started = Instant::now();
        let warp = warp_to_target(clip, last_frame, t);
        let warp_time = started.elapsed();
        let disocclusions = warp.holes.disocclusions();

        let mut predictions = Vec::with_capacity(methods.len());
        // The vectors the infillers made anyway, kept for the observer until the target is done.
        let mut vectors = Vec::with_capacity(methods.len());
        let mut record =
            FrameRecord { clip: name.to_string(), target: t, disocclusion_pixels: 0, d_mse: BTreeMap::new() };
        for (method, acc) in methods.iter().zip(acc.iter_mut()) {
            let (prediction, filled_with) = match method {
                Method::Internal(infiller) => {
                    let truth = infiller.uses_ground_truth().then_some(&truth.image);
                    let ctx = target_context(clip, [before_last, last_frame], t, &warp, truth);
                    let infill =
                        || infiller.infill(&ctx).with_context(|| format!("{} on {name}, target {t}", infiller.name()));
                    if warm_up {
                        infill()?;
                    }
                    let out = infill()?;
                    if infiller.uses_warp() {
                        *acc.stage_time.entry("warp").or_default() += warp_time;
                    }
                    for (stage, d) in out.stages {
                        *acc.stage_time.entry(stage).or_default() += d;
                    }
                    acc.timed_frames += 1;
                    (out.image.quantized_to_8bit(), out.vectors)
                }
                Method::External { name: method_name, dir } => {
                    let path = dir.join(name).join(format!("{t:04}.png"));
                    let image = read_rgb(&path).with_context(|| format!("method {method_name}"))?;
                    if !image.same_size(&truth.image) {
                        bail!(
                            "{}: {}x{} but the clip's frames are {}x{}",
                            path.display(),
                            image.width(),
                            image.height(),
                            truth.image.width(),
                            truth.image.height()
                        );
                    }
                    (image.quantized_to_8bit(), None)
                }
            };
            let scores = score_frame(&prediction, &truth.image, &disocclusions);
            record.disocclusion_pixels = scores.disocclusion_pixels;
            record.d_mse.insert(method.name().to_string(), scores.d_mse);
            acc.add(&scores);
            predictions.push(prediction);
            vectors.push(filled_with);
        }
        sink.observer.observe(&FrameOutputs {
            record: &record,
            warp: &warp,
            truth: &truth.image,
            predictions: &predictions,
            vectors: &vectors,
        });
        sink.per_frame.push(record);
        outcomes.insert(t, TargetOutcome { warp, predictions });
        bar.inc(1);
    }

    if tc_applies(targets, clip.len()) {
        add_temporal_consistency(clip, targets, &frames, &outcomes, acc);
    }
    Ok(())
}

/// Pools the TC tracks of this clip into every method's accumulator (ALGORITHMS.md §7).
fn add_temporal_consistency(
    clip: &Clip,
    targets: &[usize],
    frames: &BTreeMap<usize, Frame>,
    outcomes: &BTreeMap<usize, TargetOutcome>,
    acc: &mut [Accumulator],
) {
    let sequence: Vec<usize> = (targets[0] - 1..=targets[targets.len() - 1] + 1).collect();
    let poses: Vec<_> = sequence.iter().map(|&i| *clip.pose(i)).collect();
    let ground_truth: Vec<RgbImage> = sequence.iter().map(|i| frames[i].image.clone()).collect();
    let disocclusions: Vec<Option<Vec<bool>>> =
        sequence.iter().map(|i| outcomes.get(i).map(|o| o.warp.holes.disocclusions())).collect();
    let anchor = &outcomes[&targets[0]].warp;
    let anchor_known = anchor.holes.known();
    for (m, acc) in acc.iter_mut().enumerate() {
        let predictions: Vec<Option<RgbImage>> =
            sequence.iter().map(|i| outcomes.get(i).map(|o| o.predictions[m].clone())).collect();
        let seq = TcSequence {
            intrinsics: clip.intrinsics(),
            poses: &poses,
            ground_truth: &ground_truth,
            predictions: &predictions,
            disocclusions: &disocclusions,
            anchor_depth: &anchor.depth,
            anchor_known: &anchor_known,
        };
        acc.tc_variances.extend(tc_track_variances(&seq));
    }
}

/// The columns of the table of scores.
pub const TABLE_COLUMNS: [&str; 7] = ["method", "MSE", "D-MSE", "SSIM", "D-SSIM", "TC", "ms/frame"];

/// The cells of the table of scores, one row per method, as `ivp eval` prints them (and its
/// report shows them): one formatting for both.
pub fn table_cells(report: &EvalReport) -> Vec<[String; 7]> {
    let opt = |x: Option<f64>, digits: usize| x.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    report
        .methods
        .iter()
        .map(|m| {
            let name = if m.uses_ground_truth { format!("{} (uses ground truth)", m.name) } else { m.name.clone() };
            [
                name,
                format!("{:.1}", m.mse),
                opt(m.d_mse, 1),
                format!("{:.3}", m.ssim),
                opt(m.d_ssim, 3),
                opt(m.tc, 1),
                opt(m.ms_per_frame, 1),
            ]
        })
        .collect()
}

/// The line under the table: what the averages are over.
pub fn table_footer(report: &EvalReport) -> String {
    let m = &report.methods[0];
    format!(
        "{} clips, targets {:?}: {} frames, {} with disocclusions (D- averages), {} TC tracks; times on {}, {} threads",
        report.clips.len(),
        report.targets,
        m.frames,
        m.d_frames,
        m.tc_tracks,
        report.machine,
        report.threads
    )
}

/// The table printed by `ivp eval`.
pub fn format_table(report: &EvalReport) -> String {
    let mut rows = vec![TABLE_COLUMNS.map(String::from)];
    rows.extend(table_cells(report));
    let widths: Vec<usize> = (0..7).map(|c| rows.iter().map(|r| r[c].len()).max().unwrap_or(0)).collect();
    let mut out = String::new();
    for (i, row) in rows.iter().enumerate() {
        let cells: Vec<String> = row
            .iter()
            .enumerate()
            .map(|(c, s)| if c == 0 { format!("{s:<w$}", w = widths[c]) } else { format!("{s:>w$}", w = widths[c]) })
            .collect();
        out.push_str(&format!("| {} |\n", cells.join(" | ")));
        if i == 0 {
            let rule: Vec<String> = widths.iter().map(|w| "-".repeat(*w)).collect();
            out.push_str(&format!("|-{}-|\n", rule.join("-|-")));
        }
    }
    out.push_str(&table_footer(report));
    out.push('\n');
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| s.to_string()).collect()
    }

    fn build(methods: &[&str], externals: &[String]) -> Result<Vec<Method>> {
        build_methods(&MethodSpecs {
            names: &names(methods),
            models: &[],
            iterations: 1,
            rules: InfillRules::NONE,
            externals,
            coverage: Coverage::Dense,
            scale: Scale::Factor(1),
            prior_scale: PriorScale::Auto,
        })
    }

    fn error(methods: &[&str], externals: &[String]) -> String {
        build(methods, externals).err().expect("an error").to_string()
    }

    #[test]
    fn methods_keep_their_order_and_externals_come_last() {
        let dir = tempfile::tempdir().unwrap();
        let external = vec![format!("mine={}", dir.path().display())];
        let methods = build(&["fill", " copy ", ""], &external).unwrap();
        let order: Vec<&str> = methods.iter().map(Method::name).collect();
        assert_eq!(order, ["fill", "copy", "mine"]);
    }

    #[test]
    fn bad_method_names_are_explained() {
        assert!(error(&["ivp"], &[]).contains("add --model FILE"));
        assert!(error(&["foo"], &[]).starts_with("unknown method `foo`"));
        assert_eq!(error(&["copy", "copy"], &[]), "method `copy` is given twice");
        assert_eq!(error(&[], &names(&["bad"])), "--external takes NAME=DIR, got `bad`");
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(error(&["copy"], &[format!("copy={}", dir.path().display())]), "method `copy` is given twice");
    }
}
