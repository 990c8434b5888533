//! The camera's PSF, read from the sharpest edges of the photo: what the highlights stage
//! ([`super::light_recovery`]) needs to tell a bright narrow light from a faint wide one.
//!
//! A light far above white shows only its clipped core and a one-pixel transition to the
//! background; a wide faint disc with a sharp edge and a narrow bright disc behind a soft PSF
//! draw the same transition, so the lights alone cannot say how bright they are (measured on the
//! bench's `srgb8-psf` scenes: fitted per light, the PSF came out at 0–0.4 px for a true 0.7,
//! and 17% of the missing light came back; at the true PSF, 41%). Ordinary edges can: an edge
//! between two flat areas, blurred by the lens and integrated by the pixel, has the profile
//! `a + b·Φ(s / w)` across it, with `w² = σ² + 1/12` (the pixel's box, any direction). Edges in
//! the scene are never sharper than the camera makes them, so the sharpest well-fitted edges
//! give σ.
//!
//! Units: pixels; the photo is linear RGB.

use crate::image::Image;
use rayon::prelude::*;

/// Half-size of the square window an edge is fitted in (a 7x7 window).
const HALF: usize = 3;
/// Edge widths w (pixels) tried: from a perfectly sharp edge (√(1/12) ≈ 0.29) to σ = 3.
const W_MIN: f32 = 0.2;
const W_MAX: f32 = 3.0;
const W_STEP: f32 = 0.05;
/// Offsets of the edge from the window's centre pixel along its normal, pixels.
const S_MAX: f32 = 1.0;
const S_STEP: f32 = 0.1;
/// Least luminance step (linear) across an edge for it to count: below it 8-bit quantization
/// and texture noise dominate the profile.
const MIN_STEP: f32 = 0.08;
/// Least share of the window's variance the step model must explain (a straight edge between
/// two flat areas, not a texture, a corner or a line). 0.93: on the bench's 128 px scenes
/// (seed 3) 0.97 left 8 of 15 photos with too few edges, 0.93 two.
const MIN_EXPLAINED: f32 = 0.93;
/// Edges fitted at most: enough for a stable percentile, few enough to cost tens of ms.
const MAX_EDGES: usize = 800;
/// Well-fitted edges needed for an estimate. Few: the fallback, the lights' own fits, is worse
/// than a handful of edges (on the bench's `srgb8-psf` seed 3 it read 0.15–0.40 px for a true
/// 0.7 where 5–6 edges said 0.53–0.58). 3 instead of 12: seed 3 +0.05 / +0.21 dB (sRGB /
/// linear, pipeline `auto` − `off`), held out seed 4 +0.00 / +0.11, seed 5 and the Mitsuba
/// scenes unchanged; the median of fewer than 12 instead of the percentile gained more on seed
/// 3 (+0.38 linear) but lost 0.12 on seed 4's `srgb8`.
const MIN_EDGES: usize = 3;
/// The percentile of the fitted widths taken as the camera's: the sharpest edges, less a few
/// that noise made sharper than the PSF.
const PERCENTILE: f32 = 0.15;
/// The pixel's box filter's variance along any direction, px².
const PIXEL_VARIANCE: f32 = 1.0 / 12.0;

