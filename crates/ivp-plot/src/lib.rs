//! What every chart of ivp shares (`loss.png` of a training run, the SVGs of `cargo xtask`): the
//! font, the axes and their tick labels, the colours. plotters (re-exported, with the one feature
//! set of the workspace) draws them; its text uses DejaVu Sans compiled into the binary, so neither
//! writing a PNG nor laying out an SVG needs a system font.

use std::ops::Range;
use std::sync::Once;

pub use plotters;
use plotters::chart::MeshStyle;
use plotters::coord::ranged1d::{DefaultFormatting, KeyPointHint, Ranged};
use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

/// The font family of every text: DejaVu Sans once [`register_font`] has run.
pub const FONT: &str = "sans-serif";

/// Makes DejaVu Sans the [`FONT`] family. plotters' ab_glyph text measures and draws with the fonts
/// of this table only, so every chart calls this first (only the first call does anything).
pub fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // A constant of the dejavu crate: it parses, or the build itself is broken.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
}

/// The grid and text of every chart's axes: tick labels at 15 px, axis descriptions at 16 px, and
/// up to 4 light grid lines between labelled ticks.
pub fn house_style<'m, 'a, 'b, X, Y, DB>(
    mesh: &'m mut MeshStyle<'a, 'b, X, Y, DB>,
) -> &'m mut MeshStyle<'a, 'b, X, Y, DB>
where
    X: Ranged,
    Y: Ranged,
    DB: DrawingBackend,
{
    mesh.label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .max_light_lines(4)
        .light_line_style(RGBColor(238, 238, 238))
}

/// Distinct colours (Tableau 10), taken in order.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// The `i`-th colour of the palette (repeating after 10).
pub fn colour(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

/// How a line is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stroke {
    Solid,
    Dashed,
    Dotted,
}

impl Stroke {
    /// Drawn and skipped lengths along the line, in pixels; `None` for a solid line.
    pub fn pattern(self) -> Option<(u32, u32)> {
        match self {
            Stroke::Solid => None,
            Stroke::Dashed => Some((6, 4)),
            Stroke::Dotted => Some((2, 4)),
        }
    }

    /// Markers on a solid line are filled, on the others hollow.
    pub fn filled_markers(self) -> bool {
        self == Stroke::Solid
    }
}

/// How an entry of a legend is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mark {
    /// A filled box (bars).
    Bar,
    /// A marker alone: a filled or a hollow circle.
    Point { filled: bool },
    /// A line with a marker on it (filled on a solid line, hollow on the others).
    Line { stroke: Stroke, marker: bool },
    /// A black ring on a thin line (points singled out, such as a Pareto front).
    Ring,
}

/// One entry of a legend.
pub struct LegendEntry {
    pub label: String,
    pub colour: RGBColor,
    pub mark: Mark,
}

/// Draws a legend down `area`, a column of its own beside the plots (plotters' own legend is
/// clipped to the plotting area, where it hides data), with an optional title.
pub fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    title: Option<&str>,
    entries: &[LegendEntry],
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let text = (FONT, 15).into_font().color(&BLACK);
    let mut y = 48;
    if let Some(title) = title {
        area.draw_text(title, &(FONT, 17).into_font().color(&BLACK), (12, y - 8))?;
        y += 30;
    }
    let (x0, x1) = (14, 44);
    for entry in entries {
        let c = entry.colour;
        match entry.mark {
            Mark::Bar => area.draw(&Rectangle::new([(x0 + 6, y - 7), (x1 - 6, y + 7)], c.filled()))?,
            Mark::Point { filled } => draw_marker(area, ((x0 + x1) / 2, y), c, filled)?,
            Mark::Line { stroke, marker } => {
                let dashes: Vec<(i32, i32)> = match stroke.pattern() {
                    Some((drawn, skipped)) => {
                        (x0..x1).step_by((drawn + skipped) as usize).map(|s| (s, (s + drawn as i32).min(x1))).collect()
                    }
                    None => vec![(x0, x1)],
                };
                for (a, b) in dashes {
                    area.draw(&PathElement::new([(a, y), (b, y)], c.stroke_width(2)))?;
                }
                if marker {
                    draw_marker(area, ((x0 + x1) / 2, y), c, stroke.filled_markers())?;
                }
            }
            Mark::Ring => {
                area.draw(&PathElement::new([(x0, y), (x1, y)], BLACK.stroke_width(1)))?;
                area.draw(&Circle::new(((x0 + x1) / 2, y), 8, BLACK.stroke_width(2)))?;
            }
        }
        area.draw_text(&entry.label, &text, (x1 + 10, y - 8))?;
        y += 24;
    }
    Ok(())
}

