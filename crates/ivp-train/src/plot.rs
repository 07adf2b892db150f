//! `loss.png` of a run: the training loss and its terms (top) and the validation D-MSE against
//! `fill` (bottom), both over steps, with ticks, axis labels and a legend; a log axis where the
//! values span decades. Dashed lines mark the steps where the recipe changes what it trains on or
//! how (a jump of the loss there is the recipe, not a fault), and a band marks the steps the model
//! file averages. Drawn with plotters through ivp-plot (the font is compiled in).

use std::path::Path;

use anyhow::{anyhow, Result};
use ivp_core::RgbImage;
use ivp_plot::plotters::coord::Shift;
use ivp_plot::plotters::prelude::*;
use ivp_plot::{draw_legend, house_style, register_font, tick_label, Axis, LegendEntry, Mark, Stroke, FONT};

use crate::metrics_csv::MetricsRow;
use crate::validation::{ValidationReport, ValidationScores};

const WIDTH: u32 = 1150;
const PANEL_HEIGHT: u32 = 380;
/// Room for the legend, right of each plot.
const LEGEND_WIDTH: u32 = 250;

/// A line through points (step, value), drawn in its colour with a legend entry.
struct Curve {
    label: String,
    colour: RGBColor,
    points: Vec<(f64, f64)>,
    /// Mark every point (sparse series such as the validations).
    markers: bool,
}

/// One chart: its title, the label of its y axis, and its curves.
struct Panel {
    title: &'static str,
    y_label: &'static str,
    curves: Vec<Curve>,
}

/// What `loss.png` marks beside the curves.
#[derive(Clone, Debug, Default)]
pub struct Marks {
    /// Steps where the training changes, each with what changes there (the training loop passes
    /// its configuration's schedule).
    pub changes: Vec<(u64, String)>,
    /// The steps whose parameters the model file averages (empty while there is none).
    pub model_steps: Vec<u64>,
}

// Not a grey: text is anti-aliased in greys.
const CHANGE_COLOUR: RGBColor = RGBColor(170, 50, 110);
const MODEL_BAND: RGBColor = RGBColor(255, 224, 150);

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Writes the two panels for `rows` to `path` (PNG, atomically), with `marks`.
pub fn write_loss_curve(path: &Path, rows: &[MetricsRow], marks: &Marks) -> Result<()> {
    register_font();
    let max_step = rows.last().map_or(1.0, |r| r.step as f64).max(1.0);
    // A run stopped early has not reached its later changes.
    let changes = marks.changes.iter().filter(|c| c.0 as f64 <= max_step).cloned().collect();
    let marks = &Marks { changes, model_steps: marks.model_steps.clone() };
    let panels = [loss_panel(rows), validation_panel(rows, max_step)];
    let (width, height) = (WIDTH, 2 * PANEL_HEIGHT);
    let mut pixels = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        for (area, panel) in root.split_evenly((2, 1)).iter().zip(&panels) {
            let (plot, legend) = area.split_horizontally(WIDTH - LEGEND_WIDTH);
            draw_panel(&plot, &legend, panel, max_step, marks)?;
        }
        root.present().map_err(|e| anyhow!("drawing the loss curve: {e}"))?;
    }
    let colours = pixels.chunks_exact(3).map(|p| [p[0], p[1], p[2]].map(|b| b as f32 / 255.0));
    let image = RgbImage::from_pixels(width as usize, height as usize, colours.collect());
    ivp_data::write_rgb_png(path, &image)?;
    Ok(())
}

/// Reads one loss term from a row.
type LossTerm = fn(&MetricsRow) -> f32;

/// The training loss and each of its terms that is not always 0.
fn loss_panel(rows: &[MetricsRow]) -> Panel {
    let terms: [(&str, LossTerm); 5] = [
        ("total (weighted sum)", |r| r.loss.total),
        ("masked MSE", |r| r.loss.mse),
        ("SSIM term", |r| r.loss.ssim),
        ("smoothness (unweighted)", |r| r.loss.smooth),
        ("guide terms (weighted)", |r| r.loss.guide),
    ];
    let curves = terms
        .into_iter()
        .enumerate()
        .map(|(i, (label, value))| Curve {
            label: label.to_string(),
            colour: ivp_plot::colour(i),
            points: rows.iter().map(|r| (r.step as f64, value(r) as f64)).collect(),
            markers: false,
        })
        .filter(|c| c.points.iter().any(|p| p.1 != 0.0))
        .collect();
    Panel { title: "Training loss (mean over each logging window)", y_label: "loss", curves }
}

