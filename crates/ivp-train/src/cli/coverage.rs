//! The flags every command that runs a model shares: how it covers a frame, at what scale, and
//! which holes it leaves to the thin-run rule.

use clap::Args;
use ivp_core::inference::{Coverage, Scale, TileShape};
use ivp_core::infill::THIN_RUN;

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
    /// Shrink frames by this integer factor before the network and the temporal prior see them;
    /// `auto` shrinks frames of 810 rows or more towards 540 rows (2 at 1080p).
    #[arg(long, default_value_t = Scale::Auto)]
    pub scale: Scale,
    /// Disocclusions in runs of at most this many unknown pixels between two known ones (along a
    /// row, else a column) copy the farther of the two before the network runs (0: the network
    /// fills every disocclusion, as in the paper; ALGORITHMS.md §6.5).
    #[arg(long, default_value_t = THIN_RUN)]
    pub thin_run: usize,
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
}
