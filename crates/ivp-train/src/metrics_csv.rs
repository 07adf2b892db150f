//! `metrics.csv` of a training run: one row per logged step (the training losses averaged since the
//! previous row, the validation scores at 320x240 and 1920x1080 when the step validated, `fill` on
//! the same frames), read back when a run resumes and drawn by `plot`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{ensure, Context, Result};

use crate::validation::{ValidationReport, ValidationScores};

/// The loss terms of one training step, as numbers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossValues {
    pub mse: f32,
    pub ssim: f32,
    pub smooth: f32,
    /// The guide terms, already weighted: the fading guide (0 once it has faded) plus the
    /// foreground guard (`TrainConfig::foreground_guard`).
    pub guide: f32,
    pub total: f32,
    /// The global norm of the step's gradients before any clipping; a window keeps its largest.
    pub grad_norm: f32,
}

/// Training losses accumulated between two log rows.
#[derive(Default)]
pub struct LossWindow {
    sum: [f64; 5],
    max_grad_norm: f32,
    count: u32,
}

impl LossWindow {
    pub fn add(&mut self, l: &LossValues) {
        for (s, v) in self.sum.iter_mut().zip([l.mse, l.ssim, l.smooth, l.guide, l.total]) {
            *s += v as f64;
        }
        self.max_grad_norm = self.max_grad_norm.max(l.grad_norm);
        self.count += 1;
    }

    /// The mean since the last call (the largest gradient norm).
    pub fn take(&mut self) -> LossValues {
        let n = self.count.max(1) as f64;
        let m = self.sum.map(|s| (s / n) as f32);
        let grad_norm = self.max_grad_norm;
        *self = Self::default();
        LossValues { mse: m[0], ssim: m[1], smooth: m[2], guide: m[3], total: m[4], grad_norm }
    }
}

/// One row of `metrics.csv`.
#[derive(Clone, Debug)]
pub struct MetricsRow {
    pub step: u64,
    pub loss: LossValues,
    pub validation: Option<ValidationReport>,
    pub fill: ValidationReport,
    pub elapsed: Duration,
}

const METRICS_HEADER: &str = "step,mse,ssim,smooth,guide,total,val_d_mse,val_d_ssim,fill_d_mse,fill_d_ssim,\
                              val_hd_d_mse,val_hd_d_ssim,fill_hd_d_mse,fill_hd_d_ssim,\
                              val_real_d_mse,val_real_d_ssim,fill_real_d_mse,fill_real_d_ssim,max_grad_norm,elapsed_s";
const METRICS_FIELDS: usize = 20;
/// Rows of runs written before the real clips' and the gradient norm's columns existed.
const METRICS_FIELDS_WITHOUT_REAL: usize = 15;

/// Decimals of a D-MSE in `metrics.csv`.
const D_MSE_DECIMALS: usize = 3;

/// Two fields, D-MSE and D-SSIM, empty where there is no score.
fn score_fields(s: Option<ValidationScores>) -> String {
    s.map_or(",".to_string(), |s| format!("{:.*},{:.5}", D_MSE_DECIMALS, s.d_mse, s.d_ssim))
}

/// A D-MSE as `metrics.csv` holds it, for choices that a resumed run makes again from the file.
pub fn d_mse_as_logged(d_mse: f64) -> f64 {
    format!("{d_mse:.D_MSE_DECIMALS$}").parse().expect("a formatted number parses")
}

/// `metrics.csv`, rewritten atomically after every row so that it is always complete.
pub struct MetricsLog {
    path: PathBuf,
    rows: Vec<MetricsRow>,
}

impl MetricsLog {
    pub fn new(path: PathBuf) -> Self {
        Self { path, rows: Vec::new() }
    }

    /// The log of a run resumed at `step`: rows after it are dropped (they will be run again).
    pub fn resume(path: PathBuf, step: u64) -> Result<Self> {
        let mut rows = Vec::new();
        if path.exists() {
            let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
            for (i, line) in text.lines().enumerate().skip(1) {
                let row =
                    parse_row(line).with_context(|| format!("{}: line {}: malformed row", path.display(), i + 1))?;
                if row.step <= step {
                    rows.push(row);
                }
            }
        }
        Ok(Self { path, rows })
    }

    pub fn push(&mut self, row: MetricsRow) {
        self.rows.push(row);
    }

    pub fn rows(&self) -> &[MetricsRow] {
        &self.rows
    }

    pub fn last_mut(&mut self) -> Option<&mut MetricsRow> {
        self.rows.last_mut()
    }

    pub fn last_elapsed(&self) -> Duration {
        self.rows.last().map_or(Duration::ZERO, |r| r.elapsed)
    }

    pub fn save(&self) -> Result<()> {
        let mut text = String::from(METRICS_HEADER);
        text.push('\n');
        for r in &self.rows {
            let v = r.validation.unwrap_or_default();
            text.push_str(&format!(
                "{},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{},{},{},{:.4},{:.1}\n",
                r.step,
                r.loss.mse,
                r.loss.ssim,
                r.loss.smooth,
                r.loss.guide,
                r.loss.total,
                score_fields(v.small),
                score_fields(r.fill.small),
                score_fields(v.large),
                score_fields(r.fill.large),
                score_fields(v.real),
                score_fields(r.fill.real),
                r.loss.grad_norm,
                r.elapsed.as_secs_f64()
            ));
        }
        ivp_data::write_atomically(&self.path, text.as_bytes())?;
        Ok(())
    }
}

