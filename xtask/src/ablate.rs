//! `cargo xtask ablate`: the rows of the paper's Table 2, each trained with several seeds on
//! identical data, scored on the Blender clips and on a generated held-out split, and summarised
//! as mean and standard deviation over the seeds.
//!
//! Rows: `intensity` (the U-Net predicts colours), `no-tg` (zeros for the temporal prior; its
//! guide term pulls towards the depth-aware `fill` vectors instead of the prior, see
//! `GuideSource` in ivp-train), `no-depth`, `no-iter` (the full
//! model at P = 1) and `full` (P = 3). `no-iter` and `full` are the same trained models. Runs that
//! finished are reused and stopped ones resumed, so a sweep can span several sittings. The models
//! are scored with `--thin-run 0 --far-blur 0`, as the paper infills: the thin-run rule
//! (ALGORITHMS.md §6.5) fills the slivers in which the rows differ most, with the same pixels for
//! every row, and the far blur (also §6.5) applies to the vector rows only.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, Context, Result};

use crate::charts::{self, Bar, BarChart, BarGroup};

/// The flags that score models without the rules the paper does not have.
const PAPER_INFILLING: [&str; 4] = ["--thin-run", "0", "--far-blur", "0"];
use crate::run;

/// The variants trained, in the order of the table.
const TRAINED: [&str; 4] = ["intensity", "no-tg", "no-depth", "full"];

/// The order they are trained in.
const TRAINING_ORDER: [&str; 4] = ["full", "no-depth", "no-tg", "intensity"];

/// A row of the table: the trained variant it uses and the iterations of its test-time infilling.
const ROWS: [(&str, &str, usize); 5] = [
    ("intensity", "intensity", 3),
    ("no-tg", "no-tg", 3),
    ("no-depth", "no-depth", 3),
    ("no-iter", "full", 1),
    ("full", "full", 3),
];

/// Seed of the generated held-out clips: far from the training stream's seeds (the demo's too).
const HELD_OUT_SEED: &str = "59297";

/// What one sweep does.
pub struct Sweep {
    pub seeds: Vec<u64>,
    /// Training steps (the recipe's when `None`).
    pub steps: Option<u64>,
    /// The Blender clips (skipped when absent).
    pub blender: PathBuf,
    /// The real clips every run validates on and chooses its model by (not `blender`'s).
    pub validation_data: PathBuf,
    pub out: PathBuf,
    /// A few steps at small sizes: a smoke test of the whole pipeline.
    pub quick: bool,
    /// Also write the HTML report of `ivp eval --report` over the variants into `OUT/report`.
    pub report: bool,
}

/// One score of one row, seed and dataset.
#[derive(Clone, Debug)]
struct Score {
    row: &'static str,
    seed: u64,
    dataset: String,
    d_mse: f64,
    d_ssim: f64,
    tc: Option<f64>,
    ms_per_frame: f64,
    train_minutes: f64,
}

