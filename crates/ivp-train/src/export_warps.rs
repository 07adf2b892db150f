//! Warped frames on disk: `ivp warp`'s single warp, and every evaluation target of a dataset
//! warped the way `eval` warps it, so that another tool can infill the very same disocclusions.

use std::path::Path;

use anyhow::{bail, Context, Result};
use ivp_core::infill::fill_new_regions;
use ivp_core::{relative_pose, warp_forward, PixelClass, Warp};
use ivp_data::{find_clips, write_depth_exr, write_gray_png, write_rgb_png, Clip};

use crate::eval::{check_targets, clip_name, warp_to_target};
use crate::progress::progress_bar;

/// How much of a warped frame is left to infill, in percent of its pixels.
#[derive(Clone, Copy, Debug)]
pub struct HolePercentages {
    pub disocclusions: f64,
    pub new_regions: f64,
}

/// Warps frame `from` of `clip` into the view of frame `to` and writes `OUT/warped.png` (see
/// [`write_warp`]), `OUT/holes.png` and `OUT/depth.exr`.
pub fn write_frame_pair_warp(clip: &Clip, from: usize, to: usize, out: &Path) -> Result<HolePercentages> {
    for i in [from, to] {
        if i >= clip.len() {
            bail!("{}: frame {i} does not exist (the clip has frames 0..={})", clip.path().display(), clip.len() - 1);
        }
    }
    let frame = clip.load_frame(from)?;
    let transform = relative_pose(clip.pose(from), clip.pose(to));
    let warp = warp_forward(&frame.image, &frame.depth, clip.intrinsics(), &transform);
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_warp(&warp, &out.join("warped.png"), &out.join("holes.png"))?;
    write_depth_exr(out.join("depth.exr"), &warp.depth)?;
    let holes = &warp.holes;
    let total = holes.classes().len() as f64;
    Ok(HolePercentages {
        disocclusions: 100.0 * holes.count(PixelClass::Disocclusion) as f64 / total,
        new_regions: 100.0 * holes.count(PixelClass::NewRegion) as f64 / total,
    })
}

/// What [`export_targets`] wrote.
#[derive(Clone, Copy, Debug)]
pub struct ExportedTargets {
    pub clips: usize,
    /// Targets over all clips.
    pub targets: usize,
}

/// Writes `OUT/<clip name>/<t:04>.png` and `<t:04>_holes.png` for every target `t` of every clip
/// under `data`: frame `t - 1` warped to `t`, exactly as `eval` warps it.
pub fn export_targets(data: &Path, targets: &[usize], out: &Path, progress: bool) -> Result<ExportedTargets> {
    let clips: Vec<Clip> = find_clips(data)?.iter().map(Clip::open).collect::<Result<_, _>>()?;
    // Every clip is checked before the first file is written, so that a bad target leaves nothing behind.
    for clip in &clips {
        check_targets(clip, targets)?;
    }
    let bar = progress_bar(progress, (clips.len() * targets.len()) as u64, "exporting");
    for clip in &clips {
        let dir = out.join(clip_name(data, clip.path()));
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        for &t in targets {
            let warp = warp_to_target(clip, &clip.load_frame(t - 1)?, t);
            write_warp(&warp, &dir.join(format!("{t:04}.png")), &dir.join(format!("{t:04}_holes.png")))?;
            bar.inc(1);
        }
    }
    bar.finish_and_clear();
    Ok(ExportedTargets { clips: clips.len(), targets: clips.len() * targets.len() })
}

/// The warped frame with new regions filled by the common rule and disocclusions black (what every
/// method starts from), and its holes image (255 disocclusion, 128 new region, 0 known).
pub fn write_warp(warp: &Warp, image_path: &Path, holes_path: &Path) -> Result<()> {
    let mut image = warp.image.clone();
    fill_new_regions(&mut image, &warp.holes);
    write_rgb_png(image_path, &image)?;
    write_gray_png(holes_path, warp.holes.width(), warp.holes.height(), &warp.holes.to_gray8())?;
    Ok(())
}