fn parse_row(line: &str) -> Result<MetricsRow> {
    let f: Vec<&str> = line.split(',').collect();
    ensure!(
        f.len() == METRICS_FIELDS || f.len() == METRICS_FIELDS_WITHOUT_REAL,
        "{} fields, expected {METRICS_FIELDS} (or {METRICS_FIELDS_WITHOUT_REAL} in runs of older versions)",
        f.len()
    );
    let current = f.len() == METRICS_FIELDS;
    let num =
        |i: usize| -> Result<f64> { f[i].parse::<f64>().with_context(|| format!("field {} is `{}`", i + 1, f[i])) };
    let scores = |i: usize| -> Result<Option<ValidationScores>> {
        (!f[i].is_empty()).then(|| Ok(ValidationScores { d_mse: num(i)?, d_ssim: num(i + 1)? })).transpose()
    };
    let report = |small: usize, large: usize, real: usize| -> Result<ValidationReport> {
        let real = if current { scores(real)? } else { None };
        Ok(ValidationReport { small: scores(small)?, large: scores(large)?, real })
    };
    let validation = report(6, 10, 14)?;
    Ok(MetricsRow {
        step: f[0].parse().with_context(|| format!("step `{}`", f[0]))?,
        loss: LossValues {
            mse: num(1)? as f32,
            ssim: num(2)? as f32,
            smooth: num(3)? as f32,
            guide: num(4)? as f32,
            total: num(5)? as f32,
            grad_norm: if current { num(18)? as f32 } else { 0.0 },
        },
        validation: (validation != ValidationReport::default()).then_some(validation),
        fill: report(8, 12, 16)?,
        elapsed: Duration::from_secs_f64(num(f.len() - 1)?.max(0.0)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(d_mse: f64, d_ssim: f64) -> ValidationReport {
        ValidationReport {
            small: Some(ValidationScores { d_mse, d_ssim }),
            large: Some(ValidationScores { d_mse: 2.0 * d_mse, d_ssim }),
            real: Some(ValidationScores { d_mse: 3.0 * d_mse, d_ssim }),
        }
    }

    fn row(step: u64, validation: Option<ValidationReport>) -> MetricsRow {
        let loss = LossValues { mse: 0.5, ssim: 0.25, smooth: 0.125, guide: 0.0, total: 0.875, grad_norm: 2.5 };
        let fill = ValidationReport { large: None, ..report(581.5, 0.75) };
        MetricsRow { step, loss, validation, fill, elapsed: Duration::from_secs(step) }
    }

    #[test]
    fn a_resumed_log_keeps_the_rows_up_to_its_step() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("metrics.csv");
        let mut log = MetricsLog::new(path.clone());
        log.push(row(25, None));
        log.push(row(50, Some(report(400.25, 0.5))));
        log.push(row(75, None));
        log.save().unwrap();
        let resumed = MetricsLog::resume(path, 50).unwrap();
        let steps: Vec<u64> = resumed.rows().iter().map(|r| r.step).collect();
        assert_eq!(steps, [25, 50]);
        assert_eq!(resumed.rows()[1].validation, Some(report(400.25, 0.5)));
        assert_eq!(resumed.rows()[1].fill, row(50, None).fill, "a size without frames reads back as none");
        assert_eq!(resumed.rows()[0].loss, row(25, None).loss);
        assert_eq!(resumed.last_elapsed(), Duration::from_secs(50));
    }

    #[test]
    fn rows_of_runs_before_the_real_clips_columns_still_read() {
        // The last row of results/ablate/full/seed0/metrics.csv's format (15 fields).
        let old = "5000,0.003326,0.052108,0.713894,0.000000,0.056148,233.725,0.84265,350.641,0.79422,,,,,1501.4";
        let row = parse_row(old).unwrap();
        let scores = |d_mse, d_ssim| Some(ValidationScores { d_mse, d_ssim });
        assert_eq!(row.validation, Some(ValidationReport { small: scores(233.725, 0.84265), large: None, real: None }));
        assert_eq!(row.fill, ValidationReport { small: scores(350.641, 0.79422), large: None, real: None });
        assert_eq!((row.step, row.elapsed), (5000, Duration::from_secs_f64(1501.4)));
        assert!(parse_row(&old.replacen(",1501.4", ",,1501.4", 1)).is_err(), "16 fields is neither format");
    }

    #[test]
    fn losses_are_averaged_over_the_steps_of_a_row() {
        let mut window = LossWindow::default();
        window.add(&LossValues { total: 1.0, grad_norm: 4.0, ..Default::default() });
        window.add(&LossValues { total: 3.0, grad_norm: 0.5, ..Default::default() });
        let mean = window.take();
        assert_eq!((mean.total, mean.grad_norm), (2.0, 4.0), "the mean loss, the largest norm");
        assert_eq!(window.take().total, 0.0, "take starts a new window");
    }
}
