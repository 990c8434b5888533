//! Binary-mask helpers shared by the stages: distance fields, dilation, erosion, softening.
//!
//! Masks are `&[bool]` of `width * height`, row-major, `true` = inside.

use crate::image::Image;
use image::{ImageBuffer, Luma};

/// Euclidean distance (pixels) from every pixel to the nearest `true` pixel of `mask`;
/// `f32::INFINITY` everywhere when the mask is empty. Linear time (Felzenszwalb–Huttenlocher,
/// via imageproc). Allocates one f64 plane.
pub fn distance_to(mask: &[bool], width: usize, height: usize) -> Vec<f32> {
    if !mask.iter().any(|&m| m) {
        return vec![f32::INFINITY; mask.len()];
    }
    let buf = ImageBuffer::<Luma<u8>, Vec<u8>>::from_raw(width as u32, height as u32, mask.iter().map(|&m| m as u8).collect())
        .expect("mask size");
    imageproc::distance_transform::euclidean_squared_distance_transform(&buf)
        .into_raw()
        .into_iter()
        .map(|d2| d2.sqrt() as f32)
        .collect()
}

/// Pixels within `radius` of the mask (disk structuring element).
pub fn dilate(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    distance_to(mask, width, height).into_iter().map(|d| d <= radius).collect()
}

/// Pixels farther than `radius` from the mask's complement (disk structuring element).
/// Pixels on the image border are not eroded by the outside: the mask may run off-frame.
pub fn erode(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
    distance_to(&outside, width, height).into_iter().map(|d| d > radius).collect()
}

/// Gaussian blur of a one-channel image (`sigma` in pixels; ≤ 0 returns a copy).
pub fn gaussian_blur(plane: &Image, sigma: f32) -> Image {
    debug_assert_eq!(plane.channels, 1);
    if sigma <= 0.0 || plane.is_empty() {
        return plane.clone();
    }
    let buf = ImageBuffer::<Luma<f32>, Vec<f32>>::from_raw(plane.width as u32, plane.height as u32, plane.data.clone())
        .expect("plane size");
    let out = imageproc::filter::gaussian_blur_f32(&buf, sigma);
    Image::from_vec(plane.width, plane.height, 1, out.into_raw()).expect("plane size")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morphology() {
        let (w, h) = (9, 9);
        let mut m = vec![false; w * h];
        m[4 * w + 4] = true;
        let d = dilate(&m, w, h, 2.0);
        assert_eq!(d.iter().filter(|&&v| v).count(), 13);
        assert_eq!(erode(&d, w, h, 1.0).iter().filter(|&&v| v).count(), 5);
        assert!(distance_to(&vec![false; 4], 2, 2).iter().all(|d| d.is_infinite()));
    }
}