/// The PSF σ (pixels) of `rgb` (linear RGB) from its sharpest edges, leaving out edges whose
/// window lies within `margin` pixels of a sample with `clipped` set (non-zero: their
/// profile is cut off), or `None` when the photo has too few clean edges. Cost: one gradient pass over the frame (parallel by
/// bands of rows, each with its own few rows of luminance: a frame-sized luminance plane was
/// a 49 MB allocation whose first touch, at 12 MP, cost as much as the pass), then at most
/// [`MAX_EDGES`] small fits.
pub fn estimate(rgb: &Image, clipped: &[u8], margin: f32) -> Option<f32> {
    let (w, h) = (rgb.width, rgb.height);
    if w < 2 * HALF + 3 || h < 2 * HALF + 3 {
        return None;
    }
    // Candidates: local maxima of the gradient along its direction, strong enough. Magnitudes
    // are compared squared (libm's careful hypot was most of this frame-wide pass).
    let norm2 = |(gx, gy): (f32, f32)| gx * gx + gy * gy;
    let least = (MIN_STEP / 4.0) * (MIN_STEP / 4.0);
    let (top, bottom) = (HALF + 1, h - HALF - 1);
    let mut cands: Vec<(usize, usize, f32)> = (top..bottom)
        .into_par_iter()
        .step_by(BAND_ROWS)
        .flat_map_iter(|y0| {
            let y1 = (y0 + BAND_ROWS).min(bottom);
            // The band's rows and the two above and below that its gradients read.
            let lum = luminance_rows(rgb, y0 - 2..y1 + 2);
            let at = |x: usize, y: usize| lum[(y + 2 - y0) * w + x];
            let grad = |x: usize, y: usize| -> (f32, f32) { (0.5 * (at(x + 1, y) - at(x - 1, y)), 0.5 * (at(x, y + 1) - at(x, y - 1))) };
            (y0..y1)
                .flat_map(|y| {
                    (HALF + 1..w - HALF - 1).filter_map(move |x| {
                        let (gx, gy) = grad(x, y);
                        let g2 = norm2((gx, gy));
                        if g2 < least {
                            return None;
                        }
                        // Along the gradient's main axis, the neighbours must not be stronger.
                        let (dx, dy) = if gx.abs() >= gy.abs() { (1, 0) } else { (0, 1) };
                        (g2 >= norm2(grad(x + dx, y + dy)) && g2 > norm2(grad(x - dx, y - dy))).then(|| (x, y, g2.sqrt()))
                    })
                })
                .collect::<Vec<_>>()
        })
        .collect();
    // The strongest (a pool of 8 per edge fitted, partly selected: a full sort of a 12 MP
    // photo's candidates cost more than the fits), spread over the frame by a stride through
    // them by strength; none near a clipped sample.
    let pool = (8 * MAX_EDGES).min(cands.len());
    if pool > 0 && pool < cands.len() {
        cands.select_nth_unstable_by(pool - 1, |a, b| b.2.total_cmp(&a.2));
        cands.truncate(pool);
    }
    let clipped_at = |i: usize| clipped[i] != 0;
    cands.retain(|&(x, y, _)| !super::mask::any_within(clipped_at, w, h, (x - HALF, y - HALF, x + HALF, y + HALF), margin));
    cands.sort_by(|a, b| b.2.total_cmp(&a.2));
    let stride = (cands.len() / MAX_EDGES).max(1);
    let lum = |x: usize, y: usize| super::highlights::luminance(&rgb.data[(y * w + x) * 3..][..3]);
    let mut widths: Vec<f32> = cands.par_iter().step_by(stride).take(MAX_EDGES).filter_map(|&(x, y, _)| fit_edge(&lum, x, y)).collect();
    if widths.len() < MIN_EDGES {
        return None;
    }
    let k = ((widths.len() - 1) as f32 * PERCENTILE).round() as usize;
    let width = *widths.select_nth_unstable_by(k, f32::total_cmp).1;
    Some((width * width - PIXEL_VARIANCE).max(0.0).sqrt())
}

/// Rows of the candidate pass per band (each band computes its rows' luminance and two more
/// above and below).
const BAND_ROWS: usize = 64;

/// The luminance of rows `rows` of `rgb`, one plane of `rows.len()` rows.
fn luminance_rows(rgb: &Image, rows: std::ops::Range<usize>) -> Vec<f32> {
    let w = rgb.width;
    rgb.data[rows.start * w * 3..rows.end * w * 3].chunks_exact(3).map(super::highlights::luminance).collect()
}

