//! The guide term of the first training steps: what it pulls the vectors towards, and the term
//! itself. It follows the conventions of the paper's losses (`ivp_core::nn::loss`): `|x|` with
//! PyTorch's gradient at 0, a mean over the guided pixels that is exactly 0 when there are none.

use anyhow::{bail, Result};
use candle_core::Tensor;
use ivp_core::geometry::NearestKnown;
use ivp_core::infill::rules::background_source;
use ivp_core::nn::loss::abs;
use ivp_core::nn::model::{NetInput, Variant};
use ivp_core::{DepthMap, Image, VectorField};
use serde::{Deserialize, Serialize};

/// The guide's target as a training configuration names it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuideChoice {
    /// From what the variant reads ([`GuideSource::of`]): the depth-aware `fill` vectors for the
    /// variants that read depth (`full`, `no-tg`), the spread temporal prior for `no-depth`.
    #[default]
    Auto,
    /// The `fill` vectors, for every vector variant.
    Fill,
    /// The spread temporal prior, for the variants that read it (`full` was guided so until
    /// 2026-12-03).
    Prior,
}

impl GuideChoice {
    /// The target of `variant`'s guide (`None` for the variant without vectors).
    pub fn source_for(self, variant: Variant) -> Result<Option<GuideSource>> {
        let of_variant = GuideSource::of(variant);
        Ok(match self {
            GuideChoice::Auto => of_variant,
            GuideChoice::Fill => of_variant.map(|_| GuideSource::DepthFill),
            GuideChoice::Prior if variant.predicts_vectors() && !variant.reads_temporal_prior() => {
                bail!("guide = \"prior\": variant {variant} does not read the temporal prior")
            }
            GuideChoice::Prior => of_variant.map(|_| GuideSource::TemporalPrior),
        })
    }
}

/// Radius of the window over which [`guide_loss`] spreads the prior into the holes.
pub const GUIDE_RADIUS: usize = 10;

/// Where the guide term of the first steps takes its target vectors from.
///
/// Why a guide: the paper's losses see the vectors only through the bilinear read of the warped
/// frame, whose holes are black. A vector that reads the foreground next to a sliver lowers the
/// loss compared with reading black, and a vector that lands inside a wide hole gets no gradient
/// at all, so an unguided network learns the background side only slowly (`no-tg` without a
/// guide validated at 3x `fill`'s D-MSE after 5000 steps). Pulling the vectors towards a
/// reasonable field first gives training a start; the guide then fades out and the paper's
/// losses refine the vectors. The target is built only from inputs the variant reads, so an
/// ablation never learns through the loss from what it removes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GuideSource {
    /// The temporal prior spread into the holes ([`guide_loss`]); for the variant that reads the
    /// prior but not depth (`no-depth`).
    TemporalPrior,
    /// The depth-aware `fill` vectors of the warped depth ([`fill_guide_loss`]), for the variants
    /// that read depth. Over three seeds it trains `full` steadier and better than the prior
    /// (results/recipe/README.md).
    DepthFill,
}

/// The guide term of one step: its target (`None`: no guide) and its weight.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guide {
    pub source: Option<GuideSource>,
    pub weight: f64,
}

impl Guide {
    /// No guide term.
    pub const NONE: Guide = Guide { source: None, weight: 0.0 };

    /// The guide of `variant` ([`GuideSource::of`]) at `weight`.
    pub fn of(variant: Variant, weight: f64) -> Self {
        Self { source: GuideSource::of(variant), weight }
    }
}

impl GuideSource {
    /// The guide of `variant`, from its own inputs only: the `fill` vectors if it reads depth,
    /// else the spread prior; `None` for the variant without vectors (`intensity`).
    pub fn of(variant: Variant) -> Option<Self> {
        if !variant.predicts_vectors() {
            None
        } else if variant.reads_depth() {
            Some(Self::DepthFill)
        } else {
            Some(Self::TemporalPrior)
        }
    }
}

/// The guide term towards the temporal prior: the mean absolute difference, over the
/// disocclusion pixels, between the vectors and the prior spread into the holes (each pixel the
/// mean of the non-zero prior vectors within [`GUIDE_RADIUS`]); pixels without any prior nearby
/// are left out. The spread prior alone, used as vectors at test time, beats `fill` on
/// data/blender-dev.
pub fn guide_loss(vectors: &Tensor, prior: &Tensor, mask: &Tensor) -> Result<Tensor> {
    let target = GuideTarget::spread_prior(prior, mask)?;
    target.loss(vectors, target.count)
}