/// The network's validation D-MSE at each size as a ratio to `fill`'s on the same frames (1: as
/// good as `fill`), so that both sizes share one axis.
fn validation_panel(rows: &[MetricsRow], max_step: f64) -> Panel {
    type SizeOf = fn(&ValidationReport) -> Option<ValidationScores>;
    let sizes: [(&str, SizeOf); 3] = [("320x240", |r| r.small), ("1920x1080", |r| r.large), ("real clips", |r| r.real)];
    let mut curves = Vec::new();
    // fill's line takes colour 2.
    for ((name, size), colour) in sizes.into_iter().zip([0, 1, 3]) {
        let points: Vec<(f64, f64)> = rows
            .iter()
            .filter_map(|r| {
                let (v, f) = (size(r.validation.as_ref()?)?, size(&r.fill)?);
                Some((r.step as f64, v.d_mse / f.d_mse))
            })
            .collect();
        if !points.is_empty() {
            curves.push(Curve {
                label: format!("network, {name}"),
                colour: ivp_plot::colour(colour),
                points,
                markers: true,
            });
        }
    }
    if !rows.is_empty() {
        curves.push(Curve {
            label: "fill".to_string(),
            colour: ivp_plot::colour(2),
            points: vec![(0.0, 1.0), (max_step, 1.0)],
            markers: false,
        });
    }
    Panel {
        title: "Validation D-MSE on fixed whole frames, as a ratio to fill's (lower is better)",
        y_label: "D-MSE / fill's",
        curves,
    }
}