pub fn ablate(ivp: &Path, sweep: &Sweep) -> Result<()> {
    std::fs::create_dir_all(&sweep.out).with_context(|| format!("creating {}", sweep.out.display()))?;
    let held_out = generate_held_out(ivp, sweep)?;
    let mut datasets = vec![("generated".to_string(), held_out)];
    if sweep.blender.is_dir() && !sweep.quick {
        datasets.insert(0, ("blender-dev".to_string(), sweep.blender.clone()));
    } else if !sweep.quick {
        eprintln!("warning: {} is missing; scoring on the generated split only", sweep.blender.display());
    }

    let run_dir = |variant: &str, seed: u64| sweep.out.join(variant).join(format!("seed{seed}"));
    // Everything is trained before anything is scored, the full model's seeds first: they are
    // also the recipe's spread over seeds (results/resolution), and a sweep stopped part-way
    // leaves whole variants rather than whole seeds.
    for variant in TRAINING_ORDER {
        for &seed in &sweep.seeds {
            train(ivp, sweep, variant, seed, &run_dir(variant, seed))?;
        }
    }
    let mut scores = Vec::new();
    for &seed in &sweep.seeds {
        let models: BTreeMap<&str, PathBuf> = TRAINED.iter().map(|&v| (v, run_dir(v, seed))).collect();
        for (name, data) in &datasets {
            for (iterations, rows) in [(3, &ROWS[..]), (1, &ROWS[3..4])] {
                let rows: Vec<_> = rows.iter().filter(|r| r.2 == iterations).collect();
                let json = sweep.out.join(format!("scores_{name}_seed{seed}_P{iterations}.json"));
                let mut cmd = Command::new(ivp);
                // The default targets (6, 8, 10) of 12-frame clips, with the temporal consistency tracks.
                cmd.args(["--quiet", "eval", "--data"]).arg(data).args(["--methods", "fill"]);
                cmd.args(["--iterations", &iterations.to_string()]).args(PAPER_INFILLING).arg("--json").arg(&json);
                for (row, variant, _) in &rows {
                    cmd.arg("--model").arg(format!("{row}={}", models[variant].join("model.safetensors").display()));
                }
                run(cmd.stdout(std::process::Stdio::null()))?;
                let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json)?)?;
                let mut rows: Vec<(&'static str, Option<&str>)> = rows.iter().map(|r| (r.0, Some(r.1))).collect();
                if iterations == 3 {
                    rows.insert(0, ("fill", None)); // the classical baseline, on the same frames
                }
                for (row, variant) in rows {
                    let m = &report["methods"][row];
                    let number =
                        |key: &str| m[key].as_f64().with_context(|| format!("{}: no {key} for {row}", json.display()));
                    scores.push(Score {
                        row,
                        seed,
                        dataset: name.clone(),
                        d_mse: number("d_mse")?,
                        d_ssim: number("d_ssim")?,
                        tc: m["tc"].as_f64(),
                        ms_per_frame: number("ms_per_frame")?,
                        train_minutes: variant.map_or(Ok(0.0), |v| train_minutes(&models[v]))?,
                    });
                }
            }
        }
    }
    if sweep.report {
        let (name, data) = &datasets[0];
        let seed = sweep.seeds[0];
        let models: Vec<(&str, PathBuf)> =
            TRAINED.iter().map(|&v| (v, run_dir(v, seed).join("model.safetensors"))).collect();
        write_report(ivp, data, &models, &sweep.out.join("report"))?;
        println!("report of {name}, seed {seed}: {}", sweep.out.join("report/index.html").display());
    }
    let (csv, md) = (sweep.out.join("ablations.csv"), sweep.out.join("ablations.md"));
    std::fs::write(&csv, to_csv(&scores)).with_context(|| format!("writing {}", csv.display()))?;
    std::fs::write(&md, to_markdown(&scores, sweep)).with_context(|| format!("writing {}", md.display()))?;
    let svg = sweep.out.join("ablations.svg");
    charts::write_bar_chart(&svg, &d_mse_chart(&scores))?;
    print!("{}", std::fs::read_to_string(&md)?);
    println!("written: {}, {} and {}", csv.display(), md.display(), svg.display());
    Ok(())
}

/// The HTML report of `ivp eval --report` over `models` (each at P = 3, beside `fill` and
/// `telea`) on `data`, written into `dir` afresh: the folder is the sweep's own, so a report of an
/// earlier sweep is removed first rather than mixed with this one.
fn write_report(ivp: &Path, data: &Path, models: &[(&str, PathBuf)], dir: &Path) -> Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("removing the previous report {}", dir.display()))?;
    }
    let mut cmd = Command::new(ivp);
    cmd.args(["--quiet", "eval", "--data"]).arg(data).args(["--methods", "fill,telea", "--iterations", "3"]);
    cmd.args(PAPER_INFILLING);
    for (name, model) in models {
        cmd.arg("--model").arg(format!("{name}={}", model.display()));
    }
    cmd.arg("--report").arg(dir);
    println!("{cmd:?}");
    run(cmd.stdout(std::process::Stdio::null()))
}

/// The held-out clips, generated once (the same seed gives byte-identical files).
fn generate_held_out(ivp: &Path, sweep: &Sweep) -> Result<PathBuf> {
    let dir = sweep.out.join("held-out");
    if !dir.is_dir() {
        let mut cmd = Command::new(ivp);
        cmd.args(["--quiet", "generate", "--out"]).arg(&dir).args(["--seed", HELD_OUT_SEED]);
        if sweep.quick {
            cmd.args(["--clips", "2", "--width", "96", "--height", "72"]);
        } else {
            cmd.args(["--clips", "4"]);
        }
        run(&mut cmd)?;
    }
    Ok(dir)
}

fn train(ivp: &Path, sweep: &Sweep, variant: &str, seed: u64, dir: &Path) -> Result<()> {
    if dir.join("model.safetensors").is_file() {
        println!("{variant} seed {seed}: reusing {}", dir.display());
        return Ok(());
    }
    let mut cmd = Command::new(ivp);
    cmd.args(["--quiet", "train", "--synthetic", "--variant", variant, "--seed", &seed.to_string(), "--out"]).arg(dir);
    if sweep.quick {
        use_quick_recipe(&mut cmd, &sweep.out.join("quick.toml"))?;
    }
    if let Some(steps) = sweep.steps {
        cmd.args(["--steps", &steps.to_string()]);
    }
    if !sweep.quick {
        cmd.arg("--validation-data").arg(&sweep.validation_data);
    }
    if dir.join("checkpoints").is_dir() {
        cmd.arg("--resume");
    }
    println!("{variant} seed {seed}: training in {}", dir.display());
    run(&mut cmd)
}