/// The guide term towards `fill`: the mean absolute difference, over the disocclusion pixels,
/// between the vectors and the vector from each pixel to the pixel the `fill` rule copies (of
/// the nearest known pixels in the four directions, the one with the largest warped depth).
/// Known pixels are those with a non-zero warped depth; a hole pixel with no known pixel in any
/// direction is left out.
pub fn fill_guide_loss(vectors: &Tensor, warped_depth: &Tensor, mask: &Tensor) -> Result<Tensor> {
    let target = GuideTarget::fill_vectors(warped_depth, mask)?;
    target.loss(vectors, target.count)
}

/// What a guide term compares the vectors with: target vectors, and the pixels they apply to.
pub(crate) struct GuideTarget {
    /// The target vectors: (B, 2, H, W).
    vectors: Tensor,
    /// 1 at the disocclusion pixels with a target: (B, 1, H, W).
    weight: Tensor,
    /// The number of such pixels.
    pub(crate) count: f64,
}

impl GuideTarget {
    pub(crate) fn new(source: GuideSource, input: &NetInput<'_>) -> Result<Self> {
        match source {
            GuideSource::TemporalPrior => Self::spread_prior(input.prior, input.mask),
            GuideSource::DepthFill => Self::fill_vectors(input.warped_depth, input.mask),
        }
    }

    fn spread_prior(prior: &Tensor, mask: &Tensor) -> Result<Self> {
        Self::per_sample(prior, mask, |i| {
            let field: VectorField = ivp_core::nn::tensor::from_tensor(&prior.narrow(0, i, 1)?)?;
            Ok(ivp_core::prior::mean_of_nonzero_vectors(&field, GUIDE_RADIUS))
        })
    }

    fn fill_vectors(warped_depth: &Tensor, mask: &Tensor) -> Result<Self> {
        Self::per_sample(warped_depth, mask, |i| {
            let depth: DepthMap = ivp_core::nn::tensor::from_tensor(&warped_depth.narrow(0, i, 1)?)?;
            let hole: Image<1> = ivp_core::nn::tensor::from_tensor(&mask.narrow(0, i, 1)?)?;
            let (w, h) = (depth.width(), depth.height());
            let known: Vec<bool> = depth.pixels().iter().map(|&[z]| z != 0.0 && !z.is_nan()).collect();
            let nearest = NearestKnown::new(w, h, &known);
            let mut field = VectorField::zeros(w, h);
            for v in 0..h {
                for u in 0..w {
                    if hole.at(u, v) == 0.0 {
                        continue;
                    }
                    if let Some((su, sv)) = background_source(&nearest, &depth, (u, v)) {
                        field.set(u, v, [su as f32 - u as f32, sv as f32 - v as f32]);
                    }
                }
            }
            Ok(field)
        })
    }

    /// Stacks the target field `field_of(i)` of each sample `i` of a (B, C, H, W) `like`; a
    /// pixel is guided where it is a disocclusion and its target is not zero.
    fn per_sample(like: &Tensor, mask: &Tensor, field_of: impl Fn(usize) -> Result<VectorField>) -> Result<Self> {
        let (b, _, h, w) = like.dims4()?;
        let mut target = Vec::with_capacity(b * 2 * h * w);
        let mut has_target = Vec::with_capacity(b * h * w);
        for i in 0..b {
            let field = field_of(i)?;
            for c in 0..2 {
                target.extend(field.pixels().iter().map(|p| p[c]));
            }
            has_target.extend(field.pixels().iter().map(|p| f32::from(p[0] != 0.0 || p[1] != 0.0)));
        }
        let vectors = Tensor::from_vec(target, (b, 2, h, w), like.device())?;
        let weight = (Tensor::from_vec(has_target, (b, 1, h, w), like.device())? * mask)?;
        // An exact count: a sum of at most 2^24 ones in f32.
        let count = weight.sum_all()?.to_scalar::<f32>()? as f64;
        Ok(Self { vectors, weight, count })
    }

