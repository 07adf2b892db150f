//! `cargo xtask bench --speed-vs-error`: time per frame against D-MSE for the classical methods
//! and trained models (width multipliers, iterations P = 1, 2, 3, sparse and dense, and at 1080p
//! also at full size, `--scale 1`), at 320x240 and 1920x1080, by running `ivp eval`;
//! `OUT/speed_vs_error.{csv,md,svg}` with the Pareto front.
//!
//! Time per frame is `ivp eval`'s `ms_per_frame`: the whole prediction of a frame (the warp, and
//! for a model the temporal prior, P passes of the network and the infilling), on the same frames
//! for every method.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{bail, ensure, Context, Result};

use crate::charts::{self, TimedPanel, TimedPoint, TimedSeries};
use crate::{ablate, run};
use ivp_plot::Stroke;

/// The classical methods, in the order of the tables (`oracle` reads the ground truth: shown, but
/// never on the Pareto front).
const CLASSICAL: [&str; 5] = ["copy", "warp", "fill", "oracle", "telea"];

/// Iterations of the models' test-time infilling.
const ITERATIONS: [usize; 3] = [1, 2, 3];

/// The widths swept by default, each from [`model_file`] when it exists.
pub const DEFAULT_WIDTHS: [&str; 4] = ["0.125", "0.25", "0.5", "1.0"];

/// Seed of the generated clips: far from the training stream's and the ablation's.
const GENERATED_SEED: &str = "77017";

/// What one sweep does.
pub struct Options {
    /// Trained models: width multiplier and model file (missing files are skipped, with a warning).
    pub models: Vec<(String, PathBuf)>,
    /// The 320x240 clips (generated ones replace them when absent).
    pub data: PathBuf,
    /// The 1920x1080 Blender clips, scored besides a generated full-HD clip when they exist.
    pub data_hd: PathBuf,
    /// Where the report goes: OUT/speed_vs_error.{csv,md,svg}.
    pub out: PathBuf,
    /// Generated clips, scores and the quick model (an ignored folder).
    pub work: PathBuf,
    /// `--threads` of every `ivp` run.
    pub threads: usize,
    /// Tiny generated clips and a model trained for a few steps: a test of the pipeline.
    pub quick: bool,
    /// The command as typed, for the report's header.
    pub command: String,
}

/// A dataset to score on.
#[derive(Clone, Debug)]
struct Dataset {
    name: String,
    width: usize,
    height: usize,
    dir: PathBuf,
    targets: &'static str,
    /// The large frames: models also run at full size (`--scale 1`) beside the default, which
    /// shrinks large frames (ALGORITHMS.md §6.7).
    large: bool,
}

impl Dataset {
    fn resolution(&self) -> String {
        format!("{}x{}", self.width, self.height)
    }
}

/// How a model covers a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coverage {
    Sparse,
    Dense,
    /// Sparse, with the frame at full size however large (`--scale 1`).
    SparseFullSize,
}

impl Coverage {
    fn name(self) -> &'static str {
        match self {
            Coverage::Sparse => "sparse",
            Coverage::Dense => "dense",
            Coverage::SparseFullSize => "sparse full-size",
        }
    }

    /// Its line in the chart.
    fn stroke(self) -> Stroke {
        match self {
            Coverage::Sparse => Stroke::Solid,
            Coverage::Dense => Stroke::Dashed,
            Coverage::SparseFullSize => Stroke::Dotted,
        }
    }

    /// The flags of `ivp eval` that select it.
    fn flags(self) -> &'static [&'static str] {
        match self {
            Coverage::Sparse => &[],
            Coverage::Dense => &["--dense"],
            Coverage::SparseFullSize => &["--scale", "1"],
        }
    }
}

/// How a method was run: classical, or a model at a width, iterations and coverage.
#[derive(Clone, Debug, PartialEq)]
pub enum Setting {
    Classical,
    Model { width: String, iterations: usize, coverage: Coverage },
}

