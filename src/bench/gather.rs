//! The gathering baseline: every output pixel averages the all-in-focus image over a disk of
//! its *own* circle of confusion, `r(x) = K·|D(x) − f|`, as SteReFo-style and other
//! single-layer "gather" renderers do. There is no occlusion reasoning: a sharp foreground
//! pixel stays sharp (its CoC is small) and a blurred background pixel next to it gathers the
//! foreground's colour (bleeding), and a blurred foreground never turns semi-transparent.
//!
//! Disk coverage is exact per row: each row of the disk is a span whose fractional ends are
//! weighted by how much of the end pixel they cover, summed with a prefix sum per row
//! (O(r) per pixel). Borders replicate.

use crate::image::Image;
use crate::render::lens::coc_radius;
use rayon::prelude::*;

/// Gathers `rgb` (linear, 3 channels) with per-pixel CoC radii from `disparity` (one channel).
pub fn gather(rgb: &Image, disparity: &Image, blur: f32, focus: f32) -> Image {
    let (w, h) = (rgb.width, rgb.height);
    assert_eq!((disparity.width, disparity.height, rgb.channels), (w, h, 3), "gather: input shapes");
    // Row prefix sums per channel: P[y][c][j] = Σ_{k<j} rgb[y][k][c].
    let prefix: Vec<Vec<[f64; 3]>> = (0..h)
        .map(|y| {
            let mut p = vec![[0f64; 3]; w + 1];
            for x in 0..w {
                let px = rgb.pixel(x, y);
                for c in 0..3 {
                    p[x + 1][c] = p[x][c] + px[c] as f64;
                }
            }
            p
        })
        .collect();
    let mut out = Image::new(w, h, 3);
    out.data.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let r = coc_radius(disparity.data[y * w + x] - focus, blur);
            if r < 0.5 {
                row[x * 3..x * 3 + 3].copy_from_slice(rgb.pixel(x, y));
                continue;
            }
            let cx = x as f64;
            let ri = r.floor() as isize;
            let mut acc = [0f64; 3];
            let mut wsum = 0f64;
            for dy in -ri..=ri {
                let hw2 = (r as f64).powi(2) - (dy * dy) as f64;
                if hw2 <= 0.0 {
                    continue;
                }
                let hw = hw2.sqrt();
                let yy = (y as isize + dy).clamp(0, h as isize - 1) as usize;
                let p = &prefix[yy];
                let (a, b) = (cx - hw, cx + hw);
                let (fa, fb) = (integral(p, rgb, yy, a), integral(p, rgb, yy, b));
                for c in 0..3 {
                    acc[c] += fb[c] - fa[c];
                }
                wsum += b - a;
            }
            for c in 0..3 {
                row[x * 3 + c] = (acc[c] / wsum) as f32;
            }
        }
    });
    out
}

/// `F(t) = ∫_{-1/2}^{t} row(s) ds` of the piecewise-constant row (pixel j covers
/// [j − 1/2, j + 1/2]), replicated beyond both ends.
#[inline]
fn integral(p: &[[f64; 3]], rgb: &Image, y: usize, t: f64) -> [f64; 3] {
    let w = rgb.width;
    let u = t + 0.5;
    if u <= 0.0 {
        let e = rgb.pixel(0, y);
        return [0, 1, 2].map(|c| u * e[c] as f64);
    }
    if u >= w as f64 {
        let e = rgb.pixel(w - 1, y);
        return [0, 1, 2].map(|c| p[w][c] + (u - w as f64) * e[c] as f64);
    }
    let j = u.floor() as usize;
    let v = rgb.pixel(j, y);
    [0, 1, 2].map(|c| p[j][c] + (u - j as f64) * v[c] as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flat_image_stays_flat_and_in_focus_is_identity() {
        let rgb = Image::filled(9, 7, 3, 0.25);
        let d = Image::filled(9, 7, 1, 0.0);
        let out = gather(&rgb, &d, 10.0, 1.0);
        assert!(out.data.iter().all(|&v| (v - 0.25).abs() < 1e-6));
        let mut tex = Image::new(5, 5, 3);
        tex.data.iter_mut().enumerate().for_each(|(i, v)| *v = i as f32);
        assert_eq!(gather(&tex, &Image::filled(5, 5, 1, 0.3), 10.0, 0.3).data, tex.data);
    }

    #[test]
    fn blurred_point_spreads_over_its_disk() {
        let mut rgb = Image::new(21, 21, 3);
        rgb.pixel_mut(10, 10).copy_from_slice(&[1.0, 1.0, 1.0]);
        let d = Image::filled(21, 21, 1, 1.0);
        let out = gather(&rgb, &d, 3.0, 0.0);
        // Radius 3: the centre gathers 1/(π·9) of the point, a pixel 5 px away gathers none.
        assert!((out.pixel(10, 10)[0] - 1.0 / (std::f32::consts::PI * 9.0)).abs() < 0.01);
        assert_eq!(out.pixel(15, 10)[0], 0.0);
    }
}
