//! A report on disk: the folder is checked first (an evaluation can take minutes; a folder that
//! would be refused is refused before it runs), then every image and the page are written
//! atomically, the page last.

use std::path::{Path, PathBuf};

use ivp_data::{write_atomically, write_rgb_png};

use crate::eval::EvalReport;
use crate::report::charts::{d_mse_against_time_svg, d_mse_bars_svg};
use crate::report::collect::ReportCollector;
use crate::report::colours::{error_legend, error_map, longest_vector, vector_legend};
use crate::report::error::ReportError;
use crate::report::page::{render, Files, PageContext, ERROR_LEGEND_WIDTH, VECTOR_LEGEND_SIZE};
use crate::report::regions::pixel_errors;
use crate::sheet::vectors_to_rgb;

/// The name of the page in a report's folder.
pub const PAGE: &str = "index.html";

/// Checks that `dir` can take a report: absent (it will be created), empty, or anything when
/// `force` is set (files of the same names are then replaced, others left).
pub fn prepare_report_dir(dir: &Path, force: bool) -> Result<(), ReportError> {
    let io = |source| ReportError::Io { path: dir.to_path_buf(), source };
    match std::fs::metadata(dir) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io(e)),
        Ok(meta) if !meta.is_dir() => Err(ReportError::NotAFolder(dir.to_path_buf())),
        Ok(_) => {
            let empty = std::fs::read_dir(dir).map_err(io)?.next().is_none();
            if empty || force {
                Ok(())
            } else {
                Err(ReportError::NotEmpty(dir.to_path_buf()))
            }
        }
    }
}

/// What [`write_report`] wrote.
#[derive(Clone, Debug)]
pub struct WrittenReport {
    pub page: PathBuf,
    pub files: usize,
    pub bytes: u64,
}

/// Writes the report of `report` (the scores) and `collected` (what was kept of each frame) into
/// `dir`, creating it. Call [`prepare_report_dir`] before evaluating.
pub fn write_report(
    dir: &Path,
    report: &EvalReport,
    collected: &ReportCollector,
    context: &PageContext,
) -> Result<WrittenReport, ReportError> {
    std::fs::create_dir_all(dir).map_err(|source| ReportError::Io { path: dir.to_path_buf(), source })?;
    let mut written = Written { dir, files: 0, bytes: 0 };
    written.png(Files::ERROR_LEGEND, &error_legend(ERROR_LEGEND_WIDTH, 12))?;
    written.png(Files::VECTOR_LEGEND, &vector_legend(VECTOR_LEGEND_SIZE))?;
    for (f, frame) in collected.frames.iter().enumerate() {
        written.png(&Files::overview(f), &frame.thumbnail)?;
        for (k, crops) in frame.regions.iter().enumerate() {
            written.png(&Files::warped(f, k), &crops.warped)?;
            written.png(&Files::truth(f, k), &crops.truth)?;
            // One length for every method's vectors in the region, so that their colours compare.
            let longest = longest_vector(crops.vectors.iter().flatten());
            for (m, prediction) in crops.predictions.iter().enumerate() {
                written.png(&Files::prediction(f, k, m), prediction)?;
                let errors = pixel_errors(prediction, &crops.truth);
                written.png(&Files::error(f, k, m), &error_map(&errors, &crops.disocclusions, &crops.truth))?;
                if let Some(vectors) = &crops.vectors[m] {
                    written.png(&Files::vectors(f, k, m), &vectors_to_rgb(vectors, Some(longest)))?;
                }
            }
        }
    }
    let models = collected.methods.iter().filter(|m| m.is_model).count();
    let mut context = context.clone();
    context.charts = false;
    if models >= 2 {
        if let (Some(time), Some(bars)) = (d_mse_against_time_svg(&report.methods)?, d_mse_bars_svg(&report.methods)?) {
            written.bytes(Files::TIME_CHART, time.as_bytes())?;
            written.bytes(Files::BARS_CHART, bars.as_bytes())?;
            context.charts = true;
        }
    }
    written.bytes(PAGE, render(report, collected, &context).as_bytes())?;
    Ok(WrittenReport { page: dir.join(PAGE), files: written.files, bytes: written.bytes })
}

