//! The network's inference-only forms, without gradients: a convolution of a map upsampled by 2
//! in phases, a decoder step at chosen pixels, the depth head with its upsampling folded into its
//! convolutions, and the network's output at chosen pixels only (`IvpNet::unmasked_output_at`).
//! `the_output_at_points_equals_the_whole_output_there` and
//! `the_depth_head_at_inference_equals_its_training_form` hold them equal to the training forms.

use candle_core::{Result, Tensor};

use super::{Conv, DepthHead, IvpNet, NetInput};
use crate::nn::ops::at_points::{decoder_step_at, pixels_read, scatter, BatchPixel};
use crate::nn::ops::upsample_bilinear_to;
use crate::nn::ops::upsampled_conv::conv2d_of_upsampled;

impl Conv {
    /// This convolution (stride 1) of `x` upsampled bilinearly by 2 ([`conv2d_of_upsampled`]).
    pub(super) fn of_upsampled(&self, x: &Tensor, relu: bool) -> Result<Tensor> {
        conv2d_of_upsampled(x, &self.weight, &self.bias, relu)
    }

    /// A decoder step at `points` of the skip's size only: (N, Cout) ([`decoder_step_at`]).
    pub(super) fn values_at(
        &self,
        coarse: &Tensor,
        skip: &Tensor,
        points: &[BatchPixel],
        relu: bool,
    ) -> Result<Tensor> {
        decoder_step_at(coarse, skip, &self.weight, &self.bias, relu, points)
    }

    /// [`Conv::values_at`] as a map of the skip's size, zero away from `points`.
    pub(super) fn forward_at(
        &self,
        coarse: &Tensor,
        skip: &Tensor,
        points: &[BatchPixel],
        relu: bool,
    ) -> Result<Tensor> {
        let values = self.values_at(coarse, skip, points, relu)?;
        let (b, _, h, w) = skip.dims4()?;
        scatter(&values, points, (b, self.weight.dim(0)?, h, w))
    }
}

impl DepthHead {
    /// [`DepthHead::forward`] for inference, equal up to rounding: `c3` and the upsampling before
    /// it in one step ([`conv2d_of_upsampled`]: half the multiply-adds, and no upsampled map of 32
    /// channels), and `c4` too where its upsampling is by exactly 2 (maps of even sides, as tiles
    /// are): c4 and its upsampling took 13.9 ms of a 1080p frame on one thread, now 6. No gradient.
    pub fn infer(&self, depth: &Tensor) -> Result<Tensor> {
        let (_, _, h, w) = depth.dims4()?;
        let x = self.c1.forward_relu(depth)?;
        let x = self.c2.forward_relu(&x)?;
        let x = self.c3.of_upsampled(&x, true)?;
        let (_, _, xh, xw) = x.dims4()?;
        let x = if (2 * xh, 2 * xw) == (h, w) {
            self.c4.of_upsampled(&x, false)?
        } else {
            self.c4.forward(&upsample_bilinear_to(&x, h, w)?)?
        };
        candle_nn::ops::sigmoid(&x)
    }
}

impl IvpNet {
    /// [`IvpNet::masked_output`] at `points` only, before the mask: one row of output channels per
    /// point, (N, C). For inference, where vectors are read at the pixels to predict only. The
    /// encoder runs over the whole input; each decoder level only at the pixels that the points
    /// read through the levels above it ([`pixels_read`]).
    pub fn unmasked_output_at(&self, input: &NetInput<'_>, points: &[BatchPixel]) -> Result<Tensor> {
        let [x1, x2, x3, x4, x5] = self.encode(input, true)?;
        // The pixels of each decoder level that the points need, from the top level down.
        let (b, _, h, w) = x1.dims4()?;
        let hw = |t: &Tensor| -> Result<(usize, usize)> { Ok((t.dim(2)?, t.dim(3)?)) };
        let (s2, s3, s4) = (hw(&x2)?, hw(&x3)?, hw(&x4)?);
        let p8 = pixels_read(points, (h, w), (b, s2.0, s2.1));
        let p7 = pixels_read(&p8, s2, (b, s3.0, s3.1));
        let p6 = pixels_read(&p7, s3, (b, s4.0, s4.1));
        let y = self.d6.forward_at(&x5, &x4, &p6, true)?;
        let y = self.d7.forward_at(&y, &x3, &p7, true)?;
        let y = self.d8.forward_at(&y, &x2, &p8, true)?;
        let y = self.d9.values_at(&y, &x1, points, false)?;
        if self.config.variant.predicts_vectors() {
            Ok(y)
        } else {
            candle_nn::ops::sigmoid(&y)
        }
    }
}