/// A circle of radius 5 at a pixel: filled, or a ring with a white centre.
pub fn draw_marker<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    at: (i32, i32),
    c: RGBColor,
    filled: bool,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    if filled {
        area.draw(&Circle::new(at, 5, c.filled()))
    } else {
        area.draw(&Circle::new(at, 5, WHITE.filled()))?;
        area.draw(&Circle::new(at, 5, c.stroke_width(2)))
    }
}

/// A tick value with at most 3 significant digits and no float noise (0.3, 25, 1000, 2.5e-5).
pub fn tick_label(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let magnitude = v.abs().log10().floor();
    if !(-3.0..6.0).contains(&magnitude) {
        return format!("{v:.1e}");
    }
    let decimals = (2.0 - magnitude).max(0.0) as usize;
    let text = format!("{v:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        text
    }
}

/// Whether positive values from `lo` to `hi` span a decade or more: on a linear axis the low end
/// would be flattened.
pub fn spans_decades(lo: f64, hi: f64) -> bool {
    lo > 0.0 && hi.is_finite() && hi / lo >= 10.0
}

/// An axis of values: linear, or logarithmic where they span decades.
#[derive(Clone)]
pub enum Axis {
    Linear(RangedCoordf64),
    Log(LogAxis),
}

impl Axis {
    /// The axis that shows every finite value of `values` with a margin: log scale (over the
    /// positive ones) when they span a decade or more, else linear, from 0 when no value is
    /// negative and 0 is near. `None` without a finite value.
    pub fn fitting(values: impl Iterator<Item = f64>) -> Option<Axis> {
        let values: Vec<f64> = values.filter(|v| v.is_finite()).collect();
        let (lo, hi) = values.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        if lo > hi {
            return None;
        }
        let lowest_positive = values.iter().copied().filter(|&v| v > 0.0).fold(f64::INFINITY, f64::min);
        if spans_decades(lowest_positive, hi) {
            return Some(Axis::Log(LogAxis::new(lowest_positive / 1.4, hi * 1.4)));
        }
        let pad = ((hi - lo) * 0.08).max(hi.abs() * 0.05).max(1e-9);
        let start = if lo >= 0.0 { (lo - pad).max(0.0) } else { lo - pad };
        Some(Axis::Linear((start..hi + pad).into()))
    }

    /// A log axis over the positive finite values of `values`, with a margin; `None` without one.
    pub fn log_fitting(values: impl Iterator<Item = f64>) -> Option<Axis> {
        let (lo, hi) = values
            .filter(|v| v.is_finite() && *v > 0.0)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| (lo.min(v), hi.max(v)));
        (lo <= hi).then(|| Axis::Log(LogAxis::new(lo / 1.4, hi * 1.4)))
    }

    /// A linear axis over `range`.
    pub fn linear(range: Range<f64>) -> Axis {
        Axis::Linear(range.into())
    }

    pub fn is_log(&self) -> bool {
        matches!(self, Axis::Log(_))
    }

    /// `label`, saying ", log scale" when the axis is.
    pub fn describe(&self, label: &str) -> String {
        if self.is_log() {
            format!("{label}, log scale")
        } else {
            label.to_string()
        }
    }

    /// Whether `v` can be placed on the axis (a log axis has no place for 0 or below).
    pub fn shows(&self, v: f64) -> bool {
        v.is_finite() && (!self.is_log() || v > 0.0)
    }
}

impl Ranged for Axis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        match self {
            Axis::Linear(a) => a.map(value, limit),
            Axis::Log(a) => a.map(value, limit),
        }
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        match self {
            Axis::Linear(a) => a.key_points(hint),
            Axis::Log(a) => a.key_points(hint),
        }
    }

    fn range(&self) -> Range<f64> {
        match self {
            Axis::Linear(a) => a.range(),
            Axis::Log(a) => a.range(),
        }
    }
}

