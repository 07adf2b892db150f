//! Images and candle tensors: interleaved pixels (`Image<C>`) to planar NCHW and back. The one
//! conversion of the workspace, used by training batches and by inference alike.

use candle_core::{bail, Device, Result, Tensor};

use crate::geometry::Image;

/// Images of one size as a `(B, C, H, W)` tensor on the CPU: interleaved pixels become planes.
pub fn to_batch_tensor<const C: usize>(images: &[&Image<C>]) -> Result<Tensor> {
    let Some(first) = images.first() else { bail!("no image to convert to a tensor") };
    let (width, height) = (first.width(), first.height());
    if let Some(other) = images.iter().find(|image| !image.same_size(first)) {
        bail!("images of different sizes in one batch: {width}x{height} and {}x{}", other.width(), other.height());
    }
    let plane = width * height;
    let mut data = vec![0f32; images.len() * C * plane];
    for (image, planes) in images.iter().zip(data.chunks_exact_mut((C * plane).max(1))) {
        // One plane at a time: sequential writes, which vectorise (interleaved ones did not).
        for (c, out) in planes.chunks_exact_mut(plane.max(1)).enumerate() {
            for (value, pixel) in out.iter_mut().zip(image.pixels()) {
                *value = pixel[c];
            }
        }
    }
    Tensor::from_vec(data, (images.len(), C, height, width), &Device::Cpu)
}

/// An image as a `(1, C, H, W)` tensor.
pub fn to_tensor<const C: usize>(image: &Image<C>) -> Result<Tensor> {
    to_batch_tensor(&[image])
}

/// The first image of a `(B, C, H, W)` tensor.
pub fn from_tensor<const C: usize>(t: &Tensor) -> Result<Image<C>> {
    let (_, c, h, w) = t.dims4()?;
    if c != C {
        bail!("expected {C} channels, got {c}");
    }
    let data: Vec<f32> = t.get(0)?.flatten_all()?.to_vec1()?;
    let plane = h * w;
    let pixels = (0..plane).map(|i| std::array::from_fn(|ch| data[ch * plane + i])).collect();
    Ok(Image::from_pixels(w, h, pixels))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::RgbImage;

    #[test]
    fn tensors_and_images_convert_both_ways() {
        let image = RgbImage::from_pixels(3, 2, (0..6).map(|i| [i as f32, 10.0 + i as f32, 20.0 + i as f32]).collect());
        let t = to_tensor(&image).unwrap();
        assert_eq!(t.dims(), [1, 3, 2, 3]);
        assert_eq!(t.get(0).unwrap().get(1).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()[4], 14.0);
        assert_eq!(from_tensor::<3>(&t).unwrap(), image);
    }

    #[test]
    fn batches_stack_images_in_order_and_refuse_mixed_sizes() {
        let a = RgbImage::filled(4, 3, [0.1, 0.2, 0.3]);
        let b = RgbImage::filled(4, 3, [0.4, 0.5, 0.6]);
        let t = to_batch_tensor(&[&a, &b]).unwrap();
        assert_eq!(t.dims(), [2, 3, 3, 4]);
        assert_eq!(from_tensor::<3>(&t.narrow(0, 1, 1).unwrap()).unwrap(), b);
        assert!(to_batch_tensor(&[&a, &RgbImage::zeros(3, 4)]).is_err());
        assert!(to_batch_tensor::<3>(&[]).is_err());
    }
}
