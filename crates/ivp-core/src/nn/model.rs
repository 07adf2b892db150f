//! The IVP network of ALGORITHMS.md §6.1: a depth head that normalises the warped depth, and a U-Net that
//! turns (temporal prior, normalised depth) into infilling vectors for the disocclusions.
//!
//! Parameter names equal the `state_dict` names of `IvpUNet` in `shared/bench/torch_reference.py`
//! (`depth.c1.weight`, `e1.weight`, ..., `d9.bias`), so exported weights load there unchanged.
//!
//! | layer | input | output | kernel | stride |
//! |---|---|---|---|---|
//! | depth.c1 | warped depth (1) | 16 h | 7 | 2 |
//! | depth.c2 | 16 h | 32 h | 7 | 2 |
//! | depth.c3 | bilinear x2 of c2 (32 h) | 16 h | 7 | 1 |
//! | depth.c4 | bilinear to input size (16 h) | 1, sigmoid | 7 | 1 |
//! | e1 | prior (2) + depth head (1) | 64 m | 7 | 1 |
//! | e2 .. e5 | | 128 m, 256 m, 256 m, 256 m | 5, 3, 3, 3 | 2 |
//! | d6 .. d8 | nearest x2 of the last + skip e4, e3, e2 | 256 m, 128 m, 64 m | 3 | 1 |
//! | d9 | nearest x2 of d8 + skip e1 | 2 (vectors, no ReLU) | 3 | 1 |
//!
//! `m` is the width multiplier and `h` the depth head's (1 in the paper; the recipe trains
//! `m` = `h` = 0.25, since at `m` = 0.25 the paper's head is 39% of the multiply-adds).
//!
//! The intensity-prediction ablation keeps this shape but reads `f_n`, `f^w_n`, the depth head's
//! output and `f^w_{n+1}` (10 channels) and ends in 3 channels through a sigmoid: RGB for the holes.

mod inference;

use std::collections::HashMap;
use std::fmt;
use std::str::FromStr;

use candle_core::{DType, Device, Result, Tensor, Var};
use candle_nn::{Init, VarBuilder, VarMap};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::nn::ops::{conv2d, conv2d_relu, sample_bilinear, upsample_bilinear_to, upsample_concat};

/// The encoder widths at width multiplier 1 (the paper's).
pub const ENCODER_WIDTHS: [usize; 5] = [64, 128, 256, 256, 256];

/// The output widths of the depth head's `c1 .. c3` at depth-head multiplier 1 (the paper's).
pub const DEPTH_HEAD_WIDTHS: [usize; 3] = [16, 32, 16];

/// What the network predicts and from what (ALGORITHMS.md §6.1 and the paper's ablations).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Variant {
    /// Vectors from the temporal prior and the normalised depth: the paper's model.
    Full,
    /// RGB for the holes directly, from `f_n`, `f^w_n`, the normalised depth and `f^w_{n+1}`.
    Intensity,
    /// `Full` with zeros in place of the temporal prior.
    NoTemporalPrior,
    /// `Full` without the depth head: zeros in its channel (the U-Net keeps its shape).
    NoDepth,
}

impl Variant {
    pub const ALL: [Variant; 4] = [Variant::Full, Variant::Intensity, Variant::NoTemporalPrior, Variant::NoDepth];

    /// The name on the command line and in exported metadata.
    pub fn as_str(self) -> &'static str {
        match self {
            Variant::Full => "full",
            Variant::Intensity => "intensity",
            Variant::NoTemporalPrior => "no-tg",
            Variant::NoDepth => "no-depth",
        }
    }

    /// True for the variants whose output is infilling vectors.
    pub fn predicts_vectors(self) -> bool {
        self != Variant::Intensity
    }

    /// True for the variants whose input holds the temporal prior (`no-tg` and `intensity` never
    /// see it).
    pub fn reads_temporal_prior(self) -> bool {
        matches!(self, Variant::Full | Variant::NoDepth)
    }

    /// True for the variants whose input holds the normalised warped depth (all but `no-depth`).
    pub fn reads_depth(self) -> bool {
        self != Variant::NoDepth
    }

    fn input_channels(self) -> usize {
        if self == Variant::Intensity {
            10
        } else {
            3
        }
    }

    fn output_channels(self) -> usize {
        if self == Variant::Intensity {
            3
        } else {
            2
        }
    }
}

