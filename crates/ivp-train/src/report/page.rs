//! The HTML page of a report: the table of scores, the charts, and a section per target frame with
//! its crops, error maps and vectors, in an order the reader can change (a few lines of inline
//! script; the page fetches nothing and runs without a server).

use std::fmt::Write as _;

use crate::eval::{table_cells, table_footer, EvalReport, FrameRecord, TABLE_COLUMNS};
use crate::report::charts::SIZE as CHART_SIZE;
use crate::report::collect::{FrameSummary, MethodInfo, RegionCrops, ReportCollector};
use crate::report::colours::{longest_vector, ERROR_SCALE_MAX};

/// The most crops are magnified on the page (nearest neighbour, by the browser).
pub const MAX_MAGNIFICATION: usize = 3;

/// The width a row of crops should fit: a window 1280 pixels wide, less the margins.
const ROW_WIDTH: usize = 1200;

/// How many times crops `crop_width` wide are magnified so that a row of `columns` of them fits
/// [`ROW_WIDTH`] (at least 1, at most [`MAX_MAGNIFICATION`]): with many methods, less.
pub fn magnification(columns: usize, crop_width: usize) -> usize {
    (ROW_WIDTH / (columns.max(1) * (crop_width + 4)).max(1)).clamp(1, MAX_MAGNIFICATION)
}

/// Width of the error scale's legend image, in pixels.
pub const ERROR_LEGEND_WIDTH: usize = 256;
/// Side of the vector colours' legend image.
pub const VECTOR_LEGEND_SIZE: usize = 48;

/// The files of a report besides the page, named by position (frame, region, method) so that no
/// name of a clip or method has to be a valid file name.
pub struct Files;

impl Files {
    pub const ERROR_LEGEND: &'static str = "legend-error.png";
    pub const VECTOR_LEGEND: &'static str = "legend-vectors.png";
    pub const TIME_CHART: &'static str = "chart-d-mse-vs-ms.svg";
    pub const BARS_CHART: &'static str = "chart-d-mse.svg";

    pub fn overview(frame: usize) -> String {
        format!("f{frame:03}-overview.png")
    }

    pub fn warped(frame: usize, region: usize) -> String {
        format!("f{frame:03}-r{region}-warped.png")
    }

    pub fn truth(frame: usize, region: usize) -> String {
        format!("f{frame:03}-r{region}-truth.png")
    }

    pub fn prediction(frame: usize, region: usize, method: usize) -> String {
        format!("f{frame:03}-r{region}-m{method}-prediction.png")
    }

    pub fn error(frame: usize, region: usize, method: usize) -> String {
        format!("f{frame:03}-r{region}-m{method}-error.png")
    }

    pub fn vectors(frame: usize, region: usize, method: usize) -> String {
        format!("f{frame:03}-r{region}-m{method}-vectors.png")
    }
}

/// What the header says besides the scores.
#[derive(Clone, Debug, Default)]
pub struct PageContext {
    /// The command line that made the report.
    pub command: String,
    /// The machine it ran on.
    pub machine: String,
    /// Seconds the evaluation took.
    pub seconds: f64,
    /// Whether the charts were written (there are two models or more).
    pub charts: bool,
}

/// `args` as one line a shell would split back into them.
pub fn command_line(args: impl Iterator<Item = String>) -> String {
    args.map(|a| {
        if a.is_empty() || a.contains(|c: char| c.is_whitespace() || "'\"$`\\;&|<>()*?!#~".contains(c)) {
            format!("'{}'", a.replace('\'', "'\\''"))
        } else {
            a
        }
    })
    .collect::<Vec<_>>()
    .join(" ")
}

/// The machine as std sees it: host name (Linux), cores, operating system and architecture.
pub fn describe_machine() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|h| h.trim().to_string())
        .ok()
        .filter(|h| !h.is_empty())
        .unwrap_or_else(|| "unknown host".to_string());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    format!(
        "{host}: {cores} cores available, {} worker threads, {} {}",
        rayon::current_num_threads(),
        std::env::consts::OS,
        std::env::consts::ARCH
    )
}

