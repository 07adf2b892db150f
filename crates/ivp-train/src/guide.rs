//! The guide term of the first training steps: what it pulls the vectors towards, and the term
//! itself. It follows the conventions of the paper's losses (`ivp_core::nn::loss`): `|x|` with
//! PyTorch's gradient at 0, a mean over the guided pixels that is exactly 0 when there are none.

use anyhow::{bail, Result};
use candle_core::Tensor;
use ivp_core::geometry::NearestKnown;
use ivp_core::infill::rules::background_source;
use ivp_core::nn::loss::abs;
use ivp_core::nn::model::{NetInput, Variant};
use ivp_core::prior::background_depth_threshold;
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

/// The guide terms of one step: the guide's target (`None`: no guide) and weight, and the weight
/// of the foreground guard ([`GuideTarget::at_foreground_reads`]; 0: none).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Guide {
    pub source: Option<GuideSource>,
    pub weight: f64,
    pub foreground_guard: f64,
}

impl Guide {
    /// No guide term.
    pub const NONE: Guide = Guide { source: None, weight: 0.0, foreground_guard: 0.0 };

    /// The guide of `variant` ([`GuideSource::of`]) at `weight`, without the foreground guard.
    pub fn of(variant: Variant, weight: f64) -> Self {
        Self { source: GuideSource::of(variant), weight, foreground_guard: 0.0 }
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
            let known = warp_covered(&depth);
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

    /// This target on those of its pixels alone whose vector in `vectors` (B, 2, H, W), rounded to
    /// the nearest pixel, reads a known pixel of `warped_depth` nearer than the pixel's background
    /// depth threshold (ALGORITHMS.md §6.5): the *foreground guard*. Why: a vector that reads the
    /// near object beside a sliver lowers the paper's losses against reading the black hole, and
    /// a heavier MSE term made some seeds settle there (results/recipe-hd); the guard pulls such
    /// vectors towards the background side and lets go as soon as they read it. Where it applies
    /// is decided on the vectors as they are, not differentiated.
    pub(crate) fn at_foreground_reads(&self, vectors: &Tensor, warped_depth: &Tensor) -> Result<Self> {
        let (b, _, h, w) = warped_depth.dims4()?;
        if vectors.dims() != [b, 2, h, w] {
            bail!("foreground guard: vectors {:?} for a warped depth {:?}", vectors.dims(), warped_depth.dims());
        }
        let vectors = vectors.detach().flatten_all()?.to_vec1::<f32>()?;
        let guided = self.weight.flatten_all()?.to_vec1::<f32>()?;
        let plane = h * w;
        let mut at_foreground = vec![0f32; b * plane];
        for i in 0..b {
            let depth: DepthMap = ivp_core::nn::tensor::from_tensor(&warped_depth.narrow(0, i, 1)?)?;
            let known = warp_covered(&depth);
            let thresholds = background_depth_threshold(&known, &depth);
            let (dx, dy) = (&vectors[2 * i * plane..][..plane], &vectors[(2 * i + 1) * plane..][..plane]);
            for p in (0..plane).filter(|&p| guided[i * plane + p] != 0.0) {
                let Some(threshold) = thresholds[p] else { continue };
                let (x, y) = ((p % w) as f32 + dx[p], (p / w) as f32 + dy[p]);
                let (x, y) = (x.round(), y.round());
                if !(x >= 0.0 && y >= 0.0 && x < w as f32 && y < h as f32) {
                    continue;
                }
                let (x, y) = (x as usize, y as usize);
                if known[y * w + x] && depth.at(x, y) < threshold {
                    at_foreground[i * plane + p] = 1.0;
                }
            }
        }
        let weight = Tensor::from_vec(at_foreground, (b, 1, h, w), warped_depth.device())?;
        let count = weight.sum_all()?.to_scalar::<f32>()? as f64;
        Ok(Self { vectors: self.vectors.clone(), weight, count })
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

/// The pixels the warp covered: those of non-zero, non-NaN warped depth.
fn warp_covered(warped_depth: &DepthMap) -> Vec<bool> {
    warped_depth.pixels().iter().map(|&[z]| z != 0.0 && !z.is_nan()).collect()
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
    fn the_foreground_guard_applies_where_a_vector_reads_the_near_side_only() {
        // The strip of the test above: foreground (depth 1) at 0..3, a hole at 3..6, background
        // (depth 5) at 6..9; the hole's background threshold is (1 + 5) / 2 = 3.
        let (w, h) = (9, 1);
        let depth: Vec<f32> = (0..w).map(|x| [1.0, 0.0, 5.0][x / 3]).collect();
        let mask: Vec<f32> = (0..w).map(|x| f32::from((3..6).contains(&x))).collect();
        let (depth, mask) = (tensor(depth, (1, 1, h, w)), tensor(mask, (1, 1, h, w)));
        let fill = GuideTarget::fill_vectors(&depth, &mask).unwrap();
        // Hole pixels 3, 4, 5 read pixel 2 (foreground), 8 (background) and 4 (the hole, unknown).
        let dx = vec![0.0, 0.0, 0.0, -1.0, 4.0, -1.0, 0.0, 0.0, 0.0];
        let vectors = Var::from_tensor(&tensor([dx.clone(), vec![0.0; 9]].concat(), (1, 2, h, w))).unwrap();
        let guard = fill.at_foreground_reads(&vectors, &depth).unwrap();
        assert_eq!(guard.count, 1.0);
        // Pixel 3's target is (3, 0): |-1 - 3| over 2 components, divided by the 3 hole pixels.
        let loss = guard.loss(&vectors, 3.0).unwrap();
        assert_eq!(loss.to_scalar::<f32>().unwrap(), 4.0 / 6.0);
        let grad = loss.backward().unwrap().get(&vectors).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let moved: Vec<usize> = (0..2 * w).filter(|&i| grad[i] != 0.0).collect();
        assert_eq!(moved, [3], "pulls pixel 3 alone, towards the background: {grad:?}");
        assert!(grad[3] < 0.0);
        // Rounded to the nearest pixel (4 and 5 read pixel 2); outside the frame (3), or reading
        // the hole: no guard.
        let outside =
            tensor([vec![0.0, 0.0, 0.0, -3.6, -2.4, -3.4, 0.0, 0.0, 0.0], vec![0.0; 9]].concat(), (1, 2, h, w));
        assert_eq!(fill.at_foreground_reads(&outside, &depth).unwrap().count, 2.0);
        let in_the_hole =
            tensor([vec![0.0, 0.0, 0.0, 1.0, 0.4, -1.0, 0.0, 0.0, 0.0], vec![0.0; 9]].concat(), (1, 2, h, w));
        assert_eq!(fill.at_foreground_reads(&in_the_hole, &depth).unwrap().count, 0.0);
        // Nothing known: no threshold, no guard, and a zero loss rather than NaN.
        let unknown = depth.zeros_like().unwrap();
        let none = GuideTarget::fill_vectors(&unknown, &mask).unwrap().at_foreground_reads(&vectors, &unknown).unwrap();
        assert_eq!((none.count, none.loss(&vectors, 3.0).unwrap().to_scalar::<f32>().unwrap()), (0.0, 0.0));
        // Vectors of another size are an error.
        assert!(fill.at_foreground_reads(&vectors.narrow(3, 0, 8).unwrap(), &depth).is_err());
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