impl fmt::Display for Variant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Variant {
    type Err = String;

    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Variant::ALL.into_iter().find(|v| v.as_str() == s).ok_or_else(|| {
            let names: Vec<_> = Variant::ALL.iter().map(|v| v.as_str()).collect();
            format!("unknown model variant `{s}` (expected one of {})", names.join(", "))
        })
    }
}

/// A variant is written by its name (`full`, `no-tg`, ...), in configuration files too.
impl serde::Serialize for Variant {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

impl<'de> serde::Deserialize<'de> for Variant {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        name.parse().map_err(serde::de::Error::custom)
    }
}

/// The shape of a network: everything needed to rebuild it before loading weights.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ModelConfig {
    pub variant: Variant,
    /// Scales the encoder widths (64, 128, 256, 256, 256) and the decoder with them; 1 = the paper.
    pub width_mult: f64,
    /// Scales the depth head's widths (16, 32, 16); 1 = the paper, whatever `width_mult` is.
    pub depth_head_mult: f64,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self::new(Variant::Full, 1.0)
    }
}

impl ModelConfig {
    /// `variant` at width multiplier `width_mult`, with the paper's depth head.
    pub const fn new(variant: Variant, width_mult: f64) -> Self {
        Self { variant, width_mult, depth_head_mult: 1.0 }
    }

    /// The same network with the depth head's widths scaled by `m`.
    pub const fn with_depth_head_mult(self, m: f64) -> Self {
        Self { depth_head_mult: m, ..self }
    }

    /// The five encoder widths, as `torch_reference.py` computes them.
    pub fn encoder_widths(&self) -> [usize; 5] {
        ENCODER_WIDTHS.map(|c| scaled_width(c, self.width_mult))
    }

    /// The output widths of the depth head's `c1 .. c3`.
    pub fn depth_head_widths(&self) -> [usize; 3] {
        DEPTH_HEAD_WIDTHS.map(|c| scaled_width(c, self.depth_head_mult))
    }
}

/// `full (width 0.25)`, with `, depth head 0.5` when the head is not the paper's.
impl fmt::Display for ModelConfig {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} (width {}", self.variant, self.width_mult)?;
        if self.depth_head_mult != 1.0 {
            write!(f, ", depth head {}", self.depth_head_mult)?;
        }
        f.write_str(")")
    }
}

fn scaled_width(c: usize, m: f64) -> usize {
    ((c as f64 * m).round() as usize).max(1)
}

/// A 2-D convolution with bias and zero padding of `kernel / 2`, as `nn.Conv2d(.., padding=k//2)`.
#[derive(Clone, Debug)]
pub struct Conv {
    weight: Tensor,
    bias: Tensor,
    stride: usize,
}

impl Conv {
    pub fn new(vb: VarBuilder, inputs: usize, outputs: usize, kernel: usize, stride: usize) -> Result<Self> {
        // PyTorch's default initialisation; `seed_parameters` redraws it from a seed.
        let bound = 1.0 / ((inputs * kernel * kernel) as f64).sqrt();
        let init = Init::Uniform { lo: -bound, up: bound };
        let weight = vb.get_with_hints((outputs, inputs, kernel, kernel), "weight", init)?;
        let bias = vb.get_with_hints(outputs, "bias", init)?;
        Ok(Self { weight, bias, stride })
    }

    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        let kernel = self.weight.dim(3)?;
        conv2d(x, &self.weight, Some(&self.bias), self.stride, kernel / 2)
    }

    /// `relu(forward(x))`, fused into the convolution.
    pub fn forward_relu(&self, x: &Tensor) -> Result<Tensor> {
        let kernel = self.weight.dim(3)?;
        conv2d_relu(x, &self.weight, Some(&self.bias), self.stride, kernel / 2)
    }

    /// The weight (outputs, inputs, kernel, kernel).
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    pub fn bias(&self) -> &Tensor {
        &self.bias
    }

    pub fn stride(&self) -> usize {
        self.stride
    }

    /// The zero padding on every side: `kernel / 2`.
    pub fn padding(&self) -> usize {
        self.weight.dims()[3] / 2
    }
}