/// Escapes text for HTML content and attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// Methods that leave the holes as they are (`copy`, `warp`): baselines of no infilling, left out
/// of "the methods differ most", which would otherwise always be about them.
const NOT_INFILLING: [&str; 2] = ["copy", "warp"];

/// How far the methods that infill (not those of [`NOT_INFILLING`], not those that read the
/// ground truth) disagree on a frame: the largest D-MSE over the smallest. `None` with fewer than
/// two such scores; infinite when one is exact and another is not.
pub fn spread(record: &FrameRecord, methods: &[MethodInfo]) -> Option<f64> {
    let scores: Vec<f64> = methods
        .iter()
        .filter(|m| !m.uses_ground_truth && !NOT_INFILLING.contains(&m.name.as_str()))
        .filter_map(|m| record.d_mse.get(&m.name).copied().flatten())
        .collect();
    if scores.len() < 2 {
        return None;
    }
    let (lo, hi) = scores.iter().fold((f64::INFINITY, 0f64), |(lo, hi), &s| (lo.min(s), hi.max(s)));
    Some(if lo > 0.0 {
        hi / lo
    } else if hi > 0.0 {
        f64::INFINITY
    } else {
        1.0
    })
}

/// A method's D-MSE on a frame over `fill`'s; `None` without both.
pub fn ratio_to_fill(record: &FrameRecord, method: &str) -> Option<f64> {
    let of = |name: &str| record.d_mse.get(name).copied().flatten();
    let (m, fill) = (of(method)?, of("fill")?);
    (fill > 0.0).then(|| m / fill)
}

const STYLE: &str = "body{font-family:sans-serif;margin:16px;color:#222;max-width:1600px}\
table{border-collapse:collapse}td,th{padding:2px 8px;text-align:right}th{background:#eee}\
td:first-child,th:first-child{text-align:left}.scores td,.scores th{border:1px solid #ccc}\
code{background:#f4f4f4;padding:1px 4px;word-break:break-all}\
.frame{border-top:2px solid #888;margin-top:18px;padding-top:6px}\
.frame-head{display:flex;gap:24px;align-items:flex-start;flex-wrap:wrap}\
.better{background:#d4f4d4}.worse{background:#f8d0d0}\
.crops{display:block;overflow-x:auto}.crops td{text-align:center;vertical-align:top;padding:2px;font-size:13px}\
.crops th{font-size:13px;font-weight:normal;background:none;text-align:center}\
.crops img,.legend img,img.overview{image-rendering:pixelated}\
.rowlabel{writing-mode:vertical-rl;transform:rotate(180deg);font-size:12px;color:#555}\
.charts img{margin-right:8px;border:1px solid #ddd}small{color:#555}";

const SCRIPT: &str = "const frames=document.getElementById('frames');\
document.getElementById('order').addEventListener('change',function(e){\
const key=e.target.value;const items=Array.from(frames.children);\
const num=function(el,k){const v=el.getAttribute('data-'+k);return v===null?-1:parseFloat(v);};\
items.sort(function(a,b){if(key==='order')return num(a,'order')-num(b,'order');\
return(num(b,key)-num(a,key))||(num(a,'order')-num(b,'order'));});\
items.forEach(function(el){frames.appendChild(el);});});";

/// The whole page.
pub fn render(report: &EvalReport, collected: &ReportCollector, context: &PageContext) -> String {
    let methods = &collected.methods;
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>ivp evaluation report</title><style>{STYLE}</style></head><body>\n\
         <h1>ivp evaluation report</h1>\n"
    );
    let _ = writeln!(html, "<p>Command: <code>{}</code><br>", escape(&context.command));
    let _ = writeln!(html, "Machine: {}; the evaluation took {:.1} s.</p>", escape(&context.machine), context.seconds);
    html.push_str(&scores_table(report));
    if context.charts {
        let _ = writeln!(
            html,
            "<p class=\"charts\"><img src=\"{}\" alt=\"D-MSE against ms per frame\" width=\"{w}\" height=\"{h}\">\
             <img src=\"{}\" alt=\"D-MSE by method\" width=\"{w}\" height=\"{h}\"></p>",
            Files::TIME_CHART,
            Files::BARS_CHART,
            w = CHART_SIZE.0,
            h = CHART_SIZE.1
        );
    }
    // A row of crops: the warped view, every method and the truth.
    let magnify = magnification(methods.len() + 2, collected.options.window);
    html.push_str(&how_to_read(collected, magnify));
    html.push_str(&order_control(methods));
    html.push_str("<div id=\"frames\">\n");
    for (f, frame) in collected.frames.iter().enumerate() {
        html.push_str(&frame_section(f, frame, methods, magnify, collected.options.thumbnail_width));
    }
    let _ = write!(html, "</div>\n<script>{SCRIPT}</script>\n</body></html>\n");
    html
}

