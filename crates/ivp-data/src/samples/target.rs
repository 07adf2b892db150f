//! One training target of a clip: the frames it uses, and the warps and prior that every crop of
//! it reads (ALGORITHMS.md §5, §6.2), computed once.

use ivp_core::prior::{target_prior, TargetPrior};
use ivp_core::{relative_pose, warp_forward, RgbImage, VectorField, Warp};

use super::source::ClipFrames;

/// Which way a clip is played. A static scene seen along the reversed frame sequence is another
/// valid camera trajectory, with other disocclusions: it doubles the targets of every clip.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Playback {
    Forward,
    Reversed,
}

impl Playback {
    pub const BOTH: [Playback; 2] = [Playback::Forward, Playback::Reversed];
}

/// The frames of one target `t = n + 1`, as indices into the clip (whatever the direction).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct TargetFrames {
    /// Frame `n - 2`.
    pub before_last: usize,
    /// Frame `n`, the last rendered frame.
    pub last: usize,
    /// Frame `t = n + 1`, the ground truth.
    pub target: usize,
}

/// Along a trajectory, target position `p` uses positions `p - 3`, `p - 1` and `p`.
const FIRST_TARGET_POSITION: usize = 3;

impl TargetFrames {
    /// How many targets a clip of `frames` frames has in each direction: `t` runs over
    /// `3..frames` so that `n - 2 = t - 3 >= 0`.
    pub fn per_direction(frames: usize) -> usize {
        frames.saturating_sub(FIRST_TARGET_POSITION)
    }

    /// Target number `i` (`0..per_direction(frames)`) of a clip of `frames` frames played in `direction`.
    pub fn new(frames: usize, direction: Playback, i: usize) -> Self {
        assert!(i < Self::per_direction(frames), "target {i} of a {frames}-frame clip");
        let position = FIRST_TARGET_POSITION + i;
        let frame = |p: usize| match direction {
            Playback::Forward => p,
            Playback::Reversed => frames - 1 - p,
        };
        Self { before_last: frame(position - 3), last: frame(position - 1), target: frame(position) }
    }
}

/// What every crop of one target reads, at full frame size.
#[derive(Debug)]
pub(crate) struct PreparedTarget {
    pub frames: TargetFrames,
    /// `f_n` warped into view `t`: `f^w_t`, `d^w_t` and the holes of `t`.
    pub warped: Warp,
    /// The temporal prior of `t` (ALGORITHMS.md §6.2), zero on the holes of `t`.
    pub prior: VectorField,
    /// `f_{n-2}` warped into view `n`: `f^w_n`, for the intensity ablation.
    pub last_warped: RgbImage,
    /// Row-major indices of the disocclusion pixels of `warped`: the possible crop centres.
    pub disocclusions: Vec<u32>,
}

impl PreparedTarget {
    /// Warps `n - 2 -> n` and `n -> t` and computes the prior of `t` (ALGORITHMS.md §6.2 steps 1-3).
    /// `None` when the warp `n -> t` has no disocclusion: such a target gives no sample.
    pub fn compute(clip: &ClipFrames, frames: TargetFrames) -> Option<Self> {
        let k = &clip.intrinsics;
        let (last, target_pose) = (clip.view(frames.last), &clip.poses[frames.target]);
        // Cheapest first: most targets of a moving camera have disocclusions, but a still one has none.
        let warped = warp_forward(last.image, last.depth, k, &relative_pose(last.pose, target_pose));
        let disocclusions: Vec<u32> = (warped.holes.disocclusions().iter().enumerate())
            .filter_map(|(i, &hole)| hole.then_some(i as u32))
            .collect();
        if disocclusions.is_empty() {
            return None;
        }
        let before_last = clip.view(frames.before_last);
        let TargetPrior { prior, warp_to_last } =
            target_prior(&before_last, &last, target_pose, k, &warped.holes.known());
        Some(Self { frames, warped, prior, last_warped: warp_to_last.image, disocclusions })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_of_a_twelve_frame_clip() {
        assert_eq!(TargetFrames::per_direction(12), 9);
        assert_eq!(TargetFrames::per_direction(3), 0);
        let first = TargetFrames::new(12, Playback::Forward, 0);
        assert_eq!(first, TargetFrames { before_last: 0, last: 2, target: 3 });
        let last = TargetFrames::new(12, Playback::Forward, 8);
        assert_eq!(last, TargetFrames { before_last: 8, last: 10, target: 11 });
        let reversed = TargetFrames::new(12, Playback::Reversed, 0);
        assert_eq!(reversed, TargetFrames { before_last: 11, last: 9, target: 8 });
        let reversed_last = TargetFrames::new(12, Playback::Reversed, 8);
        assert_eq!(reversed_last, TargetFrames { before_last: 3, last: 1, target: 0 });
    }
}