/// Normalises the warped depth (0 in holes, in scene units) to (0, 1).
#[derive(Clone, Debug)]
pub struct DepthHead {
    c1: Conv,
    c2: Conv,
    c3: Conv,
    c4: Conv,
}

impl DepthHead {
    /// A head whose `c1 .. c3` have the output widths `c`.
    pub fn new(vb: VarBuilder, c: [usize; 3]) -> Result<Self> {
        Ok(Self {
            c1: Conv::new(vb.pp("c1"), 1, c[0], 7, 2)?,
            c2: Conv::new(vb.pp("c2"), c[0], c[1], 7, 2)?,
            c3: Conv::new(vb.pp("c3"), c[1], c[2], 7, 1)?,
            c4: Conv::new(vb.pp("c4"), c[2], 1, 7, 1)?,
        })
    }

    /// `c1 .. c4`, in order.
    pub fn layers(&self) -> [&Conv; 4] {
        [&self.c1, &self.c2, &self.c3, &self.c4]
    }

    /// `depth` (B, 1, H, W) to (B, 1, H, W) in (0, 1).
    pub fn forward(&self, depth: &Tensor) -> Result<Tensor> {
        let (_, _, h, w) = depth.dims4()?;
        let x = self.c1.forward_relu(depth)?;
        let x = self.c2.forward_relu(&x)?;
        let (_, _, xh, xw) = x.dims4()?;
        let x = self.c3.forward_relu(&upsample_bilinear_to(&x, 2 * xh, 2 * xw)?)?;
        let x = self.c4.forward(&upsample_bilinear_to(&x, h, w)?)?;
        candle_nn::ops::sigmoid(&x)
    }
}

/// The inputs of one forward pass, all (B, C, H, W) f32 tensors of one size. The intensity variant
/// alone reads `last` and `last_warped`; the others may leave them `None`.
#[derive(Clone, Copy, Debug)]
pub struct NetInput<'a> {
    /// Temporal prior (B, 2, H, W), in pixels.
    pub prior: &'a Tensor,
    /// Warped depth `d^w_{n+1}` (B, 1, H, W), 0 in holes.
    pub warped_depth: &'a Tensor,
    /// Disocclusions (B, 1, H, W): 1 where the network must predict, else 0.
    pub mask: &'a Tensor,
    /// Warped frame `f^w_{n+1}` (B, 3, H, W) in [0, 1], 0 in holes.
    pub warped: &'a Tensor,
    /// Last rendered frame `f_n` (B, 3, H, W).
    pub last: Option<&'a Tensor>,
    /// `f^w_n`, frame `n - 2` warped to view `n` (B, 3, H, W).
    pub last_warped: Option<&'a Tensor>,
}

/// What a forward pass gives.
#[derive(Clone, Debug)]
pub struct NetOutput {
    /// The predicted frame: the warped frame, with the holes of `mask` infilled.
    pub frame: Tensor,
    /// The vectors (B, 2, H, W), zero outside the mask; `None` for the intensity variant.
    pub vectors: Option<Tensor>,
}

/// The whole network: depth head and U-Net.
#[derive(Clone, Debug)]
pub struct IvpNet {
    config: ModelConfig,
    depth: Option<DepthHead>,
    e1: Conv,
    e2: Conv,
    e3: Conv,
    e4: Conv,
    e5: Conv,
    d6: Conv,
    d7: Conv,
    d8: Conv,
    d9: Conv,
}