/// The smoke test's recipe: seconds, not minutes.
const QUICK_RECIPE: &str = "width_mult = 0.125\nsteps = 4\nbatch = 2\ncrop = 32\nguide_steps = 2\n\
                            validation_clips = 0\nvalidation_hd_clips = 0\nlog_every = 1\nvalidate_every = 0\ncheckpoint_every = 2\n";

/// Makes `cmd` (an `ivp train`) run the smoke test's recipe, written to `config`, validated on one
/// frame of one committed clip: the recipe's 36 real frames took most of a quick run's 30 s in the
/// debug build.
pub fn use_quick_recipe(cmd: &mut Command, config: &Path) -> Result<()> {
    std::fs::write(config, QUICK_RECIPE).with_context(|| format!("writing {}", config.display()))?;
    let clip = crate::root().join("data/blender-dev/clip_002");
    cmd.arg("--config").arg(config);
    cmd.arg("--validation-data").arg(clip).args(["--validation-targets", "6"]);
    Ok(())
}

/// Minutes of training of a finished run: the last `elapsed_s` of its `metrics.csv`.
fn train_minutes(run_dir: &Path) -> Result<f64> {
    let path = run_dir.join("metrics.csv");
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let last = text.lines().last().context("empty metrics.csv")?;
    let seconds: f64 =
        last.rsplit(',').next().unwrap_or("").parse().with_context(|| format!("{}: last row", path.display()))?;
    Ok(seconds / 60.0)
}

fn to_csv(scores: &[Score]) -> String {
    let mut out = String::from("variant,seed,d_mse,d_ssim,tc,ms_per_frame,train_minutes,dataset\n");
    for s in scores {
        let tc = s.tc.map_or(String::new(), |t| format!("{t:.2}"));
        let _ = writeln!(
            out,
            "{},{},{:.2},{:.4},{tc},{:.1},{:.2},{}",
            s.row, s.seed, s.d_mse, s.d_ssim, s.ms_per_frame, s.train_minutes, s.dataset
        );
    }
    out
}

/// Mean and sample standard deviation (0 for one value).
fn mean_std(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = if values.len() > 1 { values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0) } else { 0.0 };
    (mean, var.sqrt())
}

/// The rows of the table, `fill` first, as the chart and the tables order them.
fn table_rows() -> impl Iterator<Item = &'static str> {
    std::iter::once("fill").chain(ROWS.iter().map(|r| r.0))
}

/// The datasets of `scores`, in name order.
fn datasets_of(scores: &[Score]) -> Vec<&str> {
    let names: std::collections::BTreeSet<&str> = scores.iter().map(|s| s.dataset.as_str()).collect();
    names.into_iter().collect()
}

/// D-MSE per row as bars, one group per dataset, ± the standard deviation over seeds (no error bar
/// from a single seed: there is no spread to show).
fn d_mse_chart(scores: &[Score]) -> BarChart {
    let seeds = scores.iter().map(|s| s.seed).collect::<std::collections::BTreeSet<_>>().len();
    let spread = if seeds > 1 {
        format!("mean ± standard deviation over {seeds} seeds")
    } else {
        "n = 1 seed: no spread to show".to_string()
    };
    let groups = datasets_of(scores)
        .into_iter()
        .map(|dataset| BarGroup {
            name: dataset.to_string(),
            bars: table_rows()
                .map(|row| {
                    let values: Vec<f64> =
                        scores.iter().filter(|s| s.row == row && s.dataset == dataset).map(|s| s.d_mse).collect();
                    bar(&values)
                })
                .collect(),
        })
        .collect();
    BarChart {
        title: format!("Ablations: D-MSE by row, {spread} (lower is better)"),
        y_label: "D-MSE (8-bit levels²)".to_string(),
        series: table_rows().map(str::to_string).collect(),
        groups,
    }
}

/// The bar of `values`: their mean, and their spread when there are two or more.
fn bar(values: &[f64]) -> Option<Bar> {
    if values.is_empty() {
        return None;
    }
    let (mean, std) = mean_std(values);
    Some(Bar { mean, std: (values.len() > 1).then_some(std) })
}