/// Counts what is written into a report's folder.
struct Written<'a> {
    dir: &'a Path,
    files: usize,
    bytes: u64,
}

impl Written<'_> {
    fn png(&mut self, name: &str, image: &ivp_core::RgbImage) -> Result<(), ReportError> {
        let path = self.dir.join(name);
        write_rgb_png(&path, image)?;
        self.count(&path)
    }

    fn bytes(&mut self, name: &str, bytes: &[u8]) -> Result<(), ReportError> {
        let path = self.dir.join(name);
        write_atomically(&path, bytes)?;
        self.count(&path)
    }

    fn count(&mut self, path: &Path) -> Result<(), ReportError> {
        let meta = std::fs::metadata(path).map_err(|source| ReportError::Io { path: path.to_path_buf(), source })?;
        self.files += 1;
        self.bytes += meta.len();
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use ivp_core::{DepthMap, HoleMask, PixelClass, RgbImage, VectorField, Warp};

    use super::*;
    use crate::eval::{FrameObserver, FrameOutputs, FrameRecord, MethodReport};
    use crate::machine::Machine;
    use crate::report::collect::{MethodInfo, ReportOptions};

    fn method(name: &str, d_mse: f64, ms: Option<f64>) -> MethodReport {
        MethodReport {
            name: name.to_string(),
            uses_ground_truth: false,
            mse: d_mse / 10.0,
            d_mse: Some(d_mse),
            ssim: 0.9,
            d_ssim: Some(0.7),
            tc: Some(100.0),
            tc_tracks: 5,
            ms_per_frame: ms,
            ms_by_stage: BTreeMap::new(),
            frames: 2,
            d_frames: 2,
        }
    }

    const NAMES: [&str; 3] = ["fill", "model-a", "model-b"];

    /// Two frames of 40x30 with one square hole, observed by a collector as `evaluate` would hand
    /// them over: `fill` is grey in the hole, model-a exact, model-b black.
    fn collected() -> (EvalReport, ReportCollector) {
        let methods = NAMES
            .iter()
            .map(|&n| MethodInfo { name: n.to_string(), uses_ground_truth: false, is_model: n != "fill" })
            .collect();
        let mut collector =
            ReportCollector::new(methods, ReportOptions { regions: 2, window: 16, thumbnail_width: 320 });
        let (w, h) = (40, 30);
        let truth = RgbImage::from_fn(w, h, |u, v| [u as f32 / 40.0, v as f32 / 30.0, 0.5]);
        let hole = |u: usize, v: usize| (10..18).contains(&u) && (5..12).contains(&v);
        let classes =
            (0..w * h).map(|i| if hole(i % w, i / w) { PixelClass::Disocclusion } else { PixelClass::Known }).collect();
        let warp = Warp {
            image: RgbImage::from_fn(w, h, |u, v| if hole(u, v) { [0.0; 3] } else { truth.get(u, v) }),
            depth: DepthMap::filled(w, h, [1.0]),
            holes: HoleMask::from_classes(w, h, classes),
        };
        let fill = RgbImage::from_fn(w, h, |u, v| if hole(u, v) { [0.5; 3] } else { truth.get(u, v) });
        let predictions = vec![fill, truth.clone(), warp.image.clone()];
        let vectors = vec![None, Some(VectorField::filled(w, h, [3.0, -1.0])), Some(VectorField::zeros(w, h))];
        let mut per_frame = Vec::new();
        for target in [6, 8] {
            let d_mse: BTreeMap<String, Option<f64>> =
                NAMES.iter().zip([400.0, 0.0, 9000.0 + target as f64]).map(|(n, d)| (n.to_string(), Some(d))).collect();
            let record = FrameRecord { clip: "clip_<a>".to_string(), target, disocclusion_pixels: 56, d_mse };
            collector.observe(&FrameOutputs {
                record: &record,
                warp: &warp,
                truth: &truth,
                predictions: &predictions,
                vectors: &vectors,
            });
            per_frame.push(record);
        }
        let methods = vec![
            method("fill", 400.0, Some(1.0)),
            method("model-a", 0.0, Some(20.0)),
            method("model-b", 9007.0, Some(30.0)),
        ];
        let report = EvalReport {
            clips: vec!["clip_<a>".to_string()],
            targets: vec![6, 8],
            methods,
            per_frame,
            machine: Machine { cpu: "Test CPU".to_string(), vectors: "avx2" },
            threads: 2,
        };
        (report, collector)
    }

    #[test]
    fn a_non_empty_folder_is_refused_unless_forced() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("report");
        assert!(prepare_report_dir(&dir, false).is_ok(), "absent: created later");
        std::fs::create_dir(&dir).unwrap();
        assert!(prepare_report_dir(&dir, false).is_ok(), "empty");
        std::fs::write(dir.join("notes.txt"), "mine").unwrap();
        let refused = prepare_report_dir(&dir, false).unwrap_err();
        assert!(matches!(refused, ReportError::NotEmpty(ref p) if p == &dir));
        assert!(refused.to_string().contains(&dir.display().to_string()) && refused.to_string().contains("--force"));
        assert!(prepare_report_dir(&dir, true).is_ok());
        let file = dir.join("notes.txt");
        assert!(matches!(prepare_report_dir(&file, true), Err(ReportError::NotAFolder(_))));
    }

    #[test]
    fn the_page_lists_every_method_and_frame_and_links_only_files_written() {
        let (report, collected) = collected();
        assert_eq!(collected.frames.len(), 2);
        let region = &collected.frames[0].regions[0].region;
        assert_eq!(region.pixels, 56, "the one hole is the region");
        assert_eq!(region.best_method, 1, "model-a is exact there");
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("report");
        let context = PageContext {
            command: "ivp eval --report 'a b'".into(),
            machine: "here".into(),
            seconds: 1.0,
            charts: false,
        };
        let written = write_report(&dir, &report, &collected, &context).unwrap();
        let html = std::fs::read_to_string(&written.page).unwrap();
        for name in NAMES {
            assert!(html.contains(&format!("<th>{name}</th>")), "{name} heads the crops");
            assert!(html.contains(&format!("<td>{name}</td>")), "{name} is in the table of scores");
        }
        assert!(html.contains("clip_&lt;a&gt;, target 6") && html.contains("clip_&lt;a&gt;, target 8"), "escaped");
        assert!(html.contains("ivp eval --report &#39;a b&#39;"));
        // model-a beats fill (green), model-b loses (red) on each frame.
        assert_eq!(html.matches("<tr class=\"better\"><td><b>model-a</b>").count(), 2);
        assert_eq!(html.matches("<tr class=\"worse\"><td><b>model-b</b>").count(), 2);
        // Two models: both charts. Every image linked exists, and nothing else was written.
        assert!(html.contains(Files::TIME_CHART) && html.contains(Files::BARS_CHART));
        let mut linked: Vec<&str> =
            html.match_indices("src=\"").map(|(i, _)| &html[i + 5..][..html[i + 5..].find('"').unwrap()]).collect();
        linked.sort_unstable();
        linked.dedup();
        let mut on_disk: Vec<String> =
            std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        on_disk.retain(|f| f != PAGE);
        on_disk.sort_unstable();
        assert_eq!(linked, on_disk);
        assert_eq!(written.files, on_disk.len() + 1);
        // fill has no vectors: no image of them.
        assert!(!on_disk.contains(&Files::vectors(0, 0, 0)) && on_disk.contains(&Files::vectors(0, 0, 1)));
        // The frames sort by how much the methods differ: model-b over model-a's exact 0 is infinite.
        assert!(html.contains("data-spread=\"Infinity\""));
    }
}
