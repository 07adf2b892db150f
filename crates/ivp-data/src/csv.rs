//! `TransformationMatrices.csv` and `CameraIntrinsics.csv` (ALGORITHMS.md §3).

use std::fmt::Write as _;
use std::fs;
use std::path::Path;

use ivp_core::{Intrinsics, WorldToCamera};

use crate::error::{DataError, Result};
use crate::io::write_atomically;

pub const POSES_FILE: &str = "TransformationMatrices.csv";
pub const INTRINSICS_FILE: &str = "CameraIntrinsics.csv";

/// Below this |determinant| a world-to-camera matrix is taken as singular. A rigid transform has
/// |det| = 1 whatever the scene's scale, so this only catches degenerate rows.
const MIN_ABS_DETERMINANT: f64 = 1e-9;

/// How far the rotation part of a pose may be from orthonormal (largest element of `R^T R - I`)
/// and its determinant from +1. Poses written with 6-7 significant digits are within 1e-6; a
/// scaled or sheared matrix is off by far more.
pub const ROTATION_TOLERANCE: f64 = 1e-3;

/// How far the bottom row of a pose may be from `0 0 0 1`.
pub const BOTTOM_ROW_TOLERANCE: f64 = 1e-6;

/// Above this length (scene units) a pose's translation is implausible (100 km in metres);
/// [`crate::MAX_PLAUSIBLE_DEPTH`] is ten times more, so that a distant backdrop stays plausible.
pub const MAX_TRANSLATION: f64 = 1e5;

/// Intrinsics must have `fx`, `fy` between these multiples of the image width: 0.05 is a
/// field of view of about 170 degrees, 100 one of about 0.6 degrees.
pub const FOCAL_RANGE_IN_WIDTHS: (f64, f64) = (0.05, 100.0);

/// The principal point may lie this share of the width (height) outside the image.
pub const PRINCIPAL_POINT_SLACK: f64 = 0.1;

/// One pose per non-blank line, 16 row-major numbers each: a finite rigid transform (see
/// `check_pose`). Errors name the file and the line.
pub fn read_poses(path: &Path) -> Result<Vec<WorldToCamera>> {
    let mut poses = Vec::new();
    for (line, fields) in numeric_rows(path)? {
        let m: [f64; 16] = fields
            .try_into()
            .map_err(|f: Vec<f64>| DataError::csv(path, line, format!("expected 16 numbers, found {}", f.len())))?;
        let pose = WorldToCamera::from_row_major(m);
        check_pose(&pose).map_err(|problem| DataError::csv(path, line, problem))?;
        poses.push(pose);
    }
    Ok(poses)
}

/// Why a pose cannot be used, if it cannot: it must be finite, invertible and rigid (rotation part
/// orthonormal with determinant +1 within [`ROTATION_TOLERANCE`], bottom row `0 0 0 1` within
/// [`BOTTOM_ROW_TOLERANCE`]), with a translation shorter than [`MAX_TRANSLATION`].
pub(crate) fn check_pose(pose: &WorldToCamera) -> Result<(), String> {
    let m = pose.0;
    if !m.is_finite() {
        return Err("pose has non-finite numbers".into());
    }
    let det = m.determinant();
    if det.is_nan() || det.abs() < MIN_ABS_DETERMINANT {
        return Err(format!("pose is not invertible (determinant {det:e})"));
    }
    let bottom = m.row(3);
    let off_bottom = (bottom - glam::DVec4::W).abs().max_element();
    if off_bottom > BOTTOM_ROW_TOLERANCE {
        return Err(format!(
            "pose is not a rigid transform: bottom row is [{}, {}, {}, {}], expected [0, 0, 0, 1]",
            bottom.x, bottom.y, bottom.z, bottom.w
        ));
    }
    let r = glam::DMat3::from_mat4(m);
    let gram = r.transpose() * r;
    let off = (0..3)
        .flat_map(|i| (0..3).map(move |j| (i, j)))
        .map(|(i, j)| (gram.col(j)[i] - if i == j { 1.0 } else { 0.0 }).abs())
        .fold(0.0, f64::max);
    let r_det = r.determinant();
    if off > ROTATION_TOLERANCE {
        let scales = [r.x_axis.length(), r.y_axis.length(), r.z_axis.length()];
        return Err(format!(
            "pose is not a rigid transform: its rotation part is not orthonormal (R^T R differs from I by              {off:.3e} > {ROTATION_TOLERANCE:e}; column lengths {:.4}, {:.4}, {:.4}): remove any scale or shear",
            scales[0], scales[1], scales[2]
        ));
    }
    if (r_det - 1.0).abs() > ROTATION_TOLERANCE {
        return Err(format!(
            "pose is not a rigid transform: its rotation part has determinant {r_det:.4}, not +1 (a reflection:              flip the sign of one axis consistently)"
        ));
    }
    let t = m.w_axis.truncate().length();
    if t > MAX_TRANSLATION {
        return Err(format!("pose translation {t:e} is implausible (more than {MAX_TRANSLATION:e} scene units)"));
    }
    Ok(())
}