fn to_markdown(scores: &[Score], sweep: &Sweep) -> String {
    let mut out = String::new();
    let seeds: Vec<String> = sweep.seeds.iter().map(u64::to_string).collect();
    let _ = writeln!(out, "# Ablations: mean ± standard deviation over seeds {}\n", seeds.join(", "));
    for dataset in datasets_of(scores) {
        let _ = writeln!(out, "## {dataset}\n");
        let _ = writeln!(out, "| row | D-MSE | D-SSIM | TC | ms/frame | training minutes |");
        let _ = writeln!(out, "|---|---|---|---|---|---|");
        for row in table_rows() {
            let of: Vec<&Score> = scores.iter().filter(|s| s.row == row && s.dataset == dataset).collect();
            if of.is_empty() {
                continue;
            }
            let stat = |f: &dyn Fn(&Score) -> Option<f64>, digits: usize| {
                let values: Vec<f64> = of.iter().filter_map(|s| f(s)).collect();
                if values.is_empty() {
                    return "-".to_string();
                }
                let (m, s) = mean_std(&values);
                format!("{m:.digits$} ± {s:.digits$}")
            };
            let _ = writeln!(
                out,
                "| {row} | {} | {} | {} | {} | {} |",
                stat(&|s| Some(s.d_mse), 1),
                stat(&|s| Some(s.d_ssim), 4),
                stat(&|s| s.tc, 1),
                stat(&|s| Some(s.ms_per_frame), 0),
                stat(&|s| Some(s.train_minutes), 1)
            );
        }
        out.push('\n');
    }
    if sweep.seeds.len() > 1 {
        out.push_str(&differences_markdown(scores));
    }
    out.push_str("![D-MSE per row and dataset](ablations.svg)\n\n");
    let steps = sweep.steps.map_or(String::new(), |s| format!(" --steps {s}"));
    let quick = if sweep.quick { " --quick" } else { "" };
    let _ = writeln!(
        out,
        "Made by `cargo xtask ablate --seeds {}{steps}{quick} --out {}`.",
        seeds.join(","),
        sweep.out.display()
    );
    out
}

/// A row's D-MSE against `full`'s, seed by seed: the same seed gives both runs the same training
/// data, so the paired difference removes the part of the spread that the data and the seed share.
#[derive(Clone, Debug, PartialEq)]
struct Difference {
    row: &'static str,
    /// Mean and sample standard deviation of `row - full` over the seeds both have.
    mean: f64,
    std: f64,
    /// Seeds where the difference has the sign of the mean, out of `seeds`.
    agreeing: usize,
    seeds: usize,
    /// The larger of the two rows' standard deviations over seeds (unpaired).
    spread: f64,
}

impl Difference {
    /// Whether the difference is larger than the seed spread: its mean exceeds both the unpaired
    /// spread of either row and the paired spread, and every seed agrees on its sign.
    fn beyond_spread(&self) -> bool {
        self.mean.abs() > self.spread && self.mean.abs() > self.std && self.agreeing == self.seeds
    }
}

/// The paired difference of every row to `full` on `dataset` (rows with fewer than two shared
/// seeds are left out: one seed has no spread).
fn differences_to_full(scores: &[Score], dataset: &str) -> Vec<Difference> {
    let of = |row: &str| -> BTreeMap<u64, f64> {
        scores.iter().filter(|s| s.row == row && s.dataset == dataset).map(|s| (s.seed, s.d_mse)).collect()
    };
    let full = of("full");
    table_rows()
        .filter(|&row| row != "full")
        .filter_map(|row| {
            let this = of(row);
            let differences: Vec<f64> = this.iter().filter_map(|(seed, v)| full.get(seed).map(|f| v - f)).collect();
            if differences.len() < 2 {
                return None;
            }
            let (mean, std) = mean_std(&differences);
            let agreeing = differences.iter().filter(|d| d.signum() == mean.signum()).count();
            let spread_of = |values: &BTreeMap<u64, f64>| mean_std(&values.values().copied().collect::<Vec<_>>()).1;
            let spread = spread_of(&this).max(spread_of(&full));
            Some(Difference { row, mean, std, agreeing, seeds: differences.len(), spread })
        })
        .collect()
}

