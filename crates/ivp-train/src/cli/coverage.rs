//! The flags every command that runs a model shares: how it covers a frame, at what scale, and
//! with which rules around the network's passes.

use clap::Args;
use ivp_core::inference::{Coverage, PriorScale, Scale, TileShape};
use ivp_core::infill::{InfillRules, FAR_BLUR, THIN_RUN};

/// How a trained model covers a frame: sparse tiles by default, `--dense` for one pass over the
/// whole frame (for comparison; the results agree within the tolerance PERFORMANCE.md states).
#[derive(Args, Clone, Copy, Debug)]
pub struct CoverageArgs {
    /// Run the network over the whole frame instead of only the tiles that hold disocclusions.
    #[arg(long)]
    pub dense: bool,
    /// Side of the cells that sparse inference keeps, in pixels of the frame as given (a multiple
    /// of 16; a frame shrunk by --scale reads cells shrunk with it, rounded up to 16).
    #[arg(long, default_value_t = TileShape::DEFAULT.core)]
    pub tile_core: usize,
    /// Context read around each cell, in pixels of the frame as given (a multiple of 16; shrunk
    /// with the frame like --tile-core).
    #[arg(long, default_value_t = TileShape::DEFAULT.margin)]
    pub tile_margin: usize,
    /// Shrink frames by this integer factor before the network sees them; `auto` shrinks frames of
    /// 810 rows or more towards 540 rows (2 at 1080p).
    #[arg(long, default_value_t = Scale::Auto)]
    pub scale: Scale,
    /// Shrink frames by this integer factor before the temporal prior is measured on them; `auto`
    /// shrinks them twice as much as --scale where it shrinks them (4 at 1080p), else as much.
    #[arg(long, default_value_t = PriorScale::Auto)]
    pub prior_scale: PriorScale,
    /// Disocclusions in runs of at most this many unknown pixels between two known ones (along a
    /// row, else a column) copy the farther of the two before the network runs (0: the network
    /// fills every disocclusion, as in the paper; ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = THIN_RUN)]
    pub thin_run: usize,
    /// After the passes, blur each infilled disocclusion pixel over a window of this many pixels
    /// per pixel of its distance to the known frame (0: no blur, as in the paper; ALGORITHMS.md
    /// §6.5).
    #[arg(long, default_value_t = FAR_BLUR, value_parser = parse_far_blur, allow_hyphen_values = true)]
    pub far_blur: f32,
}

impl CoverageArgs {
    pub fn coverage(&self) -> anyhow::Result<Coverage> {
        if self.dense {
            return Ok(Coverage::Dense);
        }
        let shape = TileShape::new(self.tile_core, self.tile_margin)
            .map_err(|e| anyhow::anyhow!("--tile-core/--tile-margin: {e}"))?;
        Ok(Coverage::Sparse(shape))
    }

    /// The rules around the passes.
    pub fn rules(&self) -> InfillRules {
        InfillRules { thin_run: self.thin_run, far_blur: self.far_blur }
    }
}

fn parse_far_blur(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(strength) if strength.is_finite() && strength >= 0.0 => Ok(strength),
        _ => Err(format!("--far-blur must be a finite number of 0 or more, not `{s}`")),
    }
}