fn scores_table(report: &EvalReport) -> String {
    let mut html = String::from("<table class=\"scores\"><tr>");
    for c in TABLE_COLUMNS {
        let _ = write!(html, "<th>{}</th>", escape(c));
    }
    html.push_str("</tr>\n");
    for row in table_cells(report) {
        html.push_str("<tr>");
        for cell in row {
            let _ = write!(html, "<td>{}</td>", escape(&cell));
        }
        html.push_str("</tr>\n");
    }
    let _ = writeln!(
        html,
        "</table>\n<p><small>{}. MSE on the 0..255 scale; D- columns on disocclusion pixels only; TC: \
         temporal consistency (lower is better); ms/frame includes the warp, timed warm.</small></p>",
        escape(&table_footer(report))
    );
    html
}

fn how_to_read(collected: &ReportCollector, magnify: usize) -> String {
    let o = collected.options;
    let mut html = String::from("<h2>How to read the frames</h2>\n<p>");
    let _ = write!(
        html,
        "Each frame shows its warped view (the last frame warped into the target's pose; \
         <span style=\"background:#f0f;color:#fff\">&nbsp;magenta&nbsp;</span>: disocclusions, black: \
         new regions) and the D-MSE of every method on it, beside its ratio to <code>fill</code>'s \
         (<span class=\"better\">&nbsp;green: better than fill&nbsp;</span>, \
         <span class=\"worse\">&nbsp;red: worse&nbsp;</span>). Below it, up to {} regions are magnified \
         {magnify} times ({}x{} pixels of the frame each, numbered on the overview).</p>\n<p>",
        o.regions, o.window, o.window
    );
    html.push_str(
        "<b>Which regions:</b> a region is a connected group of disocclusion pixels. Regions are \
         ranked by the squared error the best method there leaves, summed over the region (the best \
         method being the one with the least error over it, among those that do not read the ground \
         truth): the places that weigh most in the frame's D-MSE whatever the method. Each is shown \
         through a window centred on where that error lies; a region whose window would overlap one \
         already shown by more than a quarter is skipped.</p>\n",
    );
    let _ = writeln!(
        html,
        "<p class=\"legend\"><b>Error maps</b> (one scale for every method and frame): absolute error \
         per disocclusion pixel (root of the mean over the channels of the squared error, 8-bit \
         levels) from 0 <img src=\"{}\" alt=\"error scale\" width=\"{ERROR_LEGEND_WIDTH}\" height=\"12\"> \
         {ERROR_SCALE_MAX:.0} and above; the other pixels show the truth in light grey.<br>\
         <b>Vectors</b> (methods that fill by vectors): the vector each disocclusion pixel was filled \
         with, hue its direction, saturation its length up to the longest vector of the region \
         (given under it); white is no vector. <img src=\"{}\" alt=\"vector colours\" \
         width=\"{VECTOR_LEGEND_SIZE}\" height=\"{VECTOR_LEGEND_SIZE}\" style=\"vertical-align:middle\"> \
         the colour of the vector from the centre of this disc to each of its points (right: +x, \
         down: +y).</p>",
        Files::ERROR_LEGEND,
        Files::VECTOR_LEGEND
    );
    html
}