/// `K` as 3 rows of 3 numbers: `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]` with fx, fy > 0. The
/// checks that need the frame size (`check_intrinsics` with a size) are `Clip::open`'s.
pub fn read_intrinsics(path: &Path) -> Result<Intrinsics> {
    let rows = numeric_rows(path)?;
    if rows.len() != 3 {
        let line = rows.get(3).map_or(rows.last().map_or(1, |r| r.0), |r| r.0);
        return Err(DataError::csv(path, line, format!("expected 3 rows of 3 numbers, found {} rows", rows.len())));
    }
    let mut k = [[0.0; 3]; 3];
    for (i, (line, fields)) in rows.into_iter().enumerate() {
        k[i] = fields
            .try_into()
            .map_err(|f: Vec<f64>| DataError::csv(path, line, format!("expected 3 numbers, found {}", f.len())))?;
    }
    let intrinsics = Intrinsics::new(k[0][0], k[1][1], k[0][2], k[1][2]);
    // Skew and a projective last row cannot be represented by `Intrinsics`: refuse rather than drop them.
    let zeros_ok = k[0][1] == 0.0 && k[1][0] == 0.0 && k[2] == [0.0, 0.0, 1.0];
    if !zeros_ok {
        return Err(DataError::invalid(path, format!("K must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], found {k:?}")));
    }
    check_intrinsics(&intrinsics, None).map_err(|problem| DataError::invalid(path, problem))?;
    Ok(intrinsics)
}

/// The one rule for intrinsics: finite numbers with fx, fy > 0; given the frame size `(width,
/// height)`, also fx and fy within [`FOCAL_RANGE_IN_WIDTHS`] of the width and the principal point
/// inside the frame give or take [`PRINCIPAL_POINT_SLACK`].
pub(crate) fn check_intrinsics(k: &Intrinsics, size: Option<(usize, usize)>) -> Result<(), String> {
    let finite = [k.fx, k.fy, k.cx, k.cy].iter().all(|x| x.is_finite());
    // `finite` first: the comparisons below are then never with NaN.
    if !finite || k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(format!("intrinsics need finite numbers and fx, fy > 0, found {k:?}"));
    }
    let Some((width, height)) = size else { return Ok(()) };
    let (w, h) = (width as f64, height as f64);
    let (lo, hi) = FOCAL_RANGE_IN_WIDTHS;
    // Normalised intrinsics (in units of the frame size) put fx, fy and the principal point near 1.
    let normalised = k.fx <= 4.0 && k.fy <= 4.0 && k.cx <= 1.0 && k.cy <= 1.0;
    for (name, f) in [("fx", k.fx), ("fy", k.fy)] {
        if f < lo * w {
            let hint = if normalised {
                ": it looks like normalised intrinsics; give them in pixels (multiply fx and cx by the width, fy \
                 and cy by the height)"
            } else {
                ""
            };
            return Err(format!(
                "{name} {f} is implausibly small for a {width}x{height} frame (below {lo} x width = {}){hint}",
                lo * w
            ));
        }
        if f > hi * w {
            return Err(format!(
                "{name} {f:e} is implausibly large for a {width}x{height} frame (above {hi} x width = {})",
                hi * w
            ));
        }
    }
    for (name, c, extent) in [("cx", k.cx, w), ("cy", k.cy, h)] {
        let slack = PRINCIPAL_POINT_SLACK * extent;
        if c < -slack || c > extent + slack {
            return Err(format!(
                "principal point {name} {c} lies outside the {width}x{height} frame (allowed {} .. {})",
                -slack,
                extent + slack
            ));
        }
    }
    Ok(())
}

