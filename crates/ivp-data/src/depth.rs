//! Validation of a depth map as it is loaded: what every value of a frame means, and whether the
//! frame can be warped at all.
//!
//! Every value falls in exactly one class:
//! - **usable**: finite and in `[MIN_PLAUSIBLE_DEPTH, MAX_PLAUSIBLE_DEPTH]` scene units;
//! - **far**: `+inf`, sky (renderers write it for rays that hit nothing); allowed, never warped;
//! - **missing**: `0` (or `-0`), no reading (a depth camera's hole; SceneNet's 0 mm, which its reader
//!   turns into NaN, counts here too); allowed, never warped;
//! - **implausible**: finite and positive but below `MIN_PLAUSIBLE_DEPTH` or above
//!   `MAX_PLAUSIBLE_DEPTH`: a unit mistake or garbage, not a scene;
//! - **invalid**: NaN, negative or `-inf`.
//!
//! A frame without a single usable value is an error (it would warp to nothing but holes); a frame
//! where invalid and implausible values together reach `SUSPICIOUS_DEPTH_SHARE` of the pixels gets
//! a warning that says how much of the frame they are.

use std::path::Path;

use ivp_core::DepthMap;

use crate::error::{DataError, Result};

/// Below this (in scene units, e.g. metres) a finite positive depth is implausible: a micrometre in
/// a metre-scale scene, or depth stored in units a million times too large.
pub const MIN_PLAUSIBLE_DEPTH: f32 = 1e-6;

/// Above this (in scene units) a finite depth is implausible: a thousand kilometres in a metre-scale
/// scene. Sky belongs at `+inf`; 1e6 is far above the `z = 1000` cap of the warp's depth weights.
pub const MAX_PLAUSIBLE_DEPTH: f32 = 1e6;

/// A frame where invalid and implausible values together reach this share of the pixels gets a
/// warning (10%: a few bad pixels are common at silhouettes and in real sensors, a tenth of the
/// frame is not).
pub const SUSPICIOUS_DEPTH_SHARE: f64 = 0.1;

/// How many values of one depth map fall in each class (see the module documentation).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DepthStats {
    pub pixels: usize,
    pub usable: usize,
    /// `+inf` (sky).
    pub far: usize,
    /// `0`, no reading.
    pub missing: usize,
    /// Finite positive values outside `[MIN_PLAUSIBLE_DEPTH, MAX_PLAUSIBLE_DEPTH]`.
    pub implausible: usize,
    /// NaN, negative, `-inf`.
    pub invalid: usize,
}

impl DepthStats {
    /// Counts the values of `depth`. `nan_is_missing` is for formats whose reader encodes "no
    /// reading" as NaN (SceneNet); anywhere else a NaN is invalid.
    pub fn of(depth: &DepthMap, nan_is_missing: bool) -> Self {
        let mut s = DepthStats { pixels: depth.len(), ..Default::default() };
        for &[z] in depth.pixels() {
            if z.is_nan() {
                if nan_is_missing {
                    s.missing += 1;
                } else {
                    s.invalid += 1;
                }
            } else if z == 0.0 {
                s.missing += 1;
            } else if z < 0.0 {
                s.invalid += 1;
            } else if z == f32::INFINITY {
                s.far += 1;
            } else if (MIN_PLAUSIBLE_DEPTH..=MAX_PLAUSIBLE_DEPTH).contains(&z) {
                s.usable += 1;
            } else {
                s.implausible += 1;
            }
        }
        s
    }

    /// Invalid and implausible values together.
    pub fn bad(&self) -> usize {
        self.invalid + self.implausible
    }

    /// `count` as a share of the pixels (0 for an empty map).
    pub fn share(&self, count: usize) -> f64 {
        if self.pixels == 0 {
            0.0
        } else {
            count as f64 / self.pixels as f64
        }
    }

    /// True when the frame can be warped at all: at least one usable value.
    pub fn is_usable(&self) -> bool {
        self.usable > 0
    }

    /// Whether bad values reach `SUSPICIOUS_DEPTH_SHARE` of the frame.
    pub fn is_suspicious(&self) -> bool {
        self.bad() > 0 && self.share(self.bad()) >= SUSPICIOUS_DEPTH_SHARE
    }

    /// One line: "`usable` usable (x%), `far` sky, ...", classes with no value left out.
    pub fn summary(&self) -> String {
        let mut parts = vec![format!("{:.1}% usable", 100.0 * self.share(self.usable))];
        for (count, what) in [
            (self.far, "sky (+inf)"),
            (self.missing, "missing (0)"),
            (self.implausible, "implausible (< 1e-6 or > 1e6)"),
            (self.invalid, "invalid (NaN or negative)"),
        ] {
            if count > 0 {
                parts.push(format!("{:.1}% {what}", 100.0 * self.share(count)));
            }
        }
        format!("{} of {} pixels", parts.join(", "), self.pixels)
    }
}