fn differences_markdown(scores: &[Score]) -> String {
    let mut out = String::from(
        "## Differences from `full`, paired by seed\n\n\
         D-MSE of the row minus D-MSE of `full` with the same seed (the same training data), mean ± \
         standard deviation over the seeds; \"seeds agreeing\" counts the seeds whose difference has \
         the mean's sign. A difference is called larger than the seed spread when its mean exceeds \
         the standard deviation over seeds of either row and of the paired differences, and every \
         seed agrees on its sign.\n\n",
    );
    for dataset in datasets_of(scores) {
        let differences = differences_to_full(scores, dataset);
        if differences.is_empty() {
            continue;
        }
        let _ = writeln!(
            out,
            "| {dataset}: row - full | D-MSE difference | seeds agreeing | larger than the seed spread |"
        );
        let _ = writeln!(out, "|---|---|---|---|");
        for d in differences {
            let verdict = if d.beyond_spread() { "yes" } else { "no" };
            let _ = writeln!(
                out,
                "| {} | {:+.1} ± {:.1} | {} of {} | {verdict} (spread {:.1}) |",
                d.row, d.mean, d.std, d.agreeing, d.seeds, d.spread
            );
        }
        out.push('\n');
    }
    out
}

/// Refuses seeds given twice (their rows would be counted twice in the spread).
pub fn check_seeds(seeds: &[u64]) -> Result<()> {
    let unique: std::collections::BTreeSet<_> = seeds.iter().collect();
    if unique.len() != seeds.len() || seeds.is_empty() {
        bail!("--seeds must list distinct seeds, got {seeds:?}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spread_is_the_sample_standard_deviation() {
        assert_eq!(mean_std(&[2.0, 4.0, 6.0]), (4.0, 2.0));
        assert_eq!(mean_std(&[5.0]), (5.0, 0.0));
        assert!(check_seeds(&[0, 1, 1]).is_err() && check_seeds(&[]).is_err() && check_seeds(&[0, 1]).is_ok());
    }

    fn score(row: &'static str, seed: u64, dataset: &str, d_mse: f64) -> Score {
        let dataset = dataset.to_string();
        Score { row, seed, dataset, d_mse, d_ssim: 0.8, tc: None, ms_per_frame: 3.0, train_minutes: 1.0 }
    }

    #[test]
    fn differences_are_paired_by_seed_and_judged_against_the_spread() {
        // no-depth is worse by 20-40 on every seed, much less than full's spread of 50 across
        // seeds; intensity by 200 on every seed; no-tg has one seed only: no spread, no row.
        let by_seed = [
            ("full", vec![400.0, 500.0, 450.0]),
            ("no-depth", vec![420.0, 540.0, 480.0]),
            ("intensity", vec![600.0, 700.0, 650.0]),
            ("no-tg", vec![900.0]),
        ];
        let scores: Vec<Score> = by_seed
            .into_iter()
            .flat_map(|(row, values)| values.into_iter().zip(0..).map(move |(v, seed)| score(row, seed, "g", v)))
            .collect();
        let differences = differences_to_full(&scores, "g");
        let rows: Vec<&str> = differences.iter().map(|d| d.row).collect();
        assert_eq!(rows, ["intensity", "no-depth"]);
        let (intensity, no_depth) = (&differences[0], &differences[1]);
        assert_eq!((intensity.mean, intensity.std, intensity.agreeing), (200.0, 0.0, 3));
        assert!(intensity.beyond_spread());
        assert_eq!((no_depth.mean, no_depth.std, no_depth.agreeing, no_depth.seeds), (30.0, 10.0, 3, 3));
        assert!((no_depth.spread - 60.0).abs() < 1e-9, "no-depth's own spread (60) is the larger");
        assert!(!no_depth.beyond_spread());
        let markdown = differences_markdown(&scores);
        assert!(markdown.contains("| intensity | +200.0 ± 0.0 | 3 of 3 | yes"), "{markdown}");
        assert!(markdown.contains("| no-depth | +30.0 ± 10.0 | 3 of 3 | no"), "{markdown}");
    }

    #[test]
    fn the_chart_has_a_group_per_dataset_and_error_bars_only_over_seeds() {
        let scores = [
            score("fill", 0, "generated", 580.0),
            score("full", 0, "generated", 400.0),
            score("full", 1, "generated", 440.0),
            score("full", 0, "blender-dev", 450.0),
        ];
        let chart = d_mse_chart(&scores);
        assert_eq!(chart.series, ["fill", "intensity", "no-tg", "no-depth", "no-iter", "full"]);
        let names: Vec<&str> = chart.groups.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(names, ["blender-dev", "generated"]);
        let generated = &chart.groups[1].bars;
        assert_eq!(generated[0], Some(Bar { mean: 580.0, std: None }));
        assert_eq!(generated[1], None);
        assert_eq!(generated[5], Some(Bar { mean: 420.0, std: Some(mean_std(&[400.0, 440.0]).1) }));
        assert!(chart.title.contains("2 seeds"));
        assert!(d_mse_chart(&scores[..2]).title.contains("n = 1"));
    }
}