impl IvpNet {
    pub fn new(vb: VarBuilder, config: ModelConfig) -> Result<Self> {
        let variant = config.variant;
        let c = config.encoder_widths();
        Ok(Self {
            config,
            depth: variant
                .reads_depth()
                .then(|| DepthHead::new(vb.pp("depth"), config.depth_head_widths()))
                .transpose()?,
            e1: Conv::new(vb.pp("e1"), variant.input_channels(), c[0], 7, 1)?,
            e2: Conv::new(vb.pp("e2"), c[0], c[1], 5, 2)?,
            e3: Conv::new(vb.pp("e3"), c[1], c[2], 3, 2)?,
            e4: Conv::new(vb.pp("e4"), c[2], c[3], 3, 2)?,
            e5: Conv::new(vb.pp("e5"), c[3], c[4], 3, 2)?,
            d6: Conv::new(vb.pp("d6"), c[4] + c[3], c[3], 3, 1)?,
            d7: Conv::new(vb.pp("d7"), c[3] + c[2], c[1], 3, 1)?,
            d8: Conv::new(vb.pp("d8"), c[1] + c[1], c[0], 3, 1)?,
            d9: Conv::new(vb.pp("d9"), c[0] + c[0], variant.output_channels(), 3, 1)?,
        })
    }

    /// A new network whose parameters are drawn from `seed` (PyTorch's default distribution), in a
    /// fresh `VarMap` that holds them for training and saving.
    pub fn seeded(config: ModelConfig, seed: u64) -> Result<(Self, VarMap)> {
        let varmap = VarMap::new();
        let net = Self::new(VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu), config)?;
        seed_parameters(&varmap, seed)?;
        Ok((net, varmap))
    }

    pub fn config(&self) -> ModelConfig {
        self.config
    }

    /// The depth head; `None` for the `no-depth` variant.
    pub fn depth_head(&self) -> Option<&DepthHead> {
        self.depth.as_ref()
    }

    /// `e1 .. e5`, in order.
    pub fn encoder(&self) -> [&Conv; 5] {
        [&self.e1, &self.e2, &self.e3, &self.e4, &self.e5]
    }

    /// `d6 .. d9`, in order.
    pub fn decoder(&self) -> [&Conv; 4] {
        [&self.d6, &self.d7, &self.d8, &self.d9]
    }

    /// The same network on plain tensors instead of variables, for inference: its outputs do not
    /// record the graph that made them, so every intermediate map is freed as soon as it is used
    /// (with variables, a 1080p forward pass keeps them all alive, over 4 GB at width 1).
    pub fn detached(&self) -> Self {
        let conv = |c: &Conv| Conv { weight: c.weight.detach(), bias: c.bias.detach(), stride: c.stride };
        Self {
            config: self.config,
            depth: self.depth.as_ref().map(|d| DepthHead {
                c1: conv(&d.c1),
                c2: conv(&d.c2),
                c3: conv(&d.c3),
                c4: conv(&d.c4),
            }),
            e1: conv(&self.e1),
            e2: conv(&self.e2),
            e3: conv(&self.e3),
            e4: conv(&self.e4),
            e5: conv(&self.e5),
            d6: conv(&self.d6),
            d7: conv(&self.d7),
            d8: conv(&self.d8),
            d9: conv(&self.d9),
        }
    }

    /// The encoder's maps `e1` to `e5`, the depth head in its inference form if `inference`.
    fn encode(&self, input: &NetInput<'_>, inference: bool) -> Result<[Tensor; 5]> {
        let x = self.unet_input(input, inference)?;
        let x1 = self.e1.forward_relu(&x)?;
        let x2 = self.e2.forward_relu(&x1)?;
        let x3 = self.e3.forward_relu(&x2)?;
        let x4 = self.e4.forward_relu(&x3)?;
        let x5 = self.e5.forward_relu(&x4)?;
        Ok([x1, x2, x3, x4, x5])
    }

    /// The network's output before any compositing: vectors (B, 2, H, W) or RGB (B, 3, H, W),
    /// multiplied by the mask.
    pub fn masked_output(&self, input: &NetInput<'_>) -> Result<Tensor> {
        let [x1, x2, x3, x4, x5] = self.encode(input, false)?;
        // Each skip is dropped once used: at 1080p the last ones are the largest maps.
        let y = self.d6.forward_relu(&upsample_concat(&x5, &x4)?)?;
        drop((x5, x4));
        let y = self.d7.forward_relu(&upsample_concat(&y, &x3)?)?;
        drop(x3);
        let y = self.d8.forward_relu(&upsample_concat(&y, &x2)?)?;
        drop(x2);
        let y = self.d9.forward(&upsample_concat(&y, &x1)?)?;
        let y = if self.config.variant.predicts_vectors() { y } else { candle_nn::ops::sigmoid(&y)? };
        y.broadcast_mul(input.mask)
    }

    /// The predicted frame and vectors: the warped frame with its masked pixels replaced by the
    /// bilinear read at their vectors (ALGORITHMS.md §6.3, training form) or by the predicted RGB.
    pub fn forward(&self, input: &NetInput<'_>) -> Result<NetOutput> {
        let output = self.masked_output(input)?;
        let keep = input.mask.affine(-1.0, 1.0)?;
        let known = input.warped.broadcast_mul(&keep)?;
        if self.config.variant.predicts_vectors() {
            let read = sample_bilinear(input.warped, &output)?.broadcast_mul(input.mask)?;
            Ok(NetOutput { frame: (known + read)?, vectors: Some(output) })
        } else {
            Ok(NetOutput { frame: (known + output)?, vectors: None })
        }
    }

    /// The U-Net's input channels for this variant.
    fn unet_input(&self, input: &NetInput<'_>, inference: bool) -> Result<Tensor> {
        let depth = match &self.depth {
            Some(head) if inference => head.infer(input.warped_depth)?,
            Some(head) => head.forward(input.warped_depth)?,
            None => input.warped_depth.zeros_like()?,
        };
        match self.config.variant {
            Variant::Full => Tensor::cat(&[input.prior, &depth], 1),
            Variant::NoDepth => Tensor::cat(&[input.prior, &depth], 1),
            Variant::NoTemporalPrior => Tensor::cat(&[&input.prior.zeros_like()?, &depth], 1),
            Variant::Intensity => {
                let (Some(last), Some(last_warped)) = (input.last, input.last_warped) else {
                    candle_core::bail!("the intensity variant needs the last frame and its warp from frame n-2");
                };
                Tensor::cat(&[last, last_warped, &depth, input.warped], 1)
            }
        }
    }
}