/// The chart of `panel` on `area`, its legend on `legend`.
fn draw_panel(area: &Area<'_>, legend: &Area<'_>, panel: &Panel, max_step: f64, marks: &Marks) -> Result<()> {
    let err = |e: DrawingAreaErrorKind<_>| anyhow!("drawing {}: {e}", panel.title);
    let Some(y) = Axis::fitting(panel.curves.iter().flat_map(|c| c.points.iter().map(|p| p.1))) else {
        let inner = area.titled(panel.title, (FONT, 22)).map_err(err)?;
        let (w, h) = inner.dim_in_pixel();
        let style = (FONT, 18).into_font().color(&BLACK);
        return inner.draw_text("no data yet", &style, (w as i32 / 2 - 50, h as i32 / 2)).map_err(err);
    };
    let y_label = y.describe(panel.y_label);
    let mut chart = ChartBuilder::on(area)
        .caption(panel.title, (FONT, 22))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(84)
        .build_cartesian_2d(Axis::linear(0.0..max_step), y.clone())
        .map_err(err)?;
    house_style(&mut chart.configure_mesh())
        .x_desc("training step")
        .y_desc(y_label)
        .y_labels(10)
        .x_label_formatter(&|x| format!("{x:.0}"))
        .y_label_formatter(&|v| tick_label(*v))
        .draw()
        .map_err(err)?;
    let (bottom, top) = (y.range().start, y.range().end);
    let model_band = match (marks.model_steps.first(), marks.model_steps.last()) {
        // A window of one step still gets a visible band.
        (Some(&first), Some(&last)) => Some((first as f64, (last as f64).max(first as f64 + max_step / 200.0))),
        _ => None,
    };
    if let Some((first, last)) = model_band {
        chart.draw_series([Rectangle::new([(first, bottom), (last, top)], MODEL_BAND.filled())]).map_err(err)?;
    }
    let label_style = (FONT, 14).into_font().color(&CHANGE_COLOUR);
    for (step, what) in &marks.changes {
        let x = *step as f64;
        let line = DashedLineSeries::new([(x, bottom), (x, top)], 6, 4, CHANGE_COLOUR.stroke_width(1));
        chart.draw_series(line).map_err(err)?;
        let label = EmptyElement::at((x, top)) + Text::new(what.clone(), (4, 4), label_style.clone());
        chart.draw_series([label]).map_err(err)?;
    }
    for curve in &panel.curves {
        let colour = curve.colour;
        // A log axis has no place for 0: a term that fades out ends where it reaches 0.
        let points: Vec<(f64, f64)> = curve.points.iter().filter(|p| y.shows(p.1)).copied().collect();
        chart.draw_series(LineSeries::new(points.clone(), colour.stroke_width(2))).map_err(err)?;
        if curve.markers {
            chart.draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled()))).map_err(err)?;
        }
    }
    let mut entries: Vec<LegendEntry> = panel
        .curves
        .iter()
        .map(|c| LegendEntry {
            label: c.label.clone(),
            colour: c.colour,
            mark: Mark::Line { stroke: Stroke::Solid, marker: c.markers },
        })
        .collect();
    if !marks.changes.is_empty() {
        let mark = Mark::Line { stroke: Stroke::Dashed, marker: false };
        entries.push(LegendEntry { label: "the recipe changes".to_string(), colour: CHANGE_COLOUR, mark });
    }
    if model_band.is_some() {
        entries.push(LegendEntry { label: "steps of the model file".to_string(), colour: MODEL_BAND, mark: Mark::Bar });
    }
    draw_legend(legend, None, &entries).map_err(err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics_csv::LossValues;

    #[test]
    fn writes_a_png_with_and_without_validations() {
        let dir = tempfile::tempdir().unwrap();
        let scores = |d_mse: f64| ValidationReport {
            small: Some(ValidationScores { d_mse, d_ssim: 0.8 }),
            large: Some(ValidationScores { d_mse: 1.5 * d_mse, d_ssim: 0.7 }),
            real: Some(ValidationScores { d_mse: 2.0 * d_mse, d_ssim: 0.6 }),
        };
        let fill = scores(350.0);
        let row = |step: u64, total: f32, validation: Option<f64>| MetricsRow {
            step,
            loss: LossValues { mse: total / 5.0, ssim: total * 0.8, smooth: 0.0, guide: 0.0, total, grad_norm: 1.0 },
            validation: validation.map(scores),
            fill,
            elapsed: std::time::Duration::from_secs(step),
        };
        let rows = [row(25, 0.5, None), row(50, 0.2, Some(420.0)), row(75, 0.01, Some(300.0))];
        for (name, rows) in [("loss.png", &rows[..]), ("empty.png", &[][..])] {
            write_loss_curve(&dir.path().join(name), rows, &Marks::default()).unwrap();
            let image = ivp_data::read_rgb(dir.path().join(name)).unwrap();
            assert_eq!((image.width(), image.height()), (WIDTH as usize, 2 * PANEL_HEIGHT as usize));
        }
    }

    #[test]
    fn marks_the_changes_of_the_recipe_and_the_steps_of_the_model() {
        let dir = tempfile::tempdir().unwrap();
        let row = |step: u64, total: f32| MetricsRow {
            step,
            loss: LossValues { mse: total / 5.0, ssim: total * 0.8, smooth: 0.0, guide: 0.0, total, grad_norm: 1.0 },
            validation: None,
            fill: ValidationReport { small: None, large: None, real: None },
            elapsed: std::time::Duration::from_secs(step),
        };
        let rows: Vec<MetricsRow> = (1..=20).map(|i| row(25 * i, 1.0 / i as f32)).collect();
        let count = |image: &RgbImage, colour: RGBColor| {
            let want = [colour.0, colour.1, colour.2].map(|b| b as f32 / 255.0);
            image.pixels().iter().filter(|p| p.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-3)).count()
        };
        let marks = Marks { changes: vec![(250, "MSE term x10".into())], model_steps: vec![400, 425, 450] };
        let (plain, marked) = (dir.path().join("plain.png"), dir.path().join("marked.png"));
        write_loss_curve(&plain, &rows, &Marks::default()).unwrap();
        write_loss_curve(&marked, &rows, &marks).unwrap();
        let (plain, marked) = (ivp_data::read_rgb(plain).unwrap(), ivp_data::read_rgb(marked).unwrap());
        assert_eq!(count(&plain, MODEL_BAND) + count(&plain, CHANGE_COLOUR), 0);
        // The band spans 50 of 500 steps over both panels' plotting areas (about 80 px wide).
        assert!(count(&marked, MODEL_BAND) > 10_000, "{}", count(&marked, MODEL_BAND));
        assert!(count(&marked, CHANGE_COLOUR) > 100, "{}", count(&marked, CHANGE_COLOUR));
    }

    #[test]
    fn a_run_stopped_before_a_change_does_not_mark_it() {
        let dir = tempfile::tempdir().unwrap();
        let row = |step: u64| MetricsRow {
            step,
            loss: LossValues { mse: 0.1, ssim: 0.5, smooth: 0.0, guide: 0.0, total: 0.6, grad_norm: 1.0 },
            validation: None,
            fill: ValidationReport { small: None, large: None, real: None },
            elapsed: std::time::Duration::from_secs(1),
        };
        let marks = Marks { changes: vec![(2500, "near columns".into())], model_steps: vec![] };
        let (early, late) = (dir.path().join("early.png"), dir.path().join("late.png"));
        write_loss_curve(&early, &[row(25), row(1000)], &marks).unwrap();
        write_loss_curve(&late, &[row(25), row(3000)], &marks).unwrap();
        let grey = |path| {
            let image: RgbImage = ivp_data::read_rgb(path).unwrap();
            let want = [CHANGE_COLOUR.0, CHANGE_COLOUR.1, CHANGE_COLOUR.2].map(|b| b as f32 / 255.0);
            image.pixels().iter().filter(|p| p.iter().zip(&want).all(|(a, b)| (a - b).abs() < 1e-3)).count()
        };
        assert_eq!(grey(&early), 0);
        assert!(grey(&late) > 100);
    }
}
