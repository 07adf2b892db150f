//! The charts of a report with several models: D-MSE against time per frame, and D-MSE by method,
//! drawn as SVG with ivp-plot.

use ivp_plot::plotters::prelude::*;
use ivp_plot::plotters::style::text_anchor::{HPos, Pos, VPos};
use ivp_plot::{colour, house_style, register_font, tick_label, Axis, FONT};

use crate::eval::MethodReport;
use crate::report::error::ReportError;

/// Both charts side by side fit a window 1280 pixels wide.
pub const SIZE: (u32, u32) = (600, 360);

fn drawing<E: std::error::Error + Send + Sync>(what: &'static str) -> impl Fn(DrawingAreaErrorKind<E>) -> ReportError {
    move |e| ReportError::Drawing { what, message: e.to_string() }
}

/// D-MSE against ms/frame, one labelled point per method that has both (external methods have no
/// time; methods that read the ground truth are left out: they are references). `None` with
/// fewer than two points.
pub fn d_mse_against_time_svg(methods: &[MethodReport]) -> Result<Option<String>, ReportError> {
    let points: Vec<(usize, &str, f64, f64)> = methods
        .iter()
        .enumerate()
        .filter(|(_, m)| !m.uses_ground_truth)
        .filter_map(|(i, m)| Some((i, m.name.as_str(), m.ms_per_frame?, m.d_mse?)))
        .filter(|p| p.2.is_finite() && p.3.is_finite())
        .collect();
    if points.len() < 2 {
        return Ok(None);
    }
    let what = "the chart of D-MSE against time";
    let (Some(x), Some(y)) =
        (Axis::fitting(points.iter().map(|p| p.2.max(0.01))), Axis::fitting(points.iter().map(|p| p.3)))
    else {
        return Ok(None);
    };
    register_font();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing(what))?;
        let (x_desc, y_desc) = (x.describe("ms per frame"), y.describe("D-MSE (lower is better)"));
        let mut chart = ChartBuilder::on(&root)
            .caption("D-MSE against time per frame", (FONT, 18))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(x, y)
            .map_err(drawing(what))?;
        house_style(&mut chart.configure_mesh())
            .x_desc(x_desc)
            .y_desc(y_desc)
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| tick_label(*v))
            .draw()
            .map_err(drawing(what))?;
        let label = (FONT, 14).into_font().color(&BLACK).pos(Pos::new(HPos::Left, VPos::Center));
        for &(i, name, ms, d_mse) in &points {
            let at = (ms.max(0.01), d_mse);
            chart.draw_series([Circle::new(at, 5, colour(i).filled())]).map_err(drawing(what))?;
            chart
                .draw_series([EmptyElement::at(at) + Text::new(name.to_string(), (9, 0), label.clone())])
                .map_err(drawing(what))?;
        }
        root.present().map_err(drawing(what))?;
    }
    Ok(Some(svg))
}

/// D-MSE by method as bars, with the value above each.
pub fn d_mse_bars_svg(methods: &[MethodReport]) -> Result<Option<String>, ReportError> {
    let bars: Vec<(usize, &str, f64)> = methods
        .iter()
        .enumerate()
        .filter_map(|(i, m)| Some((i, m.name.as_str(), m.d_mse?)))
        .filter(|b| b.2.is_finite())
        .collect();
    if bars.is_empty() {
        return Ok(None);
    }
    let what = "the bars of D-MSE";
    let top = bars.iter().map(|b| b.2).fold(0.0, f64::max).max(1e-9) * 1.15;
    let names: Vec<&str> = bars.iter().map(|b| b.1).collect();
    let name_at = |x: &f64| match names.get(x.round() as usize) {
        Some(n) if (x - x.round()).abs() < 1e-6 && *x > -0.5 => n.to_string(),
        _ => String::new(),
    };
    register_font();
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(drawing(what))?;
        let mut chart = ChartBuilder::on(&root)
            .caption("D-MSE by method (lower is better)", (FONT, 18))
            .margin(14)
            .x_label_area_size(44)
            .y_label_area_size(70)
            .build_cartesian_2d(Axis::linear(-0.5..bars.len() as f64 - 0.5), Axis::linear(0.0..top))
            .map_err(drawing(what))?;
        house_style(&mut chart.configure_mesh())
            .disable_x_mesh()
            .x_labels(bars.len())
            .x_label_formatter(&name_at)
            .y_desc("D-MSE")
            .y_label_formatter(&|v| tick_label(*v))
            .draw()
            .map_err(drawing(what))?;
        let value = (FONT, 13).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Bottom));
        for (k, &(i, _, d_mse)) in bars.iter().enumerate() {
            let x = k as f64;
            chart
                .draw_series([Rectangle::new([(x - 0.35, 0.0), (x + 0.35, d_mse)], colour(i).filled())])
                .map_err(drawing(what))?;
            chart
                .draw_series([Text::new(tick_label(d_mse), (x, d_mse + top * 0.01), value.clone())])
                .map_err(drawing(what))?;
        }
        root.present().map_err(drawing(what))?;
    }
    Ok(Some(svg))
}