/// Redraws every parameter of `varmap` uniformly in +-1/sqrt(fan_in) (PyTorch's default for
/// convolutions; a bias uses its weight's fan-in) from a generator seeded by `seed` and the
/// parameter's name, so that values do not depend on the order in which layers were built.
pub fn seed_parameters(varmap: &VarMap, seed: u64) -> Result<()> {
    let vars = varmap.data().lock().expect("a poisoned VarMap lock").clone();
    let fan_in = |name: &str| -> Result<usize> {
        let weight_name = format!("{}.weight", name.rsplit_once('.').map_or(name, |(layer, _)| layer));
        match vars.get(&weight_name) {
            Some(w) => Ok(w.dims()[1..].iter().product()),
            None => candle_core::bail!("parameter `{name}` has no weight `{weight_name}` to take its fan-in from"),
        }
    };
    let mut names: Vec<&String> = vars.keys().collect();
    names.sort();
    for name in names {
        let var = &vars[name];
        let bound = 1.0 / (fan_in(name)?.max(1) as f32).sqrt();
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ fnv1a(name.as_bytes()));
        let values: Vec<f32> = (0..var.elem_count()).map(|_| rng.random_range(-bound..bound)).collect();
        var.set(&Tensor::from_vec(values, var.shape(), &Device::Cpu)?)?;
    }
    Ok(())
}

/// The parameters of `varmap` by name, sorted: the order of every save and of the optimiser.
pub fn named_parameters(varmap: &VarMap) -> Vec<(String, Var)> {
    let vars: HashMap<String, Var> = varmap.data().lock().expect("a poisoned VarMap lock").clone();
    let mut named: Vec<(String, Var)> = vars.into_iter().collect();
    named.sort_by(|a, b| a.0.cmp(&b.0));
    named
}