fn order_control(methods: &[MethodInfo]) -> String {
    let mut html = String::from(
        "<h2>Frames</h2>\n<p><label>Order: <select id=\"order\">\
         <option value=\"order\">as evaluated</option>\
         <option value=\"spread\">the methods differ most first</option>",
    );
    for (i, m) in methods.iter().enumerate().filter(|(_, m)| m.is_model) {
        let _ = write!(html, "<option value=\"vs-fill-{i}\">{} against fill, worst first</option>", escape(&m.name));
    }
    html.push_str(
        "</select></label> <small>The methods differ by the largest D-MSE over the smallest among \
         the methods that infill (not copy or warp, nor those that read the truth); a model against \
         fill is its D-MSE over fill's.</small></p>\n",
    );
    html
}

fn frame_section(
    f: usize,
    frame: &FrameSummary,
    methods: &[MethodInfo],
    magnify: usize,
    thumbnail_width: usize,
) -> String {
    let r = &frame.record;
    let mut attrs = format!("data-order=\"{f}\"");
    let spread = spread(r, methods);
    if let Some(s) = spread {
        // JavaScript's parseFloat reads "Infinity" (one method exact, another not).
        let value = if s.is_finite() { format!("{s:.4}") } else { "Infinity".to_string() };
        let _ = write!(attrs, " data-spread=\"{value}\"");
    }
    for (i, m) in methods.iter().enumerate().filter(|(_, m)| m.is_model) {
        if let Some(ratio) = ratio_to_fill(r, &m.name) {
            let _ = write!(attrs, " data-vs-fill-{i}=\"{ratio:.4}\"");
        }
    }
    let mut html = format!("<section class=\"frame\" id=\"f{f:03}\" {attrs}>\n");
    let spread_text = spread.map_or(String::new(), |s| format!("; the methods differ by x{s:.2}"));
    let _ = writeln!(
        html,
        "<h3>{}, target {} <small>({}x{}, {} disocclusion pixels{spread_text})</small></h3>",
        escape(&r.clip),
        r.target,
        frame.width,
        frame.height,
        r.disocclusion_pixels
    );
    html.push_str(
        "<div class=\"frame-head\"><table class=\"scores\"><tr><th>method</th><th>D-MSE</th><th>/ fill</th></tr>\n",
    );
    for m in methods {
        let d_mse = r.d_mse.get(&m.name).copied().flatten();
        let ratio = ratio_to_fill(r, &m.name).filter(|_| m.name != "fill");
        let class = match ratio {
            Some(x) if x < 1.0 => " class=\"better\"",
            Some(x) if x > 1.0 => " class=\"worse\"",
            _ => "",
        };
        let name = if m.is_model { format!("<b>{}</b>", escape(&m.name)) } else { escape(&m.name) };
        let gt = if m.uses_ground_truth { " <small>(reads the truth)</small>" } else { "" };
        let _ = writeln!(
            html,
            "<tr{class}><td>{name}{gt}</td><td>{}</td><td>{}</td></tr>",
            d_mse.map_or("-".to_string(), |v| format!("{v:.1}")),
            ratio.map_or("-".to_string(), |x| format!("{x:.2}"))
        );
    }
    // Frames narrower than the thumbnails are shown magnified to about their width.
    let grown = (thumbnail_width / frame.thumbnail.width().max(1)).max(1);
    let (tw, th) = (frame.thumbnail.width() * grown, frame.thumbnail.height() * grown);
    let shrunk = match (frame.thumbnail_factor, grown) {
        (1, 1) => String::new(),
        (1, k) => format!(" (magnified {k} times)"),
        (s, _) => format!(" (shrunk {s} times)"),
    };
    let _ = writeln!(
        html,
        "</table><figure style=\"margin:0\"><img class=\"overview\" src=\"{}\" alt=\"warped frame\" width=\"{tw}\" \
         height=\"{th}\">\
         <figcaption><small>warped{shrunk}, regions outlined</small></figcaption></figure></div>",
        Files::overview(f)
    );
    if frame.regions.is_empty() {
        html.push_str("<p><small>No disocclusion region to show.</small></p>\n");
    }
    for (k, crops) in frame.regions.iter().enumerate() {
        html.push_str(&region_table(f, k, crops, methods, magnify));
    }
    html.push_str("</section>\n");
    html
}