    /// The guide term of `vectors`, divided by `count` guided pixels (these, or the whole batch's).
    pub(crate) fn loss(&self, vectors: &Tensor, count: f64) -> Result<Tensor> {
        let difference = abs(&(vectors - &self.vectors)?)?.broadcast_mul(&self.weight)?.sum_all()?;
        Ok((difference / (2.0 * count.max(1.0)))?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{Device, Var};

    fn tensor(v: Vec<f32>, shape: (usize, usize, usize, usize)) -> Tensor {
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    #[test]
    fn fill_guide_points_to_the_farther_side_of_a_hole() {
        // A 1 x 9 strip: foreground (depth 1) at 0..3, a hole at 3..6, background (depth 5) at 6..9.
        let (w, h) = (9, 1);
        let depth: Vec<f32> = (0..w).map(|x| [1.0, 0.0, 5.0][x / 3]).collect();
        let mask: Vec<f32> = (0..w).map(|x| f32::from((3..6).contains(&x))).collect();
        let (depth, mask) = (tensor(depth, (1, 1, h, w)), tensor(mask, (1, 1, h, w)));
        // Hole pixel x copies pixel 6, the nearest background pixel: vector (6 - x, 0).
        let on_target =
            tensor([vec![0.0, 0.0, 0.0, 3.0, 2.0, 1.0, 0.0, 0.0, 0.0], vec![0.0; 9]].concat(), (1, 2, h, w));
        assert_eq!(fill_guide_loss(&on_target, &depth, &mask).unwrap().to_scalar::<f32>().unwrap(), 0.0);
        let zeros = Var::from_tensor(&on_target.zeros_like().unwrap()).unwrap();
        let loss = fill_guide_loss(&zeros, &depth, &mask).unwrap();
        // (3 + 2 + 1) over 2 components and 3 pixels.
        assert_eq!(loss.to_scalar::<f32>().unwrap(), 1.0);
        let grad = loss.backward().unwrap().get(&zeros).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(grad[3] < 0.0 && grad[0] == 0.0 && grad[7] == 0.0, "moves hole vectors only: {grad:?}");
        // All hole (nothing known) or no hole: exactly 0, never NaN.
        let all_hole = fill_guide_loss(&zeros, &depth.zeros_like().unwrap(), &mask).unwrap();
        assert_eq!(all_hole.to_scalar::<f32>().unwrap(), 0.0);
        let none = fill_guide_loss(&zeros, &depth, &mask.zeros_like().unwrap()).unwrap();
        assert_eq!(none.to_scalar::<f32>().unwrap(), 0.0);
    }

    #[test]
    fn guide_pulls_hole_vectors_towards_the_spread_prior() {
        // A 1 x 9 strip: prior (2, 0) at the known pixels 0..3, a hole at 4..6, no prior at 7..9.
        let (w, h) = (9, 1);
        let mut prior = vec![0f32; 2 * w];
        prior[..3].fill(2.0);
        let mask: Vec<f32> = (0..w).map(|x| f32::from((4..7).contains(&x))).collect();
        let (prior, mask) = (tensor(prior, (1, 2, h, w)), tensor(mask, (1, 1, h, w)));
        // Within GUIDE_RADIUS of the prior, every hole pixel's target is (2, 0).
        let on_target = tensor([vec![0.0; 4], vec![2.0; 3], vec![0.0; 2], vec![0.0; 9]].concat(), (1, 2, h, w));
        assert_eq!(guide_loss(&on_target, &prior, &mask).unwrap().to_scalar::<f32>().unwrap(), 0.0);
        let zeros = Var::from_tensor(&on_target.zeros_like().unwrap()).unwrap();
        let loss = guide_loss(&zeros, &prior, &mask).unwrap();
        // |0 - 2| + |0 - 0| over 2 components, averaged over the 3 hole pixels.
        assert_eq!(loss.to_scalar::<f32>().unwrap(), 1.0);
        let grad = loss.backward().unwrap().get(&zeros).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        assert!(grad[4] < 0.0 && grad[0] == 0.0, "moves hole vectors only, towards the target: {grad:?}");
        // No hole, or no prior anywhere: exactly 0, never NaN.
        let none = guide_loss(&zeros, &prior, &mask.zeros_like().unwrap()).unwrap();
        assert_eq!(none.to_scalar::<f32>().unwrap(), 0.0);
        let no_prior = guide_loss(&zeros, &prior.zeros_like().unwrap(), &mask).unwrap();
        assert_eq!(no_prior.to_scalar::<f32>().unwrap(), 0.0);
    }
}
