//! Binary-mask helpers shared by the stages: distance fields, dilation, erosion, softening.
//!
//! Masks are `&[bool]` of `width * height`, row-major, `true` = inside.

use crate::image::Image;
use image::{ImageBuffer, Luma};

/// Euclidean distance (pixels) from every pixel to the nearest `true` pixel of `mask`;
/// `f32::INFINITY` everywhere when the mask is empty. Linear time (Felzenszwalb–Huttenlocher,
/// via imageproc). Allocates one f64 plane.
pub fn distance_to(mask: &[bool], width: usize, height: usize) -> Vec<f32> {
    distance_in(mask, width, height, (0, 0, width, height))
}

/// [`distance_to`], exact wherever the distance is at most `limit` and `INFINITY` or a value
/// above `limit` elsewhere. Works on the mask's bounding box grown by `limit` only (every
/// pixel that close to the mask is inside it, and so is every mask pixel): a subject that
/// covers a small part of a 12 MP frame costs a fraction of the whole transform.
pub fn distance_within(mask: &[bool], width: usize, height: usize, limit: f32) -> Vec<f32> {
    match grown_bbox(mask, width, height, limit) {
        Some(bb) => distance_in(mask, width, height, bb),
        None => vec![f32::INFINITY; mask.len()],
    }
}

/// Bounding box `(x0, y0, x1, y1)` (exclusive ends) of the `true` pixels grown by `margin`
/// and clipped to the image; None for an empty mask.
pub fn grown_bbox(mask: &[bool], width: usize, height: usize, margin: f32) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (y, row) in mask.chunks_exact(width).enumerate() {
        if let (Some(a), Some(b)) = (row.iter().position(|&m| m), row.iter().rposition(|&m| m)) {
            (x0, x1, y0, y1) = (x0.min(a), x1.max(b + 1), y0.min(y), y + 1);
        }
    }
    if x0 == usize::MAX {
        return None;
    }
    let m = if margin.is_finite() { margin.max(0.0).ceil() as usize + 1 } else { width.max(height) };
    Some((x0.saturating_sub(m), y0.saturating_sub(m), (x1 + m).min(width), (y1 + m).min(height)))
}

/// Distance to the mask's pixels inside the window `(x0, y0, x1, y1)`, computed on that window
/// only; `INFINITY` outside it.
pub fn distance_in(mask: &[bool], width: usize, height: usize, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> Vec<f32> {
    let mut out = vec![f32::INFINITY; width * height];
    let (cw, ch) = (x1 - x0, y1 - y0);
    if cw == 0 || ch == 0 || !(y0..y1).any(|y| mask[y * width + x0..y * width + x1].iter().any(|&m| m)) {
        return out;
    }
    let crop: Vec<u8> = (y0..y1).flat_map(|y| mask[y * width + x0..y * width + x1].iter().map(|&m| m as u8)).collect();
    let buf = ImageBuffer::<Luma<u8>, Vec<u8>>::from_raw(cw as u32, ch as u32, crop).expect("mask size");
    let d2 = imageproc::distance_transform::euclidean_squared_distance_transform(&buf).into_raw();
    for (row, src) in out[y0 * width..y1 * width].chunks_exact_mut(width).zip(d2.chunks_exact(cw)) {
        for (o, &d) in row[x0..x1].iter_mut().zip(src) {
            *o = d.sqrt() as f32;
        }
    }
    out
}

/// A fast-marching `max_distance` (Telea) that surely covers every pixel within Euclidean
/// distance `d`: fast marching overestimates distance by a few percent on diagonals.
pub fn marching_reach(d: f32) -> f32 {
    d * 1.1 + 2.0
}

/// Pixels within `radius` of the mask (disk structuring element).
pub fn dilate(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    distance_within(mask, width, height, radius).into_iter().map(|d| d <= radius).collect()
}

/// Pixels farther than `radius` from the mask's complement (disk structuring element).
/// Pixels on the image border are not eroded by the outside: the mask may run off-frame.
pub fn erode(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    // Only mask pixels can stay; the complement pixels that decide them are within `radius`.
    let Some(bb) = grown_bbox(mask, width, height, radius) else { return mask.to_vec() };
    let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
    distance_in(&outside, width, height, bb).into_iter().zip(mask).map(|(d, &m)| m && d > radius).collect()
}

/// The median of `v` (the upper one for an even count), reordering `v`; None when empty.
/// O(n) (selection, not a sort).
pub fn median(v: &mut [f32]) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let k = v.len() / 2;
    Some(*v.select_nth_unstable_by(k, f32::total_cmp).1)
}

/// Gaussian blur of a one-channel image (`sigma` in pixels; ≤ 0 returns a copy).
pub fn gaussian_blur(plane: &Image, sigma: f32) -> Image {
    debug_assert_eq!(plane.channels, 1);
    if sigma <= 0.0 || plane.is_empty() {
        return plane.clone();
    }
    let buf =
        ImageBuffer::<Luma<f32>, Vec<f32>>::from_raw(plane.width as u32, plane.height as u32, plane.data.clone()).expect("plane size");
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
        assert!(distance_to(&[false; 4], 2, 2).iter().all(|d| d.is_infinite()));
    }
}
