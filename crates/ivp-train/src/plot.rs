//! `loss.png` of a run: the training loss (top) and the validation D-MSE against `fill` (bottom),
//! both over steps. Drawn directly on an image: two line charts do not justify a plotting stack
//! that needs system fonts.

use std::path::Path;

use anyhow::Result;
use ivp_core::RgbImage;

use crate::metrics_csv::MetricsRow;
use crate::sheet::draw_text_in;

const WIDTH: usize = 900;
const PANEL_HEIGHT: usize = 300;
const MARGIN_LEFT: usize = 110;
const MARGIN: usize = 40;
const BLACK: [f32; 3] = [0.0, 0.0, 0.0];
const GREY: [f32; 3] = [0.8, 0.8, 0.8];
const BLUE: [f32; 3] = [0.1, 0.3, 0.85];
const ORANGE: [f32; 3] = [0.9, 0.45, 0.05];

/// Writes the two panels for `rows` to `path` (PNG, atomically).
pub fn write_loss_curve(path: &Path, rows: &[MetricsRow]) -> Result<()> {
    let mut image = RgbImage::filled(WIDTH, 2 * PANEL_HEIGHT, [1.0, 1.0, 1.0]);
    let loss: Vec<(f64, f64)> = rows.iter().map(|r| (r.step as f64, r.loss.total as f64)).collect();
    let validation: Vec<(f64, f64)> =
        rows.iter().filter_map(|r| r.validation.map(|v| (r.step as f64, v.d_mse))).collect();
    let fill = rows.first().map(|r| r.fill.d_mse);
    let max_step = rows.last().map_or(1.0, |r| r.step as f64).max(1.0);
    draw_panel(&mut image, 0, "training loss", &[(&loss, BLUE, false)], max_step);
    let fill_line: Vec<(f64, f64)> = fill.map_or(Vec::new(), |f| vec![(0.0, f), (max_step, f)]);
    draw_panel(
        &mut image,
        PANEL_HEIGHT,
        "validation D-MSE (blue) vs fill (orange)",
        &[(&validation, BLUE, true), (&fill_line, ORANGE, false)],
        max_step,
    );
    ivp_data::write_rgb_png(path, &image)?;
    Ok(())
}

/// One chart in the band of rows `top..top + PANEL_HEIGHT`; the y range covers every series.
/// A line through points (x, y), its colour, and whether to mark the points.
type Series<'a> = (&'a [(f64, f64)], [f32; 3], bool);

fn draw_panel(image: &mut RgbImage, top: usize, title: &str, series: &[Series<'_>], max_x: f64) {
    let (x0, x1) = (MARGIN_LEFT, WIDTH - MARGIN);
    let (y0, y1) = (top + MARGIN, top + PANEL_HEIGHT - MARGIN);
    draw_text_in(image, x0, top + 10, title, x1 - x0, BLACK);
    let values = series.iter().flat_map(|(s, _, _)| s.iter().map(|p| p.1)).filter(|v| v.is_finite());
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        draw_text_in(image, x0, (y0 + y1) / 2, "no data yet", x1 - x0, BLACK);
        return;
    }
    let pad = ((hi - lo) * 0.05).max(1e-9);
    let (lo, hi) = ((lo - pad).max(0.0), hi + pad);
    let to_px = |(x, y): (f64, f64)| -> (f64, f64) {
        (x0 as f64 + (x / max_x) * (x1 - x0) as f64, y1 as f64 - (y - lo) / (hi - lo) * (y1 - y0) as f64)
    };
    for i in 0..=4 {
        let y = y1 - i * (y1 - y0) / 4;
        line(image, (x0 as f64, y as f64), (x1 as f64, y as f64), GREY);
        let label = format!("{:.3}", lo + (hi - lo) * i as f64 / 4.0);
        draw_text_in(image, 4, y.saturating_sub(8), &label, MARGIN_LEFT - 8, BLACK);
    }
    line(image, (x0 as f64, y0 as f64), (x0 as f64, y1 as f64), BLACK);
    line(image, (x0 as f64, y1 as f64), (x1 as f64, y1 as f64), BLACK);
    draw_text_in(image, x1 - 16 * 10, y1 + 8, &format!("step {}", max_x as u64), 16 * 10, BLACK);
    for (points, colour, markers) in series {
        for pair in points.windows(2) {
            line(image, to_px(pair[0]), to_px(pair[1]), *colour);
        }
        if *markers {
            for &p in points.iter() {
                let (px, py) = to_px(p);
                for d in -2..=2 {
                    line(image, (px - 2.0, py + d as f64), (px + 2.0, py + d as f64), *colour);
                }
            }
        }
    }
}

/// A one-pixel line from `a` to `b`, clipped to the image.
fn line(image: &mut RgbImage, a: (f64, f64), b: (f64, f64), colour: [f32; 3]) {
    if !(a.0.is_finite() && a.1.is_finite() && b.0.is_finite() && b.1.is_finite()) {
        return;
    }
    let n = (b.0 - a.0).abs().max((b.1 - a.1).abs()).ceil().clamp(1.0, 10_000.0) as usize;
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let (x, y) = ((a.0 + t * (b.0 - a.0)).round(), (a.1 + t * (b.1 - a.1)).round());
        if x >= 0.0 && y >= 0.0 && (x as usize) < image.width() && (y as usize) < image.height() {
            image.set(x as usize, y as usize, colour);
        }
    }
}
