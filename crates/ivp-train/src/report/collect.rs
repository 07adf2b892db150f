//! What a report keeps of each target frame while the evaluation runs: a thumbnail of the warp and
//! crops around its worst regions, never the whole frames (a dataset of 1080p frames would not
//! fit in memory otherwise).

use ivp_core::geometry::Rect;
use ivp_core::{RgbImage, VectorField};

use crate::eval::{model_spec, FrameObserver, FrameOutputs, FrameRecord, Method};
use crate::report::colours::{mark_holes, thumbnail};
use crate::report::regions::{pixel_errors, worst_regions, Region};
use crate::sheet::draw_text_in;

/// What a report says about one method.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MethodInfo {
    pub name: String,
    /// Reads the target frame (`oracle`): a reference, not a method; it never picks regions.
    pub uses_ground_truth: bool,
    /// A trained model (`--model`): compared with `fill` in the report.
    pub is_model: bool,
}

impl MethodInfo {
    /// The methods of an evaluation, the models being those that `model_specs` (the `--model`
    /// arguments) name.
    pub fn of(methods: &[Method], model_specs: &[String]) -> Vec<MethodInfo> {
        let models: Vec<String> = model_specs.iter().map(|s| model_spec(s).0).collect();
        methods
            .iter()
            .map(|m| MethodInfo {
                name: m.name().to_string(),
                uses_ground_truth: matches!(m, Method::Internal(i) if i.uses_ground_truth()),
                is_model: matches!(m, Method::Internal(_)) && models.iter().any(|n| n == m.name()),
            })
            .collect()
    }
}

/// How much a report shows of each frame.
#[derive(Clone, Copy, Debug)]
pub struct ReportOptions {
    /// Regions magnified per frame.
    pub regions: usize,
    /// Side of the square window around a region, in pixels of the frame.
    pub window: usize,
    /// Overview images are shrunk by a whole factor to at most this width.
    pub thumbnail_width: usize,
}

impl Default for ReportOptions {
    fn default() -> Self {
        Self { regions: 2, window: 64, thumbnail_width: 320 }
    }
}

/// One region of one frame, as every method filled it.
#[derive(Clone, Debug)]
pub struct RegionCrops {
    pub region: Region,
    /// The warped frame, disocclusions in [`crate::report::colours::HOLE_COLOUR`].
    pub warped: RgbImage,
    pub truth: RgbImage,
    pub disocclusions: Vec<bool>,
    /// Per method: the scored prediction, and the vectors it filled with (if it fills by vectors).
    pub predictions: Vec<RgbImage>,
    pub vectors: Vec<Option<VectorField>>,
}

/// What a report keeps of one target frame.
#[derive(Clone, Debug)]
pub struct FrameSummary {
    /// The frame's scores, as the evaluation computed them.
    pub record: FrameRecord,
    pub width: usize,
    pub height: usize,
    /// The warped frame with its disocclusions marked and the regions outlined and numbered,
    /// shrunk by `thumbnail_factor`.
    pub thumbnail: RgbImage,
    pub thumbnail_factor: usize,
    pub regions: Vec<RegionCrops>,
}

/// The colour of region outlines on thumbnails (yellow: apart from the magenta of the holes).
const OUTLINE: [f32; 3] = [1.0, 0.9, 0.0];

/// Collects a [`FrameSummary`] of every frame an evaluation scores.
pub struct ReportCollector {
    pub methods: Vec<MethodInfo>,
    pub options: ReportOptions,
    pub frames: Vec<FrameSummary>,
}

impl ReportCollector {
    pub fn new(methods: Vec<MethodInfo>, options: ReportOptions) -> Self {
        Self { methods, options, frames: Vec::new() }
    }
}

impl FrameObserver for ReportCollector {
    fn observe(&mut self, frame: &FrameOutputs<'_>) {
        let (width, height) = (frame.truth.width(), frame.truth.height());
        let disocclusions = frame.warp.holes.disocclusions();
        let errors: Vec<Vec<f32>> = frame.predictions.iter().map(|p| pixel_errors(p, frame.truth)).collect();
        let choosing: Vec<Option<&[f32]>> =
            errors.iter().zip(&self.methods).map(|(e, m)| (!m.uses_ground_truth).then_some(e.as_slice())).collect();
        let o = self.options;
        let regions = worst_regions(&disocclusions, width, height, &choosing, o.regions, o.window);
        let marked = mark_holes(&frame.warp.image, &disocclusions);
        let crop = |image: &RgbImage, w: &Rect| image.crop(w.x, w.y, w.width, w.height);
        let crops = regions
            .into_iter()
            .map(|region| {
                let w = region.window;
                let rows = w.y..w.y + w.height;
                RegionCrops {
                    warped: crop(&marked, &w),
                    truth: crop(frame.truth, &w),
                    disocclusions: rows.flat_map(|v| disocclusions[v * width + w.x..][..w.width].to_vec()).collect(),
                    predictions: frame.predictions.iter().map(|p| crop(p, &w)).collect(),
                    vectors: frame
                        .vectors
                        .iter()
                        .map(|f| f.as_ref().map(|f| f.crop(w.x, w.y, w.width, w.height)))
                        .collect(),
                    region,
                }
            })
            .collect::<Vec<_>>();
        let (mut thumb, factor) = thumbnail(&marked, o.thumbnail_width);
        for (k, c) in crops.iter().enumerate() {
            outline(&mut thumb, &c.region.window, factor, &(k + 1).to_string());
        }
        self.frames.push(FrameSummary {
            record: frame.record.clone(),
            width,
            height,
            thumbnail: thumb,
            thumbnail_factor: factor,
            regions: crops,
        });
    }
}

/// Outlines `window` (in frame pixels) on a thumbnail shrunk by `factor`, with `label` inside its
/// top-left corner.
fn outline(thumb: &mut RgbImage, window: &Rect, factor: usize, label: &str) {
    let (tw, th) = (thumb.width(), thumb.height());
    let x0 = (window.x / factor).min(tw - 1);
    let y0 = (window.y / factor).min(th - 1);
    let x1 = ((window.x + window.width).div_ceil(factor)).clamp(x0 + 1, tw) - 1;
    let y1 = ((window.y + window.height).div_ceil(factor)).clamp(y0 + 1, th) - 1;
    for u in x0..=x1 {
        thumb.set(u, y0, OUTLINE);
        thumb.set(u, y1, OUTLINE);
    }
    for v in y0..=y1 {
        thumb.set(x0, v, OUTLINE);
        thumb.set(x1, v, OUTLINE);
    }
    draw_text_in(thumb, x0 + 2, y0 + 2, label, (x1 - x0).saturating_sub(2), OUTLINE);
}