/// One row of the report: a method on a dataset, its time and its scores.
#[derive(Clone, Debug, PartialEq)]
pub struct Measurement {
    pub dataset: String,
    pub resolution: String,
    pub method: String,
    pub setting: Setting,
    pub uses_ground_truth: bool,
    pub ms_per_frame: f64,
    pub d_mse: Option<f64>,
    pub d_ssim: Option<f64>,
    pub tc: Option<f64>,
    /// Not dominated in both time and D-MSE on its dataset (set by [`mark_pareto_fronts`]).
    pub pareto: bool,
}

pub fn speed_vs_error(ivp: &Path, options: &Options) -> Result<()> {
    for dir in [&options.out, &options.work] {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let datasets = prepare_datasets(ivp, options)?;
    let models = available_models(ivp, options)?;
    let mut measurements = Vec::new();
    let mut clip_counts = Vec::new();
    let mut machine = String::new();
    for dataset in &datasets {
        println!("speed vs error: {} ({})", dataset.name, dataset.resolution());
        let (rows, clips, measured_on) = measure_dataset(ivp, options, dataset, &models)?;
        measurements.extend(rows);
        clip_counts.push(clips);
        machine = measured_on;
    }
    mark_pareto_fronts(&mut measurements);

    let header = ReportHeader {
        command: &options.command,
        machine,
        threads: options.threads,
        load_average: load.split_whitespace().take(3).collect::<Vec<_>>().join(" "),
    };
    let csv = options.out.join("speed_vs_error.csv");
    let md = options.out.join("speed_vs_error.md");
    let svg = options.out.join("speed_vs_error.svg");
    std::fs::write(&csv, to_csv(&measurements)).with_context(|| format!("writing {}", csv.display()))?;
    std::fs::write(&md, to_markdown(&header, &datasets, &clip_counts, &measurements))
        .with_context(|| format!("writing {}", md.display()))?;
    write_chart(&svg, &datasets, &measurements)?;
    print!("{}", std::fs::read_to_string(&md)?);
    println!("written: {}, {} and {}", csv.display(), md.display(), svg.display());
    Ok(())
}

/// The 320x240 clips (generated when `--data` is absent), a generated 1920x1080 clip, and the
/// 1920x1080 Blender clip when it exists; in `--quick`, two tiny generated datasets in their place.
fn prepare_datasets(ivp: &Path, options: &Options) -> Result<Vec<Dataset>> {
    let generated = |width: usize, height: usize, clips: usize, frames: usize, targets, large| -> Result<Dataset> {
        let name = format!("generated-{width}x{height}");
        let dir = options.work.join(&name);
        generate(ivp, &dir, (width, height), clips, frames)?;
        Ok(Dataset { name, width, height, dir, targets, large })
    };
    if options.quick {
        return Ok(vec![generated(96, 72, 1, 12, "6,8,10", false)?, generated(192, 108, 1, 6, "3,4,5", true)?]);
    }
    let mut datasets = Vec::new();
    if options.data.is_dir() {
        let name = folder_name(&options.data);
        let dir = options.data.clone();
        datasets.push(Dataset { name, width: 320, height: 240, dir, targets: "6,8,10", large: false });
    } else {
        eprintln!("warning: {} is missing; generated 320x240 clips stand in for it", options.data.display());
        datasets.push(generated(320, 240, 4, 12, "6,8,10", false)?);
    }
    // 6 frames, like the Blender clip: targets 3, 4, 5 (no TC) at a twentieth of the rendering time.
    datasets.push(generated(1920, 1080, 1, 6, "3,4,5", true)?);
    if options.data_hd.is_dir() {
        let name = folder_name(&options.data_hd);
        let dir = options.data_hd.clone();
        datasets.push(Dataset { name, width: 1920, height: 1080, dir, targets: "3,4,5", large: true });
    } else {
        eprintln!("warning: {} is missing; scoring 1920x1080 on the generated clip only", options.data_hd.display());
    }
    Ok(datasets)
}

fn folder_name(dir: &Path) -> String {
    dir.file_name().map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// Renders clips once (the same seed gives byte-identical files, so a finished folder is reused).
fn generate(ivp: &Path, dir: &Path, (width, height): (usize, usize), clips: usize, frames: usize) -> Result<()> {
    if dir.is_dir() {
        return Ok(());
    }
    let partial = dir.with_extension("partial");
    let _ = std::fs::remove_dir_all(&partial);
    let mut cmd = Command::new(ivp);
    cmd.args(["--quiet", "generate", "--out"]).arg(&partial).args(["--seed", GENERATED_SEED]);
    cmd.args(["--clips", &clips.to_string(), "--frames", &frames.to_string()]);
    cmd.args(["--width", &width.to_string(), "--height", &height.to_string()]);
    println!("generating {clips} clip(s) of {frames} frames at {width}x{height} into {}", dir.display());
    run(cmd.stdout(Stdio::null()))?;
    std::fs::rename(&partial, dir).with_context(|| format!("renaming {} to {}", partial.display(), dir.display()))
}

/// The models whose files exist (a warning for the others); in `--quick`, one trained for a few
/// steps at width 0.125.
fn available_models(ivp: &Path, options: &Options) -> Result<Vec<(String, PathBuf)>> {
    if options.quick {
        let dir = options.work.join("quick-model");
        if !dir.join("model.safetensors").is_file() {
            let mut cmd = Command::new(ivp);
            cmd.args(["--quiet", "train", "--synthetic", "--out"]).arg(&dir);
            ablate::use_quick_recipe(&mut cmd, &options.work.join("quick.toml"))?;
            run(cmd.stdout(Stdio::null()))?;
        }
        return Ok(vec![("0.125".to_string(), dir.join("model.safetensors"))]);
    }
    let (found, missing): (Vec<_>, Vec<_>) = options.models.iter().cloned().partition(|(_, file)| file.is_file());
    for (width, file) in &missing {
        eprintln!("warning: no model of width {width}: {} is missing", file.display());
    }
    if found.is_empty() {
        eprintln!("warning: no trained model found: only the classical methods are measured");
    }
    Ok(found)
}

/// The name of the model of width `width` in `ivp eval`'s report.
fn model_name(width: &str) -> String {
    format!("ivp-w{width}")
}

/// Scores of one dataset: the classical methods once, then every model at every P and coverage
/// (all widths in one `ivp eval`, on the same warps). Returns the rows and the number of clips.
fn measure_dataset(
    ivp: &Path,
    options: &Options,
    dataset: &Dataset,
    models: &[(String, PathBuf)],
) -> Result<(Vec<Measurement>, usize, String)> {
    let report = eval(ivp, options, dataset, &CLASSICAL.join(","), &[], &[], "classical")?;
    let clips = report["clips"].as_array().map_or(0, Vec::len);
    let machine = machine_description(&report);
    let mut rows = CLASSICAL
        .iter()
        .map(|m| measurement(&report, dataset, m, m, Setting::Classical))
        .collect::<Result<Vec<_>>>()?;
    if models.is_empty() {
        return Ok((rows, clips, machine));
    }
    let names: Vec<String> = models.iter().map(|(w, _)| model_name(w)).collect();
    let specs: Vec<String> = models.iter().zip(&names).map(|((_, f), n)| format!("{n}={}", f.display())).collect();
    let mut coverages = vec![Coverage::Sparse, Coverage::Dense];
    if dataset.large {
        coverages.push(Coverage::SparseFullSize);
    }
    for coverage in coverages {
        for iterations in ITERATIONS {
            let mut extra = vec!["--iterations".to_string(), iterations.to_string()];
            extra.extend(coverage.flags().iter().map(|f| f.to_string()));
            let label = format!("P{iterations}-{}", coverage.name());
            let report = eval(ivp, options, dataset, &names.join(","), &specs, &extra, &label)?;
            for ((width, _), name) in models.iter().zip(&names) {
                let setting = Setting::Model { width: width.clone(), iterations, coverage };
                rows.push(measurement(&report, dataset, name, "ivp", setting)?);
            }
        }
    }
    Ok((rows, clips, machine))
}

/// Runs `ivp eval` on `dataset` and returns its JSON report.
fn eval(
    ivp: &Path,
    options: &Options,
    dataset: &Dataset,
    methods: &str,
    models: &[String],
    extra: &[String],
    label: &str,
) -> Result<serde_json::Value> {
    let json = options.work.join("scores").join(format!("{}_{label}.json", dataset.name));
    let mut cmd = Command::new(ivp);
    cmd.args(["--quiet", "--threads", &options.threads.to_string(), "eval", "--data"]).arg(&dataset.dir);
    cmd.args(["--targets", dataset.targets, "--methods", methods]).args(extra).arg("--json").arg(&json);
    for spec in models {
        cmd.args(["--model", spec]);
    }
    println!("  {label}");
    run(cmd.stdout(Stdio::null()))?;
    let text = std::fs::read(&json).with_context(|| format!("reading {}", json.display()))?;
    serde_json::from_slice(&text).with_context(|| format!("parsing {}", json.display()))
}

/// The row of method `name` in an `ivp eval` report, shown as `method`.
fn measurement(
    report: &serde_json::Value,
    dataset: &Dataset,
    name: &str,
    method: &str,
    setting: Setting,
) -> Result<Measurement> {
    let m = &report["methods"][name];
    ensure!(m.is_object(), "{}: no scores of {name} in ivp eval's report", dataset.name);
    Ok(Measurement {
        dataset: dataset.name.clone(),
        resolution: dataset.resolution(),
        method: method.to_string(),
        setting,
        uses_ground_truth: m["uses_ground_truth"].as_bool().unwrap_or(false),
        ms_per_frame: m["ms_per_frame"].as_f64().with_context(|| format!("{}: no time for {name}", dataset.name))?,
        d_mse: m["d_mse"].as_f64(),
        d_ssim: m["d_ssim"].as_f64(),
        tc: m["tc"].as_f64(),
        pareto: false,
    })
}

/// For each point (time, error), whether it is on the Pareto front: no other point is at least as
/// fast and as accurate and strictly better in one of the two. Points with a non-finite coordinate
/// are never on it and dominate nothing; equal points are both on it.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<bool> {
    let finite = |p: &(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let dominates = |a: &(f64, f64), b: &(f64, f64)| a.0 <= b.0 && a.1 <= b.1 && (a.0 < b.0 || a.1 < b.1);
    points.iter().map(|p| finite(p) && !points.iter().filter(|q| finite(q)).any(|q| dominates(q, p))).collect()
}

/// Sets `pareto` on every measurement: the front of its dataset in (ms per frame, D-MSE), among the
/// methods that do not read the ground truth.
fn mark_pareto_fronts(measurements: &mut [Measurement]) {
    let mut datasets: Vec<String> = measurements.iter().map(|m| m.dataset.clone()).collect();
    datasets.dedup();
    for dataset in datasets {
        let members: Vec<usize> = (0..measurements.len())
            .filter(|&i| measurements[i].dataset == dataset && !measurements[i].uses_ground_truth)
            .collect();
        let points: Vec<(f64, f64)> = members
            .iter()
            .map(|&i| (measurements[i].ms_per_frame, measurements[i].d_mse.unwrap_or(f64::NAN)))
            .collect();
        for (&i, on_front) in members.iter().zip(pareto_front(&points)) {
            measurements[i].pareto = on_front;
        }
    }
}

/// A number with `digits` decimals, or nothing when it is absent.
fn optional(value: Option<f64>, digits: usize) -> String {
    value.map_or(String::new(), |v| format!("{v:.digits$}"))
}

pub const CSV_HEADER: &str =
    "dataset,resolution,method,width_mult,iterations,coverage,ms_per_frame,d_mse,d_ssim,tc,pareto";

fn to_csv(measurements: &[Measurement]) -> String {
    let mut out = format!("{CSV_HEADER}\n");
    for m in measurements {
        let (width, iterations, coverage) = match &m.setting {
            Setting::Classical => (String::new(), String::new(), ""),
            Setting::Model { width, iterations, coverage } => (width.clone(), iterations.to_string(), coverage.name()),
        };
        let _ = writeln!(
            out,
            "{},{},{},{width},{iterations},{coverage},{:.2},{},{},{},{}",
            m.dataset,
            m.resolution,
            m.method,
            m.ms_per_frame,
            optional(m.d_mse, 2),
            optional(m.d_ssim, 4),
            optional(m.tc, 2),
            m.pareto
        );
    }
    out
}

/// What the report says about how it was made.
struct ReportHeader<'a> {
    command: &'a str,
    machine: String,
    threads: usize,
    load_average: String,
}

fn to_markdown(
    header: &ReportHeader<'_>,
    datasets: &[Dataset],
    clips: &[usize],
    measurements: &[Measurement],
) -> String {
    let mut out = String::from("# Speed against error\n\n");
    let _ = writeln!(out, "Made by `{}`", header.command);
    let _ = writeln!(
        out,
        "on {}, `ivp` run with `--threads {}` (load average when it started: {}; other work on the \
         machine slows every method alike only roughly).\n",
        header.machine, header.threads, header.load_average
    );
    out.push_str(
        "ms/frame is `ivp eval`'s time per frame: the warp, and for `ivp` the temporal prior, P passes \
         of the network and the infilling (each method's first frame is run once untimed first). D-MSE and D-SSIM are on disocclusion pixels (MSE on the \
         0..255 scale); TC is temporal consistency (lower is better), only where the targets are every \
         other frame. Pareto: no other method is both at least as fast and at least as accurate (D-MSE) \
         on the same dataset; `oracle` reads the ground truth and is left out of the front.\n\n",
    );
    for (dataset, clips) in datasets.iter().zip(clips) {
        let _ = writeln!(
            out,
            "## {} ({}, {clips} clip{}, targets {})\n",
            dataset.name,
            dataset.resolution(),
            if *clips == 1 { "" } else { "s" },
            dataset.targets
        );
        out.push_str("| method | width | P | coverage | ms/frame | D-MSE | D-SSIM | TC | Pareto |\n");
        out.push_str("|---|---|---|---|---|---|---|---|---|\n");
        for m in measurements.iter().filter(|m| m.dataset == dataset.name) {
            let (width, iterations, coverage) = match &m.setting {
                Setting::Classical => ("-".to_string(), "-".to_string(), "-"),
                Setting::Model { width, iterations, coverage } => {
                    (width.clone(), iterations.to_string(), coverage.name())
                }
            };
            let method =
                if m.uses_ground_truth { format!("{} (uses ground truth)", m.method) } else { m.method.clone() };
            let dash = |s: String| if s.is_empty() { "-".to_string() } else { s };
            let _ = writeln!(
                out,
                "| {method} | {width} | {iterations} | {coverage} | {:.1} | {} | {} | {} | {} |",
                m.ms_per_frame,
                dash(optional(m.d_mse, 1)),
                dash(optional(m.d_ssim, 4)),
                dash(optional(m.tc, 1)),
                if m.pareto { "yes" } else { "" }
            );
        }
        out.push('\n');
    }
    out.push_str("![ms per frame against D-MSE](speed_vs_error.svg)\n");
    out
}

/// The machine an `ivp eval` report names (its CPU and widest vectors), and the logical cores.
fn machine_description(report: &serde_json::Value) -> String {
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!("{}, {cores} cores", crate::machine_named_in(report))
}

/// One panel per dataset; a series per classical method and per model width and coverage (its
/// points the iterations, tagged `P1`..`P3`).
fn write_chart(path: &Path, datasets: &[Dataset], measurements: &[Measurement]) -> Result<()> {
    let panels: Vec<TimedPanel> = datasets
        .iter()
        .map(|d| TimedPanel {
            title: format!("{} ({})", d.name, d.resolution()),
            series: timed_series(measurements.iter().filter(|m| m.dataset == d.name)),
        })
        .collect();
    charts::write_speed_vs_error(
        path,
        "Time per frame against error (lower left is better)",
        "time per frame (ms)",
        "D-MSE on disocclusions (8-bit levels²)",
        &panels,
    )
}

fn timed_series<'a>(measurements: impl Iterator<Item = &'a Measurement>) -> Vec<TimedSeries> {
    let mut series: Vec<TimedSeries> = Vec::new();
    let mut widths: Vec<String> = Vec::new();
    for m in measurements {
        let point =
            |tag| TimedPoint { ms: m.ms_per_frame, error: m.d_mse.unwrap_or(f64::NAN), on_front: m.pareto, tag };
        let (name, colour, line, tag) = match &m.setting {
            Setting::Classical => {
                let i = CLASSICAL.iter().position(|c| *c == m.method).unwrap_or(CLASSICAL.len());
                let name =
                    if m.uses_ground_truth { format!("{} (uses ground truth)", m.method) } else { m.method.clone() };
                (name, ivp_plot::colour(i), None, None)
            }
            Setting::Model { width, iterations, coverage } => {
                let i = widths.iter().position(|w| w == width).unwrap_or_else(|| {
                    widths.push(width.clone());
                    widths.len() - 1
                });
                let name = format!("ivp, width {width}, {}", coverage.name());
                let colour = ivp_plot::colour(CLASSICAL.len() + i);
                (name, colour, Some(coverage.stroke()), Some(format!("P{iterations}")))
            }
        };
        match series.iter_mut().find(|s| s.name == name) {
            Some(s) => s.points.push(point(tag)),
            None => series.push(TimedSeries { name, colour, line, points: vec![point(tag)] }),
        }
    }
    series
}

