//! The SVG charts of the xtask reports: the ablation bars with their spread over seeds, and time
//! per frame against error with the Pareto front. Text is laid out with DejaVu Sans (compiled into
//! ivp-plot) and written as SVG text: writing needs no system font, and any viewer's sans-serif
//! font fits the space left for it.

use std::path::Path;

use anyhow::{anyhow, Context, Result};
use ivp_plot::plotters::coord::Shift;
use ivp_plot::plotters::prelude::*;
use ivp_plot::plotters::style::text_anchor::{HPos, Pos, VPos};
use ivp_plot::{colour, draw_legend, house_style, register_font, tick_label, Axis, LegendEntry, Mark, Stroke, FONT};

/// Widths of the legend columns: the bar chart's names are short, the speed chart's are not.
const BAR_LEGEND_WIDTH: u32 = 200;
const TIMED_LEGEND_WIDTH: u32 = 330;

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

fn drawing_error<E: std::error::Error + Send + Sync>(
    what: &str,
) -> impl Fn(DrawingAreaErrorKind<E>) -> anyhow::Error + '_ {
    move |e| anyhow!("drawing {what}: {e}")
}

/// Bars of several series in groups, each with its spread.
pub struct BarChart {
    pub title: String,
    pub y_label: String,
    /// The series, in the order of the bars of every group (legend labels).
    pub series: Vec<String>,
    pub groups: Vec<BarGroup>,
}

/// One group of bars (a dataset): one optional bar per series.
pub struct BarGroup {
    pub name: String,
    pub bars: Vec<Option<Bar>>,
}

/// A bar: the mean and, over more than one value, the standard deviation drawn as ± error bars.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bar {
    pub mean: f64,
    pub std: Option<f64>,
}

/// Writes `chart` as an SVG file.
pub fn write_bar_chart(path: &Path, chart: &BarChart) -> Result<()> {
    register_font();
    let plot_width = (260 * chart.groups.len().max(1) as u32).max(560);
    let size = (plot_width + BAR_LEGEND_WIDTH, 580);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error("the background"))?;
        let root = root.titled(&chart.title, (FONT, 19)).map_err(drawing_error(&chart.title))?;
        let (plot, legend) = root.split_horizontally(plot_width);
        draw_bars(&plot, chart)?;
        let entries: Vec<LegendEntry> = chart
            .series
            .iter()
            .enumerate()
            .map(|(i, label)| LegendEntry { label: label.clone(), colour: colour(i), mark: Mark::Bar })
            .collect();
        draw_legend(&legend, Some("rows"), &entries).map_err(drawing_error("the legend"))?;
        root.present().map_err(drawing_error(&chart.title))?;
    }
    std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))
}

fn draw_bars(area: &Area<'_>, chart: &BarChart) -> Result<()> {
    let err = drawing_error(&chart.title);
    let top = chart
        .groups
        .iter()
        .flat_map(|g| g.bars.iter().flatten())
        .map(|b| b.mean + b.std.unwrap_or(0.0))
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let groups = chart.groups.len().max(1);
    let names: Vec<&str> = chart.groups.iter().map(|g| g.name.as_str()).collect();
    // Group g is centred on x = g: at most `groups` labels fall on the whole numbers.
    let group_name = |x: &f64| match names.get(x.round() as usize) {
        Some(name) if (x - x.round()).abs() < 1e-6 && *x > -0.5 => name.to_string(),
        _ => String::new(),
    };
    let mut plot = ChartBuilder::on(area)
        .margin(14)
        .x_label_area_size(44)
        .y_label_area_size(78)
        .build_cartesian_2d(Axis::linear(-0.5..groups as f64 - 0.5), Axis::linear(0.0..(top * 1.15).max(1e-9)))
        .map_err(&err)?;
    house_style(&mut plot.configure_mesh())
        .disable_x_mesh()
        .x_desc("dataset")
        .y_desc(chart.y_label.as_str())
        .x_labels(groups)
        .x_label_formatter(&group_name)
        .y_label_formatter(&|y| tick_label(*y))
        .draw()
        .map_err(&err)?;
    let slot = 0.84 / chart.series.len().max(1) as f64;
    let value_style = (FONT, 12).into_font().color(&BLACK).pos(Pos::new(HPos::Center, VPos::Bottom));
    for (g, group) in chart.groups.iter().enumerate() {
        for (i, bar) in group.bars.iter().enumerate() {
            let Some(bar) = bar.filter(|b| b.mean.is_finite()) else { continue };
            let left = g as f64 - 0.42 + i as f64 * slot;
            let (x0, x1, centre) = (left + 0.08 * slot, left + 0.92 * slot, left + slot / 2.0);
            plot.draw_series([Rectangle::new([(x0, 0.0), (x1, bar.mean)], colour(i).filled())]).map_err(&err)?;
            let mut label_at = bar.mean;
            if let Some(std) = bar.std.filter(|s| *s > 0.0) {
                plot.draw_series(whisker(centre, bar.mean - std, bar.mean + std, 0.25 * slot)).map_err(&err)?;
                label_at = bar.mean + std;
            }
            let value = Text::new(tick_label(bar.mean), (centre, label_at + top * 0.015), value_style.clone());
            plot.draw_series([value]).map_err(&err)?;
        }
    }
    Ok(())
}

