//! Non-focal visibility (eq. 4) for a stripe of rows: box means of alpha from a summed-area
//! table, O(1) per pixel, the same numbers as the plain box mean of [`super::super::exact`].

use super::super::layer::{A, CHANNELS};
use super::super::lens::visibility_half_size;
use crate::ImageRef;

/// Non-focal visibility (eq. 4) of rows `[y0, y1)` into `out`: box means of the
/// replicate-padded alpha from a summed-area table `sat` (scratch, f64) of just the rows the
/// boxes reach. `sigma` holds the whole layer's scatter radii, `p` is the window half-size.
/// O(1) per pixel plus the table, `(rows + 2n)·(w + 2n)` for the stripe's largest box
/// half-size n; no table at all when every box is one pixel or the rows' alpha is constant.
#[inline(never)]
pub(super) fn visibility_rows(img: ImageRef<'_>, sigma: &[f32], p: usize, y0: usize, y1: usize, sat: &mut Vec<f64>, out: &mut Vec<f32>) {
    let (w, h) = (img.width, img.height);
    let nmax = sigma[y0 * w..y1 * w].iter().map(|&s| visibility_half_size(s, p)).max().unwrap_or(0);
    out.clear();
    // Every box lies in these rows; if their alpha is one constant (an opaque background, an
    // empty part of a foreground layer), every mean is that constant, exactly.
    let (ra, rb) = (y0.saturating_sub(nmax), (y1 + nmax).min(h));
    if nmax == 0 {
        // Every box is the pixel itself.
        out.extend(img.data[y0 * w * CHANNELS..y1 * w * CHANNELS].chunks_exact(CHANNELS).map(|px| px[A]));
        return;
    }
    let a0 = img.data[ra * w * CHANNELS + A];
    if img.data[ra * w * CHANNELS..rb * w * CHANNELS].chunks_exact(CHANNELS).all(|px| px[A] == a0) {
        out.resize((y1 - y0) * w, a0);
        return;
    }
    let (pw, ph) = (w + 2 * nmax, (y1 - y0) + 2 * nmax);
    sat.clear();
    sat.resize((pw + 1) * (ph + 1), 0.0);
    for yy in 0..ph {
        let sy = (y0 as i64 + yy as i64 - nmax as i64).clamp(0, h as i64 - 1) as usize;
        let src = &img.data[sy * w * CHANNELS..(sy + 1) * w * CHANNELS];
        let (above, this) = sat[yy * (pw + 1)..(yy + 2) * (pw + 1)].split_at_mut(pw + 1);
        let mut row = 0f64;
        // Replicate padding: the left and right margins repeat the edge pixels.
        let alpha = std::iter::repeat_n(src[A], nmax)
            .chain(src.chunks_exact(CHANNELS).map(|px| px[A]))
            .chain(std::iter::repeat_n(src[(w - 1) * CHANNELS + A], nmax));
        for ((t, &u), a) in this[1..].iter_mut().zip(&above[1..]).zip(alpha) {
            row += a as f64;
            *t = u + row;
        }
    }
    let inv_area: Vec<f64> = (0..=nmax).map(|n| 1.0 / ((2 * n + 1) * (2 * n + 1)) as f64).collect();
    for y in y0..y1 {
        for x in 0..w {
            let n = visibility_half_size(sigma[y * w + x], p);
            let (cx, cy) = (x + nmax, y - y0 + nmax);
            let (xa, ya, xb, yb) = (cx - n, cy - n, cx + n + 1, cy + n + 1);
            let s = sat[yb * (pw + 1) + xb] - sat[ya * (pw + 1) + xb] - sat[yb * (pw + 1) + xa] + sat[ya * (pw + 1) + xa];
            out.push((s * inv_area[n]) as f32);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::exact::box_alpha;
    use super::*;
    use crate::Image;

    #[test]
    fn summed_area_visibility_is_the_box_mean() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64 ^ 4;
        let mut uniform = move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
        };
        for (w, h, p) in [(37usize, 150usize, 9usize), (5, 70, 40), (1, 1, 3), (64, 64, 0)] {
            // Alpha: random, with a run of constant rows (the shortcut) and exact 0 / 1.
            let mut data = Vec::with_capacity(w * h * CHANNELS);
            for i in 0..w * h {
                let a = match (i / w) % 50 {
                    0..10 => 1.0,
                    10..12 => 0.0,
                    _ => uniform(),
                };
                data.extend_from_slice(&[0.2, 0.3, 0.4, a, 0.5]);
            }
            let img = Image::from_vec(w, h, CHANNELS, data).unwrap();
            // Scatter radii from 1 (one-pixel boxes) to beyond the window.
            let sigma: Vec<f32> = (0..w * h).map(|_| 1.0 + uniform() * 3.0 * p as f32).collect();
            let (mut sat, mut out) = (Vec::new(), Vec::new());
            for y0 in (0..h).step_by(64) {
                let y1 = (y0 + 64).min(h);
                visibility_rows(img.as_image_ref(), &sigma, p, y0, y1, &mut sat, &mut out);
                assert_eq!(out.len(), (y1 - y0) * w);
                for y in y0..y1 {
                    for x in 0..w {
                        let want = box_alpha(img.as_image_ref(), x, y, visibility_half_size(sigma[y * w + x], p));
                        let got = out[(y - y0) * w + x];
                        assert!((got - want).abs() <= 1e-6, "{w}x{h} p={p} ({x},{y}): {got} vs {want}");
                    }
                }
            }
        }
    }
}