/// Parses `--models W=FILE,...`; the width must be a number.
pub fn parse_models(specs: &[String]) -> Result<Vec<(String, PathBuf)>> {
    specs
        .iter()
        .map(|spec| {
            let Some((width, file)) = spec.split_once('=') else {
                bail!("--models takes WIDTH=FILE, got `{spec}`");
            };
            ensure!(
                width.parse::<f64>().is_ok_and(|w| w > 0.0),
                "--models {spec}: `{width}` is not a width multiplier"
            );
            Ok((width.to_string(), PathBuf::from(file)))
        })
        .collect()
}

/// The committed model of width `width`, trained with the recipe of its day and seed 0 (each run
/// folder's config.toml repeats it): the recipe's own width is the ablation's `full` seed 0; the
/// others were trained with `ivp train --synthetic --width-mult W --out results/width/wW`, with
/// the paper's depth head (`--depth-head-mult 1` since the recipe narrowed it).
pub fn model_file(width: &str) -> String {
    if width == "0.25" {
        "results/ablate/full/seed0/model.safetensors".to_string()
    } else {
        format!("results/width/w{width}/model.safetensors")
    }
}

/// The default `--models`: [`model_file`] for every default width.
pub fn default_models() -> Vec<String> {
    DEFAULT_WIDTHS.iter().map(|w| format!("{w}={}", model_file(w))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pareto_front_keeps_the_points_nothing_beats_in_both() {
        // (ms, error): a fast bad one, a slow good one, one beaten by the first in both, a tie.
        let points = [(1.0, 500.0), (100.0, 300.0), (2.0, 600.0), (1.0, 500.0), (50.0, f64::NAN)];
        assert_eq!(pareto_front(&points), [true, true, false, true, false]);
        // Equal time, better error dominates; equal in both does not.
        assert_eq!(pareto_front(&[(5.0, 10.0), (5.0, 9.0)]), [false, true]);
        assert_eq!(pareto_front(&[]), Vec::<bool>::new());
    }

    fn row(method: &str, setting: Setting, ms: f64, d_mse: Option<f64>) -> Measurement {
        Measurement {
            dataset: "blender-dev".into(),
            resolution: "320x240".into(),
            method: method.into(),
            setting,
            uses_ground_truth: method == "oracle",
            ms_per_frame: ms,
            d_mse,
            d_ssim: d_mse.map(|_| 0.75),
            tc: None,
            pareto: false,
        }
    }

    #[test]
    fn the_oracle_stays_off_the_front_and_csv_rows_say_how_each_method_ran() {
        let model = Setting::Model { width: "0.25".into(), iterations: 3, coverage: Coverage::Dense };
        let mut rows = vec![
            row("fill", Setting::Classical, 2.5, Some(581.8)),
            row("oracle", Setting::Classical, 2.9, Some(100.0)),
            row("ivp", model, 113.94, Some(450.2)),
            row("copy", Setting::Classical, 3.0, None),
        ];
        mark_pareto_fronts(&mut rows);
        assert_eq!(rows.iter().map(|r| r.pareto).collect::<Vec<_>>(), [true, false, true, false]);
        let csv = to_csv(&rows);
        let lines: Vec<&str> = csv.lines().collect();
        assert_eq!(lines[0], CSV_HEADER);
        assert_eq!(lines[1], "blender-dev,320x240,fill,,,,2.50,581.80,0.7500,,true");
        assert_eq!(lines[3], "blender-dev,320x240,ivp,0.25,3,dense,113.94,450.20,0.7500,,true");
        assert_eq!(lines[4], "blender-dev,320x240,copy,,,,3.00,,,,false");
        assert!(lines.iter().all(|l| l.split(',').count() == CSV_HEADER.split(',').count()));
    }

    #[test]
    fn the_machine_is_the_one_ivp_eval_names() {
        let report = serde_json::json!({"machine": {"cpu": "Intel(R) Xeon(R) CPU @ 2.20GHz", "vectors": "avx512"}});
        assert!(machine_description(&report).starts_with("Intel(R) Xeon(R) CPU @ 2.20GHz (avx512), "));
        assert!(machine_description(&serde_json::json!({})).starts_with("unknown (unknown), "));
    }

    #[test]
    fn models_are_width_equals_file() {
        let models = parse_models(&["0.25=a/model.safetensors".into()]).unwrap();
        assert_eq!(models, [("0.25".to_string(), PathBuf::from("a/model.safetensors"))]);
        assert!(parse_models(&["a/model.safetensors".into()]).is_err());
        assert!(parse_models(&["wide=a".into()]).is_err());
        assert_eq!(default_models().len(), DEFAULT_WIDTHS.len());
    }

    /// The whole pipeline at toy sizes with the dev build of ivp: the files are written and the CSV
    /// has one row per dataset and method setting.
    #[test]
    fn a_quick_sweep_writes_the_report() {
        let ivp = crate::build_ivp_debug(&crate::root()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let options = Options {
            models: Vec::new(),
            data: PathBuf::new(),
            data_hd: PathBuf::new(),
            out: dir.path().join("results"),
            work: dir.path().join("work"),
            threads: 2,
            quick: true,
            command: "cargo xtask bench --speed-vs-error --quick".into(),
        };
        speed_vs_error(&ivp, &options).unwrap();
        let csv = std::fs::read_to_string(options.out.join("speed_vs_error.csv")).unwrap();
        let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
        // 2 datasets x (5 classical + 1 width x 3 iterations x 2 coverages), and the large one
        // at full size too.
        assert_eq!(rows.len(), 2 * (CLASSICAL.len() + ITERATIONS.len() * 2) + ITERATIONS.len(), "{csv}");
        let models: Vec<_> = rows.iter().filter(|r| r[2] == "ivp").map(|r| (r[0], r[4], r[5])).collect();
        assert!(models.contains(&("generated-192x108", "2", "dense")), "{csv}");
        assert!(models.contains(&("generated-192x108", "3", "sparse full-size")), "{csv}");
        assert!(!models.iter().any(|m| m.0 == "generated-96x72" && m.2 == "sparse full-size"), "{csv}");
        assert!(rows.iter().all(|r| r[6].parse::<f64>().is_ok()), "{csv}");
        assert!(rows.iter().any(|r| r[10] == "true"), "no point on the front: {csv}");
        let md = std::fs::read_to_string(options.out.join("speed_vs_error.md")).unwrap();
        assert!(md.contains("`cargo xtask bench --speed-vs-error --quick`") && md.contains("--threads 2"), "{md}");
        assert!(md.contains(" (avx2), ") || md.contains(" (avx512), "), "the machine with its vectors: {md}");
        let svg = std::fs::read_to_string(options.out.join("speed_vs_error.svg")).unwrap();
        assert!(svg.contains("Pareto front") && svg.contains("generated-96x72"));
    }
}