/// FNV-1a: a hash that is the same on every platform and Rust version.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| (h ^ b as u64).wrapping_mul(0x0100_0000_01b3))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::ops::at_points::BatchPixel;

    fn inputs(b: usize, h: usize, w: usize, seed: u64) -> [Tensor; 6] {
        let r = |c: usize, s: u64| crate::nn::ops::test_util::random(&[b, c, h, w], seed * 10 + s);
        let mask = r(1, 1).ge(0.6f32).unwrap().to_dtype(DType::F32).unwrap();
        let depth = (r(1, 2).abs().unwrap() * 10.0).unwrap();
        let keep = mask.affine(-1.0, 1.0).unwrap();
        let warped = r(3, 3).abs().unwrap().broadcast_mul(&keep).unwrap();
        [(r(2, 4) * 3.0).unwrap(), depth, mask, warped, r(3, 5).abs().unwrap(), r(3, 6).abs().unwrap()]
    }

    fn net_input(t: &[Tensor; 6]) -> NetInput<'_> {
        NetInput {
            prior: &t[0],
            warped_depth: &t[1],
            mask: &t[2],
            warped: &t[3],
            last: Some(&t[4]),
            last_warped: Some(&t[5]),
        }
    }

    fn run(net: &IvpNet, t: &[Tensor; 6]) -> NetOutput {
        net.forward(&net_input(t)).unwrap()
    }

    #[test]
    fn the_depth_head_at_inference_equals_its_training_form() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 5).unwrap();
        let head = net.depth.as_ref().unwrap();
        // Even sides (every upsampling by 2), odd sides (the last one is not), tiny maps.
        for (h, w) in [(48, 64), (37, 29), (16, 16), (4, 4), (1, 3)] {
            let depth = inputs(2, h, w, 6)[1].clone();
            let want: Vec<f32> = head.forward(&depth).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            let got: Vec<f32> = head.infer(&depth).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            assert_eq!(got.len(), want.len());
            let worst = got.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
            assert!(worst < 1e-5, "{h}x{w}: largest difference {worst}");
        }
    }

    #[test]
    fn the_output_at_points_equals_the_whole_output_there() {
        for variant in Variant::ALL {
            let (net, _) = IvpNet::seeded(ModelConfig::new(variant, 0.125), 3).unwrap();
            // Odd sizes: the decoder crops its upsampled maps at every level.
            let (b, h, w) = (2, 37, 29);
            let t = inputs(b, h, w, 4);
            let input = net_input(&t);
            // masked_output multiplies by the mask and unmasked_output_at does not; the mask is read
            // nowhere else, so the whole output under a mask of ones is the unmasked output, and
            // points off the holes (the edges) compare real values, not zeros.
            let ones = t[2].ones_like().unwrap();
            let unmasked = NetInput { mask: &ones, ..net_input(&t) };
            let whole: Vec<f32> = net.masked_output(&unmasked).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            let mask: Vec<f32> = t[2].flatten_all().unwrap().to_vec1().unwrap();
            // The masked pixels, the corners and a row along the bottom edge.
            let points: Vec<BatchPixel> = (0..b)
                .flat_map(|image| (0..h).flat_map(move |y| (0..w).map(move |x| BatchPixel { image, y, x })))
                .filter(|p| mask[(p.image * h + p.y) * w + p.x] == 1.0 || p.y == h - 1 || p.x % (w - 1) == 0)
                .collect();
            let at: Vec<f32> =
                net.unmasked_output_at(&input, &points).unwrap().flatten_all().unwrap().to_vec1().unwrap();
            let c = at.len() / points.len();
            let (mut worst, mut largest) = (0f32, 0f32);
            for (p, values) in points.iter().zip(at.chunks_exact(c)) {
                for (ch, v) in values.iter().enumerate() {
                    let want = whole[((p.image * c + ch) * h + p.y) * w + p.x];
                    worst = worst.max((v - want).abs());
                    largest = largest.max(want.abs());
                }
            }
            assert!(worst < 1e-4 && largest > 1e-3, "{variant}: largest difference {worst} (largest value {largest})");
            let off_holes = points.iter().filter(|p| mask[(p.image * h + p.y) * w + p.x] == 0.0).count();
            assert!(off_holes > 0, "the edge points off the holes are compared too");
            assert!(net.unmasked_output_at(&input, &[]).unwrap().dims()[0] == 0);
        }
    }

    #[test]
    fn parameter_names_and_shapes_match_the_torch_reference() {
        let (_, varmap) = IvpNet::seeded(ModelConfig::default(), 0).unwrap();
        let shapes: Vec<(String, Vec<usize>)> =
            named_parameters(&varmap).into_iter().map(|(n, v)| (n, v.dims().to_vec())).collect();
        let expect = |n: &str| shapes.iter().find(|(m, _)| m == n).unwrap_or_else(|| panic!("no {n}")).1.clone();
        assert_eq!(shapes.len(), 2 * 13);
        assert_eq!(expect("depth.c1.weight"), [16, 1, 7, 7]);
        assert_eq!(expect("depth.c4.bias"), [1]);
        assert_eq!(expect("e1.weight"), [64, 3, 7, 7]);
        assert_eq!(expect("e2.weight"), [128, 64, 5, 5]);
        assert_eq!(expect("d6.weight"), [256, 512, 3, 3]);
        assert_eq!(expect("d7.weight"), [128, 512, 3, 3]);
        assert_eq!(expect("d8.weight"), [64, 256, 3, 3]);
        assert_eq!(expect("d9.weight"), [2, 128, 3, 3]);
        let count: usize = shapes.iter().map(|(_, s)| s.iter().product::<usize>()).sum();
        // The torch reference's IvpUNet(1.0) has this many parameters.
        assert_eq!(count, 3_661_219);
    }

    #[test]
    fn initialisation_is_seeded_and_within_pytorch_bounds() {
        let cfg = ModelConfig::new(Variant::Full, 0.25);
        let flat = |vm: &VarMap| -> Vec<Vec<f32>> {
            named_parameters(vm).iter().map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
        };
        let (_, a) = IvpNet::seeded(cfg, 7).unwrap();
        let (_, b) = IvpNet::seeded(cfg, 7).unwrap();
        let (_, c) = IvpNet::seeded(cfg, 8).unwrap();
        assert_eq!(flat(&a), flat(&b));
        assert_ne!(flat(&a), flat(&c));
        for (name, var) in named_parameters(&a) {
            let fan_in: usize = a.data().lock().unwrap()[&format!("{}.weight", name.rsplit_once('.').unwrap().0)]
                .dims()[1..]
                .iter()
                .product();
            let bound = 1.0 / (fan_in as f32).sqrt();
            let v: Vec<f32> = var.flatten_all().unwrap().to_vec1().unwrap();
            assert!(v.iter().all(|x| x.abs() <= bound), "{name} outside +-{bound}");
            if v.len() > 100 {
                let mean_sq = v.iter().map(|x| x * x).sum::<f32>() / v.len() as f32;
                // Uniform in +-b has variance b^2 / 3.
                assert!((mean_sq / (bound * bound / 3.0) - 1.0).abs() < 0.2, "{name}: {mean_sq}");
            }
        }
    }

    #[test]
    fn widths_follow_the_multiplier() {
        let cfg = |m| ModelConfig::new(Variant::Full, m);
        assert_eq!(cfg(1.0).encoder_widths(), [64, 128, 256, 256, 256]);
        assert_eq!(cfg(0.25).encoder_widths(), [16, 32, 64, 64, 64]);
        assert_eq!(cfg(0.125).encoder_widths(), [8, 16, 32, 32, 32]);
    }

    #[test]
    fn the_depth_head_scales_with_its_own_multiplier() {
        let paper = ModelConfig::new(Variant::Full, 0.125);
        assert_eq!(paper.depth_head_widths(), [16, 32, 16]);
        let half = paper.with_depth_head_mult(0.5);
        assert_eq!(half.depth_head_widths(), [8, 16, 8]);
        assert_eq!(half.encoder_widths(), paper.encoder_widths());
        assert_eq!(
            (paper.to_string(), half.to_string()),
            ("full (width 0.125)".into(), "full (width 0.125, depth head 0.5)".into())
        );
        let (net, varmap) = IvpNet::seeded(half, 2).unwrap();
        let shape = |name: &str| {
            named_parameters(&varmap).into_iter().find(|(n, _)| n == name).map(|(_, v)| v.dims().to_vec()).unwrap()
        };
        assert_eq!(shape("depth.c1.weight"), [8, 1, 7, 7]);
        assert_eq!(shape("depth.c3.weight"), [8, 16, 7, 7]);
        assert_eq!(shape("depth.c4.weight"), [1, 8, 7, 7]);
        let out = run(&net, &inputs(1, 19, 23, 6));
        assert_eq!(out.vectors.unwrap().dims(), [1, 2, 19, 23]);
    }

    #[test]
    fn every_variant_runs_on_odd_sizes_and_masks_its_output() {
        for variant in Variant::ALL {
            let (net, varmap) = IvpNet::seeded(ModelConfig::new(variant, 0.125), 3).unwrap();
            if variant == Variant::NoDepth {
                assert!(named_parameters(&varmap).iter().all(|(n, _)| !n.starts_with("depth.")));
            }
            let t = inputs(2, 37, 21, 1);
            let out = run(&net, &t);
            assert_eq!(out.frame.dims(), [2, 3, 37, 21]);
            let keep = t[2].affine(-1.0, 1.0).unwrap();
            // Known pixels keep the warped frame.
            let diff = ((&out.frame - &t[3]).unwrap().broadcast_mul(&keep).unwrap()).abs().unwrap();
            assert_eq!(diff.max_all().unwrap().to_scalar::<f32>().unwrap(), 0.0, "{variant}");
            match out.vectors {
                Some(v) => {
                    assert_eq!(v.dims(), [2, 2, 37, 21]);
                    let outside = v.broadcast_mul(&keep).unwrap().abs().unwrap().max_all().unwrap();
                    assert_eq!(outside.to_scalar::<f32>().unwrap(), 0.0);
                    let inside = v.abs().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap();
                    assert!(inside > 0.0 && inside.is_finite());
                }
                None => assert_eq!(variant, Variant::Intensity),
            }
        }
    }

    #[test]
    fn no_tg_ignores_the_prior_and_full_does_not() {
        let run_with_prior = |variant, prior_scale: f64| {
            let (net, _) = IvpNet::seeded(ModelConfig::new(variant, 0.125), 5).unwrap();
            let mut t = inputs(1, 16, 16, 2);
            t[0] = (&t[0] * prior_scale).unwrap();
            crate::nn::ops::test_util::flat(&run(&net, &t).vectors.unwrap())
        };
        assert_eq!(run_with_prior(Variant::NoTemporalPrior, 1.0), run_with_prior(Variant::NoTemporalPrior, 5.0));
        assert_ne!(run_with_prior(Variant::Full, 1.0), run_with_prior(Variant::Full, 5.0));
    }

    #[test]
    fn a_detached_network_computes_the_same_without_recording_a_graph() {
        let (net, _) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 4).unwrap();
        let t = inputs(1, 21, 18, 3);
        let (a, b) = (run(&net, &t), run(&net.detached(), &t));
        assert!(a.frame.track_op() && !b.frame.track_op());
        assert_eq!(crate::nn::ops::test_util::flat(&a.frame), crate::nn::ops::test_util::flat(&b.frame));
    }

    #[test]
    fn gradients_reach_every_parameter() {
        let (net, varmap) = IvpNet::seeded(ModelConfig::new(Variant::Full, 0.125), 9).unwrap();
        let t = inputs(2, 24, 19, 4);
        let out = run(&net, &t);
        let loss = out.frame.sqr().unwrap().sum_all().unwrap();
        let grads = loss.backward().unwrap();
        for (name, var) in named_parameters(&varmap) {
            let g = grads.get(&var).unwrap_or_else(|| panic!("no gradient for {name}"));
            let norm = g.sqr().unwrap().sum_all().unwrap().to_scalar::<f32>().unwrap();
            assert!(norm.is_finite() && norm > 0.0, "{name}: gradient norm {norm}");
        }
    }
}
