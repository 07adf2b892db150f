//! `TransformationMatrices.csv` and `CameraIntrinsics.csv` (SPEC §3).

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

/// One pose per non-blank line, 16 row-major numbers each, finite and invertible.
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

/// Why a pose cannot be used, if it cannot: it must be finite and invertible.
pub(crate) fn check_pose(pose: &WorldToCamera) -> Result<(), String> {
    if !pose.0.is_finite() {
        return Err("pose has non-finite numbers".into());
    }
    let det = pose.0.determinant();
    if det.is_nan() || det.abs() < MIN_ABS_DETERMINANT {
        return Err(format!("pose is not invertible (determinant {det:e})"));
    }
    Ok(())
}

/// `K` as 3 rows of 3 numbers: `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]` with fx, fy > 0.
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
    check_intrinsics(&intrinsics).map_err(|problem| DataError::invalid(path, problem))?;
    Ok(intrinsics)
}

pub(crate) fn check_intrinsics(k: &Intrinsics) -> Result<(), String> {
    let finite = [k.fx, k.fy, k.cx, k.cy].iter().all(|x| x.is_finite());
    // `finite` first: the comparisons below are then never with NaN.
    if !finite || k.fx <= 0.0 || k.fy <= 0.0 {
        return Err(format!("intrinsics need finite numbers and fx, fy > 0, found {k:?}"));
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