/// Fits `a + b·Φ((s - s0) / w)` to the window around (x, y), `s` each pixel centre's signed
/// distance along the luminance gradient's direction; returns w when the fit explains at
/// least [`MIN_EXPLAINED`] of the window's variance and the step is at least [`MIN_STEP`].
fn fit_edge(lum: &impl Fn(usize, usize) -> f32, x: usize, y: usize) -> Option<f32> {
    // The direction from a 3x3 Sobel (less noisy than the central difference).
    let at = |dx: isize, dy: isize| lum(x.wrapping_add_signed(dx), y.wrapping_add_signed(dy));
    let gx = at(1, -1) + 2.0 * at(1, 0) + at(1, 1) - at(-1, -1) - 2.0 * at(-1, 0) - at(-1, 1);
    let gy = at(-1, 1) + 2.0 * at(0, 1) + at(1, 1) - at(-1, -1) - 2.0 * at(0, -1) - at(1, -1);
    let g = gx.hypot(gy);
    if g <= 0.0 {
        return None;
    }
    let (nx, ny) = (gx / g, gy / g);
    let n = (2 * HALF + 1) * (2 * HALF + 1);
    let mut s = Vec::with_capacity(n);
    let mut v = Vec::with_capacity(n);
    for dy in -(HALF as isize)..=HALF as isize {
        for dx in -(HALF as isize)..=HALF as isize {
            s.push(dx as f32 * nx + dy as f32 * ny);
            v.push(at(dx, dy));
        }
    }
    let mean = v.iter().sum::<f32>() / n as f32;
    let total: f32 = v.iter().map(|&t| (t - mean) * (t - mean)).sum();
    if total <= 0.0 {
        return None;
    }
    // Least squares for a and b (v ≈ a + b·Φ((s - s0)/w)) at one (s0, w): (error, w, b).
    let mut phi = vec![0.0f32; n];
    let mut try_fit = |s0: f32, width: f32| -> (f32, f32, f32) {
        for (p, &sk) in phi.iter_mut().zip(&s) {
            *p = normal_cdf((sk - s0) / width);
        }
        let (sp, spp, sv, spv) =
            phi.iter().zip(&v).fold((0.0, 0.0, 0.0, 0.0), |(sp, spp, sv, spv), (&p, &t)| (sp + p, spp + p * p, sv + t, spv + p * t));
        let det = n as f32 * spp - sp * sp;
        if det <= 1e-6 {
            return (f32::INFINITY, width, 0.0);
        }
        let b = (n as f32 * spv - sp * sv) / det;
        let a = (sv - b * sp) / n as f32;
        (phi.iter().zip(&v).map(|(&p, &t)| (a + b * p - t).powi(2)).sum(), width, b)
    };
    // A coarse grid (offsets 0.25 px, widths 0.2 px), then two rounds of half steps around
    // its best: ~150 fits instead of the ~1,200 of the fine grid, the same answer on the
    // unit test's edges.
    let mut best = (f32::INFINITY, 0.0f32, 0.0f32, 0.0f32);
    let mut s0 = -S_MAX;
    while s0 <= S_MAX + 1e-6 {
        let mut width = W_MIN;
        while width <= W_MAX + 1e-6 {
            let (e, wd, b) = try_fit(s0, width);
            if e < best.0 {
                best = (e, wd, b, s0);
            }
            width += 4.0 * W_STEP;
        }
        s0 += 2.5 * S_STEP;
    }
    for (ds, dw) in [(1.25 * S_STEP, 2.0 * W_STEP), (0.625 * S_STEP, W_STEP)] {
        let (_, w0, _, c0) = best;
        for i in -1..=1 {
            for j in -1..=1 {
                let (s0, width) = (c0 + i as f32 * ds, w0 + j as f32 * dw);
                if (i, j) != (0, 0) && width >= W_MIN && s0.abs() <= S_MAX {
                    let (e, wd, b) = try_fit(s0, width);
                    if e < best.0 {
                        best = (e, wd, b, s0);
                    }
                }
            }
        }
    }
    let (err, width, step, _) = best;
    (step >= MIN_STEP && err <= (1.0 - MIN_EXPLAINED) * total && width < W_MAX).then_some(width)
}