/// Refuses a depth map without a usable value (error naming `path`) and warns about one with a
/// large share of invalid or implausible values.
pub(crate) fn check_depth(path: &Path, stats: &DepthStats) -> Result<()> {
    if !stats.is_usable() {
        return Err(DataError::invalid(
            path,
            format!(
                "no usable depth: {} (usable depth is finite and between {MIN_PLAUSIBLE_DEPTH:e} and \
                 {MAX_PLAUSIBLE_DEPTH:e} scene units)",
                stats.summary()
            ),
        ));
    }
    if let Some(warning) = depth_warning(path, stats) {
        tracing::warn!("{warning}");
    }
    Ok(())
}

/// The warning logged for a frame whose invalid and implausible values reach
/// `SUSPICIOUS_DEPTH_SHARE`: the file, their share of the frame and the counts of every class.
/// `None` for any other frame. Written apart from `check_depth` so that tests can read the text.
pub(crate) fn depth_warning(path: &Path, stats: &DepthStats) -> Option<String> {
    stats.is_suspicious().then(|| {
        format!(
            "{}: {:.1}% of the frame has invalid or implausible depth ({})",
            path.display(),
            100.0 * stats.share(stats.bad()),
            stats.summary()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(values: &[f32]) -> DepthMap {
        DepthMap::from_values(values.len(), 1, values.to_vec())
    }

    #[test]
    fn classes() {
        let d = map(&[1.0, f32::INFINITY, 0.0, -0.0, 1e-7, 2e6, f32::NAN, -1.0, f32::NEG_INFINITY, 1e6, 1e-6]);
        let s = DepthStats::of(&d, false);
        assert_eq!(s, DepthStats { pixels: 11, usable: 3, far: 1, missing: 2, implausible: 2, invalid: 3 });
        let s = DepthStats::of(&d, true);
        assert_eq!((s.missing, s.invalid), (3, 2));
    }

    #[test]
    fn unusable_frames_are_errors_naming_the_file() {
        let path = Path::new("/clip/depth/0003.exr");
        for values in [
            vec![f32::NAN; 4],
            vec![f32::INFINITY; 4],
            vec![0.0; 4],
            vec![-2.0; 4],
            vec![1e-9; 4],
            vec![1e9; 4],
            vec![0.0, f32::INFINITY, f32::NAN, -1.0],
        ] {
            let err = check_depth(path, &DepthStats::of(&map(&values), false)).unwrap_err();
            let msg = err.to_string();
            assert!(msg.contains("/clip/depth/0003.exr") && msg.contains("no usable depth"), "{msg}");
        }
    }

    #[test]
    fn sky_and_missing_are_allowed() {
        let s = DepthStats::of(&map(&[2.0, f32::INFINITY, f32::INFINITY, 0.0]), false);
        assert!(s.is_usable() && !s.is_suspicious());
        check_depth(Path::new("x.exr"), &s).unwrap();
    }

    #[test]
    fn suspicious_share() {
        let mut values = vec![1.0; 100];
        values[..9].fill(f32::NAN);
        assert!(!DepthStats::of(&map(&values), false).is_suspicious());
        values[9] = 1e-8;
        let s = DepthStats::of(&map(&values), false);
        assert!(s.is_suspicious());
        assert!(s.summary().contains("9.0% invalid"), "{}", s.summary());
        check_depth(Path::new("x.exr"), &s).unwrap();
    }

    #[test]
    fn a_tenth_of_bad_depth_warns_naming_the_file_and_the_share() {
        let path = Path::new("/clip/depth/0007.exr");
        // 100 pixels: 6 NaN and 4 implausibly far (10% bad), 5 sky, 85 usable.
        let mut values = vec![2.5; 100];
        values[..6].fill(f32::NAN);
        values[6..10].fill(1e9);
        values[10..15].fill(f32::INFINITY);
        let stats = DepthStats::of(&map(&values), false);
        assert_eq!(
            depth_warning(path, &stats).as_deref(),
            Some(
                "/clip/depth/0007.exr: 10.0% of the frame has invalid or implausible depth (85.0% usable, 5.0% sky \
                 (+inf), 4.0% implausible (< 1e-6 or > 1e6), 6.0% invalid (NaN or negative) of 100 pixels)"
            )
        );
        // A warning, not an error: the frame still loads.
        check_depth(path, &stats).unwrap();
        // One bad value fewer is below the share: no warning.
        values[9] = 2.5;
        assert_eq!(depth_warning(path, &DepthStats::of(&map(&values), false)), None);
        // Sky and missing readings alone never warn, however much of the frame they are.
        let sky_and_missing: Vec<f32> = (0..100).map(|i| [f32::INFINITY, 0.0, 3.0][i % 3]).collect();
        assert_eq!(depth_warning(path, &DepthStats::of(&map(&sky_and_missing), false)), None);
    }
}