/// A log axis ticked at 1, 2 and 5 times the powers of ten (or every digit, or 1-2-3-5, or the
/// powers alone, as room allows). plotters' own log axis ticks only from the first power of ten
/// up, so a range such as 300..6000 gets no tick below 1000.
#[derive(Clone)]
pub struct LogAxis {
    /// The linear axis of the logarithms.
    logarithms: RangedCoordf64,
    range: Range<f64>,
}

impl LogAxis {
    /// The axis from `lo` to `hi`, both positive.
    pub fn new(lo: f64, hi: f64) -> LogAxis {
        LogAxis { logarithms: (lo.ln()..hi.ln()).into(), range: lo..hi }
    }
}

impl Ranged for LogAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        self.logarithms.map(&value.ln(), limit)
    }

    fn key_points<Hint: KeyPointHint>(&self, hint: Hint) -> Vec<f64> {
        log_ticks(self.range.start, self.range.end, hint.max_num_points())
    }

    fn range(&self) -> Range<f64> {
        self.range.clone()
    }
}

/// Ticks of a log axis from `lo` to `hi`: the densest of every digit, 1-2-3-5, 1-2-5 and the powers
/// of ten alone that gives at most `max_points` (the powers of ten, thinned, when even they are too
/// many).
pub fn log_ticks(lo: f64, hi: f64, max_points: usize) -> Vec<f64> {
    if !(lo > 0.0 && hi > lo && hi.is_finite()) || max_points == 0 {
        return Vec::new();
    }
    let within = |mantissas: &[f64]| -> Vec<f64> {
        let first = lo.log10().floor() as i32;
        let last = hi.log10().ceil() as i32;
        (first..=last)
            .flat_map(|k| mantissas.iter().map(move |m| m * 10f64.powi(k)))
            .filter(|v| *v >= lo * (1.0 - 1e-9) && *v <= hi * (1.0 + 1e-9))
            .collect()
    };
    let digits: Vec<f64> = (1..10).map(f64::from).collect();
    for mantissas in [&digits[..], &[1.0, 2.0, 3.0, 5.0], &[1.0, 2.0, 5.0], &[1.0]] {
        let ticks = within(mantissas);
        if ticks.len() <= max_points {
            return ticks;
        }
    }
    let powers = within(&[1.0]);
    let step = powers.len().div_ceil(max_points);
    powers.into_iter().step_by(step).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tick_labels_are_short() {
        assert_eq!(tick_label(0.1 + 0.2), "0.3");
        assert_eq!(tick_label(0.25), "0.25");
        assert_eq!(tick_label(1000.0), "1000");
        assert_eq!(tick_label(581.84), "582");
        assert_eq!(tick_label(2.5e-5), "2.5e-5");
    }

    #[test]
    fn log_ticks_reach_below_the_first_power_of_ten() {
        assert_eq!(log_ticks(300.0, 6000.0, 6), [300.0, 500.0, 1000.0, 2000.0, 3000.0, 5000.0]);
        assert_eq!(log_ticks(300.0, 6000.0, 5), [500.0, 1000.0, 2000.0, 5000.0]);
        assert_eq!(log_ticks(0.03, 0.6, 30).len(), 13); // 0.03 ..= 0.09, 0.1 ..= 0.6
        assert_eq!(log_ticks(1e-3, 1e5, 4), [1e-3, 1.0, 1e3]);
        assert!(log_ticks(0.0, 1.0, 5).is_empty());
    }

    #[test]
    fn axes_go_log_only_over_a_decade() {
        let log = |v: &[f64]| Axis::fitting(v.iter().copied()).map(|a| a.is_log());
        assert_eq!(log(&[2.0, 4.0]), Some(false));
        assert_eq!(log(&[0.0, 2.0, 40.0, f64::NAN]), Some(true));
        assert_eq!(log(&[f64::NAN]), None);
        let axis = Axis::fitting([0.2, 0.5].into_iter()).unwrap();
        assert!(axis.range().start >= 0.0 && axis.range().start < 0.2 && axis.range().end > 0.5);
        assert!(!Axis::fitting([1.0, 100.0].into_iter()).unwrap().shows(0.0));
        assert!(Axis::log_fitting([0.0, 2.0, 4.0].into_iter()).unwrap().is_log());
        assert!(Axis::log_fitting([0.0, -1.0].into_iter()).is_none());
    }
}
