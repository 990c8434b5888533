//! Where a depth-from-defocus map can be trusted (`drbokeh dfd --confidence OUT`).
//!
//! Defocus tells depth only where two things hold, and the map is a guess elsewhere:
//! - the all-in-focus photo has texture at the blur's scale (a flat wall looks the same at any
//!   blur): `texture = 1 − exp(−(s / S)²)`, `s` the standard deviation of the photo's
//!   sRGB-encoded luminance over a box of radius `r = clamp(round(K / 4), 2, 16)` px around the
//!   pixel, `S` = [`TEXTURE_SCALE`];
//! - the estimated pixel is blurred visibly: within half a pixel of circle of confusion of the
//!   focal plane the photo is the same whatever the depth (the dead band): `visible` rises as
//!   a smoothstep from CoC radius [`DEAD_BAND_PX`] to 1 px.
//!
//! `confidence = texture × visible`, in [0, 1], one channel, the photo's size. It flags
//! textureless and in-focus regions; it does not measure occlusion. Allocates two f64
//! summed-area tables of the photo's size.

use crate::color::linear_to_srgb;
use crate::image::Image;
use crate::render::RenderSettings;
use crate::render::lens::coc_radius;
use rayon::prelude::*;

/// Luminance standard deviation (sRGB-encoded, 0..1) at which texture counts for 63%.
pub const TEXTURE_SCALE: f64 = 0.02;
/// CoC radius (px) below which a depth cannot be told from the focal plane's.
pub const DEAD_BAND_PX: f32 = 0.25;

/// The confidence map of `disparity` estimated from `aif` (linear RGB) for the render `s`
/// (see the module doc).
pub fn confidence(aif: &Image, disparity: &Image, s: &RenderSettings) -> Image {
    confidence_of_stack(aif, disparity, s.blur, &[s.focus])
}

/// [`confidence`] for a focal stack of photos focused at `foci` with blur `blur`: a pixel is
/// as visibly blurred as its best-placed photo shows it (the largest `visible` of the foci);
/// the texture term is computed once.
pub fn confidence_of_stack(aif: &Image, disparity: &Image, blur: f32, foci: &[f32]) -> Image {
    let (w, h) = (aif.width, aif.height);
    let y: Vec<f64> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let p = aif.pixel(i % w, i / w);
            linear_to_srgb((0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]).max(0.0)) as f64
        })
        .collect();
    // Summed-area tables of y and y², (w + 1) x (h + 1).
    let (sw, sh) = (w + 1, h + 1);
    let mut s1 = vec![0f64; sw * sh];
    let mut s2 = vec![0f64; sw * sh];
    for yy in 0..h {
        let (mut row1, mut row2) = (0f64, 0f64);
        for xx in 0..w {
            let v = y[yy * w + xx];
            row1 += v;
            row2 += v * v;
            s1[(yy + 1) * sw + xx + 1] = s1[yy * sw + xx + 1] + row1;
            s2[(yy + 1) * sw + xx + 1] = s2[yy * sw + xx + 1] + row2;
        }
    }
    let r = ((blur / 4.0).round() as usize).clamp(2, 16);
    let data: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (px, py) = (i % w, i / w);
            let (x0, x1, y0, y1) = (px.saturating_sub(r), (px + r + 1).min(w), py.saturating_sub(r), (py + r + 1).min(h));
            let n = ((x1 - x0) * (y1 - y0)) as f64;
            let sum = |t: &[f64]| t[y1 * sw + x1] - t[y0 * sw + x1] - t[y1 * sw + x0] + t[y0 * sw + x0];
            let mean = sum(&s1) / n;
            let var = (sum(&s2) / n - mean * mean).max(0.0);
            let texture = 1.0 - (-var / (TEXTURE_SCALE * TEXTURE_SCALE)).exp();
            let visible = foci
                .iter()
                .map(|&f| {
                    let t = ((coc_radius(disparity.data[i] - f, blur) - DEAD_BAND_PX) / (1.0 - DEAD_BAND_PX)).clamp(0.0, 1.0);
                    t * t * (3.0 - 2.0 * t)
                })
                .fold(0.0f32, f32::max);
            (texture as f32 * visible).clamp(0.0, 1.0)
        })
        .collect();
    Image::from_vec(w, h, 1, data).expect("the photo's size")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn settings(focus: f32, blur: f32) -> RenderSettings {
        RenderSettings {
            blur,
            focus,
            lens: 1,
            occlusion: true,
            profile: crate::render::Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        }
    }

    #[test]
    fn texture_and_visible_blur_both_count() {
        let (w, h) = (40usize, 20usize);
        // Left half a checkerboard, right half flat grey.
        let aif = Image::from_vec(
            w,
            h,
            3,
            (0..w * h)
                .flat_map(|i| {
                    let (x, y) = (i % w, i / w);
                    let v = if x < w / 2 { if (x + y) % 2 == 0 { 0.8 } else { 0.1 } } else { 0.3 };
                    [v, v, v]
                })
                .collect(),
        )
        .unwrap();
        let far = Image::filled(w, h, 1, 0.9);
        let c = confidence(&aif, &far, &settings(0.1, 8.0));
        assert!(c.data.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)));
        let at = |x: usize, y: usize| c.data[y * w + x];
        assert!(at(5, 10) > 0.99, "textured and blurred: {}", at(5, 10));
        assert!(at(35, 10) < 1e-6, "flat: {}", at(35, 10));
        // In the dead band (the map at the focal plane), nothing is trusted.
        let focused = Image::filled(w, h, 1, 0.1);
        let c = confidence(&aif, &focused, &settings(0.1, 8.0));
        assert!(c.data.iter().all(|&v| v == 0.0));
        // Half a pixel of CoC is half way up the smoothstep's range.
        let half = Image::filled(w, h, 1, 0.1 + 0.625 / 8.0);
        let c = confidence(&aif, &half, &settings(0.1, 8.0));
        assert!((c.data[10 * w + 5] - 0.5).abs() < 0.01, "{}", c.data[10 * w + 5]);
    }
}