/// The non-blank lines of a CSV as (1-based line number, finite numbers). Fields are separated by
/// commas, or by white space on a line without commas (numpy's `savetxt` default).
fn numeric_rows(path: &Path) -> Result<Vec<(usize, Vec<f64>)>> {
    let text = fs::read_to_string(path).map_err(|e| DataError::io(path, "cannot read", e))?;
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line_number = i + 1;
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let fields: Vec<&str> = if line.contains(',') {
            line.split(',').map(str::trim).collect()
        } else {
            line.split_whitespace().collect()
        };
        let numbers = fields
            .iter()
            .enumerate()
            .map(|(j, field)| {
                parse_number(field).map_err(|p| DataError::csv(path, line_number, format!("field {}: {p}", j + 1)))
            })
            .collect::<Result<Vec<f64>>>()?;
        rows.push((line_number, numbers));
    }
    Ok(rows)
}

fn parse_number(field: &str) -> Result<f64, String> {
    let x: f64 = field.parse().map_err(|_| format!("`{field}` is not a number"))?;
    if x.is_finite() {
        Ok(x)
    } else {
        Err(format!("`{field}` is not a finite number"))
    }
}

/// Writes poses one per line; `{:?}` of f64 is the shortest text that parses back to the same bits.
pub fn write_poses(path: &Path, poses: &[WorldToCamera]) -> Result<()> {
    let rows: Vec<Vec<f64>> = poses.iter().map(|p| p.to_row_major().to_vec()).collect();
    write_atomically(path, format_rows(&rows).as_bytes())
}

pub fn write_intrinsics(path: &Path, k: &Intrinsics) -> Result<()> {
    let rows: Vec<Vec<f64>> = k.matrix().iter().map(|r| r.to_vec()).collect();
    write_atomically(path, format_rows(&rows).as_bytes())
}

fn format_rows(rows: &[Vec<f64>]) -> String {
    let mut text = String::new();
    for row in rows {
        for (j, x) in row.iter().enumerate() {
            let sep = if j == 0 { "" } else { "," };
            let _ = write!(text, "{sep}{x:?}");
        }
        text.push('\n');
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intrinsics_rule_names_the_problem() {
        let vga = Some((640, 480));
        check_intrinsics(&Intrinsics::new(525.0, 525.0, 319.5, 239.5), vga).unwrap();
        check_intrinsics(&Intrinsics::iisc_veed_default(), Some((1920, 1080))).unwrap();
        check_intrinsics(&Intrinsics::scenenet_default(), Some((320, 240))).unwrap();
        let err = check_intrinsics(&Intrinsics::new(0.9, 1.2, 0.5, 0.5), vga).unwrap_err();
        assert!(err.contains("fx 0.9") && err.contains("normalised intrinsics; give them in pixels"), "{err}");
        let err = check_intrinsics(&Intrinsics::new(1e300, 525.0, 319.5, 239.5), vga).unwrap_err();
        assert!(err.contains("implausibly large"), "{err}");
        // Without a size only the basic rule applies (`read_intrinsics`).
        check_intrinsics(&Intrinsics::new(0.9, 1.2, 0.5, 0.5), None).unwrap();
    }

    #[test]
    fn rigid_poses_pass_and_others_say_why() {
        use glam::{DMat4, DQuat, DVec3};
        let rigid = DMat4::from_rotation_translation(DQuat::from_rotation_z(0.3), DVec3::new(1.0, -2.0, 3.0));
        check_pose(&WorldToCamera(rigid)).unwrap();
        check_pose(&WorldToCamera(rigid.inverse())).unwrap();
        let scaled = DMat4::from_scale(DVec3::splat(1.01)) * rigid;
        assert!(check_pose(&WorldToCamera(scaled)).unwrap_err().contains("not orthonormal"));
        let far = DMat4::from_translation(DVec3::new(0.0, 0.0, 1e300)) * rigid;
        assert!(check_pose(&WorldToCamera(far)).unwrap_err().contains("translation"));
    }
}