/// An error bar from `lo` to `hi` at `x`, with caps `half_width` wide on each side (plotters'
/// `ErrorBar` also rings the mean, which the bar already shows).
fn whisker(x: f64, lo: f64, hi: f64, half_width: f64) -> Vec<PathElement<(f64, f64)>> {
    let style = BLACK.stroke_width(2);
    let cap = |y: f64| PathElement::new([(x - half_width, y), (x + half_width, y)], style);
    vec![PathElement::new([(x, lo), (x, hi)], style), cap(lo), cap(hi)]
}

/// A point of a speed-against-error chart.
#[derive(Clone, Debug, PartialEq)]
pub struct TimedPoint {
    pub ms: f64,
    pub error: f64,
    /// Not dominated in both time and error by another point of its panel.
    pub on_front: bool,
    /// Written beside the marker (the iterations, `P3`), if any.
    pub tag: Option<String>,
}

/// The points of one method (or one model at one coverage).
pub struct TimedSeries {
    pub name: String,
    pub colour: RGBColor,
    /// Joined by a line (the iterations of a model); markers are hollow unless the line is solid.
    pub line: Option<Stroke>,
    pub points: Vec<TimedPoint>,
}

/// One dataset's chart.
pub struct TimedPanel {
    pub title: String,
    pub series: Vec<TimedSeries>,
}

/// Writes the panels (stacked) with one legend for them all, as SVG, both axes on log scales.
pub fn write_speed_vs_error(
    path: &Path,
    title: &str,
    x_label: &str,
    y_label: &str,
    panels: &[TimedPanel],
) -> Result<()> {
    register_font();
    const PANEL: (u32, u32) = (900, 430);
    let size = (PANEL.0 + TIMED_LEGEND_WIDTH, 50 + PANEL.1 * panels.len().max(1) as u32);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(drawing_error("the background"))?;
        let root = root.titled(title, (FONT, 22)).map_err(drawing_error(title))?;
        let (plots, legend) = root.split_horizontally(PANEL.0);
        let areas = plots.split_evenly((panels.len().max(1), 1));
        for (area, panel) in areas.iter().zip(panels) {
            draw_timed_panel(area, panel, x_label, y_label)?;
        }
        draw_legend(&legend, Some("methods"), &timed_legend(panels)).map_err(drawing_error("the legend"))?;
        root.present().map_err(drawing_error(title))?;
    }
    std::fs::write(path, svg).with_context(|| format!("writing {}", path.display()))
}

/// One entry per series name (in order of first appearance), and the Pareto front.
fn timed_legend(panels: &[TimedPanel]) -> Vec<LegendEntry> {
    let mut entries: Vec<LegendEntry> = Vec::new();
    for series in panels.iter().flat_map(|p| &p.series) {
        if entries.iter().any(|e| e.label == series.name) {
            continue;
        }
        let mark = match series.line {
            Some(stroke) => Mark::Line { stroke, marker: true },
            None => Mark::Point { filled: true },
        };
        entries.push(LegendEntry { label: series.name.clone(), colour: series.colour, mark });
    }
    entries.push(LegendEntry { label: "Pareto front".to_string(), colour: BLACK, mark: Mark::Ring });
    entries
}