fn region_table(f: usize, k: usize, crops: &RegionCrops, methods: &[MethodInfo], magnify: usize) -> String {
    let (w, h) = (crops.truth.width() * magnify, crops.truth.height() * magnify);
    let img =
        |src: String, alt: &str| format!("<img src=\"{src}\" alt=\"{}\" width=\"{w}\" height=\"{h}\">", escape(alt));
    let region = &crops.region;
    let window = region.window;
    let mut html = format!(
        "<p><small>Region {}: {} disocclusion pixels, window at ({}, {}); least error there: {} \
         (MSE {:.1}).</small></p>\n<table class=\"crops\"><tr><td></td><th>warped</th>",
        k + 1,
        region.pixels,
        window.x,
        window.y,
        escape(methods.get(region.best_method).map_or("?", |m| m.name.as_str())),
        region.best_mse
    );
    for m in methods {
        let _ = write!(html, "<th>{}</th>", escape(&m.name));
    }
    html.push_str("<th>truth</th></tr>\n<tr><td class=\"rowlabel\">prediction</td>");
    let _ = write!(html, "<td>{}</td>", img(Files::warped(f, k), "warped"));
    for (i, m) in methods.iter().enumerate() {
        let _ = write!(html, "<td>{}</td>", img(Files::prediction(f, k, i), &m.name));
    }
    let _ = write!(
        html,
        "<td>{}</td></tr>\n<tr><td class=\"rowlabel\">error</td><td></td>",
        img(Files::truth(f, k), "truth")
    );
    for (i, m) in methods.iter().enumerate() {
        let _ = write!(html, "<td>{}</td>", img(Files::error(f, k, i), &format!("error of {}", m.name)));
    }
    html.push_str("<td></td></tr>\n");
    if crops.vectors.iter().any(Option::is_some) {
        let longest = longest_vector(crops.vectors.iter().flatten());
        let _ = write!(html, "<tr><td class=\"rowlabel\">vectors</td><td><small>rim: {longest:.1} px</small></td>");
        for (i, (m, v)) in methods.iter().zip(&crops.vectors).enumerate() {
            match v {
                Some(_) => {
                    let _ =
                        write!(html, "<td>{}</td>", img(Files::vectors(f, k, i), &format!("vectors of {}", m.name)));
                }
                None => html.push_str("<td><small>no vectors</small></td>"),
            }
        }
        html.push_str("<td></td></tr>\n");
    }
    html.push_str("</table>\n");
    html
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    fn info(name: &str, uses_ground_truth: bool) -> MethodInfo {
        MethodInfo { name: name.to_string(), uses_ground_truth, is_model: name.starts_with('m') }
    }

    #[test]
    fn command_lines_quote_what_a_shell_would_split() {
        let args = ["ivp", "--data", "my clips", "it's", "a=b,c"].map(String::from);
        assert_eq!(command_line(args.into_iter()), r"ivp --data 'my clips' 'it'\''s' a=b,c");
        assert_eq!(escape("<a href=\"x\">&'"), "&lt;a href=&quot;x&quot;&gt;&amp;&#39;");
    }

    #[test]
    fn the_spread_leaves_out_baselines_and_references() {
        let scores = [("copy", 5000.0), ("warp", 9000.0), ("oracle", 10.0), ("fill", 400.0), ("m1", 200.0)];
        let d_mse: BTreeMap<String, Option<f64>> = scores.iter().map(|(n, d)| (n.to_string(), Some(*d))).collect();
        let record = FrameRecord { clip: "c".into(), target: 6, disocclusion_pixels: 9, d_mse };
        let methods: Vec<MethodInfo> = scores.iter().map(|(n, _)| info(n, *n == "oracle")).collect();
        assert_eq!(spread(&record, &methods), Some(2.0), "fill over m1 only");
        assert_eq!(spread(&record, &methods[..4]), None, "one method that infills");
        assert_eq!(ratio_to_fill(&record, "m1"), Some(0.5));
        assert_eq!(ratio_to_fill(&record, "absent"), None);
    }

    #[test]
    fn crops_are_magnified_less_when_many_methods_share_a_row() {
        assert_eq!(magnification(5, 64), 3);
        assert_eq!(magnification(8, 64), 2);
        assert_eq!(magnification(30, 64), 1);
        assert_eq!(magnification(3, 4), MAX_MAGNIFICATION);
    }
}