/// The standard normal CDF, from erf by Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7), in
/// f32: the edge fits evaluate it ~6 million times at 12 MP, and f64's `exp` was 40% of their
/// time for no accuracy the fit can use (the approximation's error is f32's epsilon).
fn normal_cdf(x: f32) -> f32 {
    let z = x.abs() / std::f32::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * z);
    let poly = t * (0.254_829_6 + t * (-0.284_496_74 + t * (1.421_413_7 + t * (-1.453_152 + t * 1.061_405_4))));
    let erf = 1.0 - poly * (-z * z).exp();
    let p = 0.5 * (1.0 + erf);
    if x >= 0.0 { p } else { 1.0 - p }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Straight edges at several angles and offsets between two flat grey levels, drawn 8x8
    /// supersampled and blurred by a Gaussian of σ: the estimate is within 0.12 px of σ.
    #[test]
    fn sharpest_edges_give_the_psf() {
        for &sigma in &[0.0f32, 0.5, 0.7, 1.2] {
            let (w, h, ss) = (96usize, 96usize, 8usize);
            // Several polygon-ish shapes: half-planes in cells of 24x24, each at its own angle.
            let value = |x: f32, y: f32| -> f32 {
                let (cx, cy) = ((x / 24.0).floor(), (y / 24.0).floor());
                let a = 0.37 + 1.13 * (cx * 4.0 + cy);
                let (ox, oy) = (cx * 24.0 + 12.3, cy * 24.0 + 11.7);
                if (x - ox) * a.cos() + (y - oy) * a.sin() > 0.0 { 0.6 } else { 0.1 }
            };
            let (sw, sh) = (w * ss, h * ss);
            let mut hi: Vec<f32> = (0..sw * sh).map(|i| value((i % sw) as f32 / ss as f32, (i / sw) as f32 / ss as f32)).collect();
            if sigma > 0.0 {
                let img = crate::stages::mask::gaussian_blur(&Image::from_vec(sw, sh, 1, hi).unwrap(), sigma * ss as f32);
                hi = img.data;
            }
            let mut rgb = Image::filled(w, h, 3, 0.0);
            for y in 0..h {
                for x in 0..w {
                    let mut acc = 0.0;
                    for j in 0..ss {
                        for i in 0..ss {
                            acc += hi[(y * ss + j) * sw + x * ss + i];
                        }
                    }
                    let v = acc / (ss * ss) as f32;
                    rgb.pixel_mut(x, y).copy_from_slice(&[v, v, v]);
                }
            }
            let got = estimate(&rgb, &vec![0; w * h], 2.0).expect("edges found");
            assert!((got - sigma).abs() <= 0.12, "σ {sigma}: estimated {got}");
        }
    }

    /// A photo whose only edges are a small square's (8 fits): still an estimate near σ
    /// (with 12 edges needed there was none, and the highlights stage fell back to its lights).
    #[test]
    fn a_few_edges_are_enough() {
        let (w, h, ss, sigma) = (40usize, 40usize, 8usize, 0.7f32);
        let (sw, sh) = (w * ss, h * ss);
        let inside = |x: f32, y: f32| (16.0..24.0).contains(&x) && (16.0..24.0).contains(&y);
        let hi: Vec<f32> =
            (0..sw * sh).map(|i| if inside((i % sw) as f32 / ss as f32, (i / sw) as f32 / ss as f32) { 0.6 } else { 0.1 }).collect();
        let hi = crate::stages::mask::gaussian_blur(&Image::from_vec(sw, sh, 1, hi).unwrap(), sigma * ss as f32).data;
        let mut rgb = Image::filled(w, h, 3, 0.0);
        for y in 0..h {
            for x in 0..w {
                let v = (0..ss * ss).map(|k| hi[(y * ss + k / ss) * sw + x * ss + k % ss]).sum::<f32>() / (ss * ss) as f32;
                rgb.pixel_mut(x, y).copy_from_slice(&[v, v, v]);
            }
        }
        let got = estimate(&rgb, &vec![0; w * h], 2.0).expect("a square's edges are enough");
        assert!((got - sigma).abs() <= 0.12, "estimated {got}");
        // Nothing but flat grey: no edge, no estimate.
        assert_eq!(estimate(&Image::filled(w, h, 3, 0.3), &vec![0; w * h], 2.0), None);
    }

    #[test]
    fn normal_cdf_matches_known_values() {
        for (x, want) in [(0.0f32, 0.5f32), (1.0, 0.841_344_7), (-1.0, 0.158_655_3), (2.5, 0.993_790_3), (-3.0, 0.001_349_9)] {
            assert!((normal_cdf(x) - want).abs() < 1e-5, "Φ({x}) = {}", normal_cdf(x));
        }
    }
}