fn draw_timed_panel(area: &Area<'_>, panel: &TimedPanel, x_label: &str, y_label: &str) -> Result<()> {
    let err = drawing_error(&panel.title);
    let points = || panel.series.iter().flat_map(|s| &s.points);
    // Both on log axes: times span decades, and errors compare by ratio (warp's black holes would
    // otherwise squeeze the methods worth comparing into a band).
    let (Some(x), Some(y)) = (Axis::log_fitting(points().map(|p| p.ms)), Axis::log_fitting(points().map(|p| p.error)))
    else {
        let inner = area.titled(&panel.title, (FONT, 19)).map_err(&err)?;
        return inner.draw_text("no measurement", &(FONT, 16).into_font().color(&BLACK), (380, 150)).map_err(&err);
    };
    let (x_label, y_label) = (x.describe(x_label), y.describe(y_label));
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FONT, 19))
        .margin(14)
        .x_label_area_size(46)
        .y_label_area_size(78)
        .build_cartesian_2d(x.clone(), y.clone())
        .map_err(&err)?;
    house_style(&mut chart.configure_mesh())
        .x_desc(x_label)
        .y_desc(y_label)
        .x_labels(12)
        .y_labels(10)
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .draw()
        .map_err(&err)?;
    let drawable = |p: &&TimedPoint| x.shows(p.ms) && y.shows(p.error);
    // The front first, under the markers: a staircase through its points in time order (what lies
    // above and right of it is dominated), a ring on each.
    let mut front: Vec<(f64, f64)> =
        points().filter(drawable).filter(|p| p.on_front).map(|p| (p.ms, p.error)).collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    chart.draw_series(LineSeries::new(staircase(&front), BLACK.stroke_width(1))).map_err(&err)?;
    chart.draw_series(front.iter().map(|&p| Circle::new(p, 9, BLACK.stroke_width(2)))).map_err(&err)?;
    for series in &panel.series {
        let c = series.colour;
        let points: Vec<(f64, f64)> = series.points.iter().filter(drawable).map(|p| (p.ms, p.error)).collect();
        match series.line.map(Stroke::pattern) {
            Some(Some((drawn, skipped))) => {
                let line = DashedLineSeries::new(points.clone(), drawn, skipped, c.stroke_width(2));
                chart.draw_series(line).map_err(&err)?;
            }
            Some(None) => {
                chart.draw_series(LineSeries::new(points.clone(), c.stroke_width(2))).map_err(&err)?;
            }
            None => {}
        }
        let filled = series.line.is_none_or(Stroke::filled_markers);
        let fill = if filled { c.filled() } else { WHITE.filled() };
        chart
            .draw_series(points.iter().map(|&p| {
                EmptyElement::at(p) + Circle::new((0, 0), 5, fill) + Circle::new((0, 0), 5, c.stroke_width(2))
            }))
            .map_err(&err)?;
        let tag_style = (FONT, 12).into_font().color(&c);
        let tags = series.points.iter().filter(drawable).filter_map(|p| {
            p.tag
                .as_ref()
                .map(|t| EmptyElement::at((p.ms, p.error)) + Text::new(t.clone(), (7, -15), tag_style.clone()))
        });
        chart.draw_series(tags).map_err(&err)?;
    }
    Ok(())
}

/// The corners of a staircase through `points` sorted by x: across at the height of one point, then
/// down to the next.
fn staircase(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut corners = Vec::with_capacity(2 * points.len());
    for (i, &p) in points.iter().enumerate() {
        if i > 0 {
            corners.push((p.0, points[i - 1].1));
        }
        corners.push(p);
    }
    corners
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_front_is_a_staircase() {
        assert_eq!(
            staircase(&[(1.0, 9.0), (2.0, 5.0), (4.0, 1.0)]),
            [(1.0, 9.0), (2.0, 9.0), (2.0, 5.0), (4.0, 5.0), (4.0, 1.0)]
        );
        assert!(staircase(&[]).is_empty());
    }

    #[test]
    fn charts_are_written_with_labels_and_legends() {
        let dir = tempfile::tempdir().unwrap();
        let bars = BarChart {
            title: "D-MSE".into(),
            y_label: "D-MSE (8-bit levels²)".into(),
            series: vec!["fill".into(), "full".into()],
            groups: vec![BarGroup {
                name: "generated".into(),
                bars: vec![Some(Bar { mean: 580.0, std: None }), Some(Bar { mean: 450.0, std: Some(20.0) })],
            }],
        };
        let path = dir.path().join("bars.svg");
        write_bar_chart(&path, &bars).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.contains("generated") && svg.contains("full") && svg.contains("8-bit levels"));

        let point = |ms, error, on_front| TimedPoint { ms, error, on_front, tag: Some("P1".into()) };
        let panel = TimedPanel {
            title: "320x240".into(),
            series: vec![TimedSeries {
                name: "ivp w=0.25 dense".into(),
                colour: colour(0),
                line: Some(Stroke::Dashed),
                points: vec![point(3.0, 500.0, true), point(90.0, 9000.0, false)],
            }],
        };
        let path = dir.path().join("timed.svg");
        write_speed_vs_error(&path, "speed", "ms per frame", "D-MSE", &[panel]).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.contains("Pareto front") && svg.contains("ivp w=0.25 dense") && svg.contains("ms per frame"));
    }
}
