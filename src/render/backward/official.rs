//! The official profile's per-layer backward: the adjoint of [`exact`]'s official kernel,
//! whose raw output `[ΣR, ΣG, ΣB, W, o]` the tape keeps (the forward is that kernel itself).
//!
//! Per target `x` and tap to source `y`: `k = α_y·E(σ_y, r)·v` with `v = O(y, x)` (1 at the
//! centre or with `q(x) = 1`), `ΣRGB += k·c_y`, `W += k`. Given the cotangents `(g_Σ, g_W)` of
//! the target's sums, `g_k = g_Σ·c_y + g_W`, and the tap adds `g_Σ·k` to `c_y`, `g_k·E·v` to
//! `α_y` (also where `α_y = 0`, which the forward skips), `g_k·α_y·v·∂E/∂σ` to `σ_y`, and
//! through `v` to `d_y`, `d_x` and `q(x)`. The visibility `o` is a box mean of alpha whose
//! size `trunc(σ/2)` is piecewise constant: its gradient goes to alpha only.
//!
//! [`exact`]: crate::render::exact

use super::accum::{self, PixelGrad};
use crate::render::aperture::Tap;
use crate::render::layer::{A, CHANNELS, D, Layer};
use crate::render::lens::{energy_with_grad, focal_defocus, in_front_with_grad, scatter_radius, visibility_half_size, weight_unit};
use crate::render::{RenderSettings, min_visible_radius};

/// Gradients of one layer given, per pixel, the cotangents `[g_ΣR, g_ΣG, g_ΣB, g_W, g_o]` of
/// its raw sums. One pass over the taps per target (no second forward: the sums are not
/// needed, only their cotangents), rows in parallel bands (see [`accum::scatter_rows`]); then
/// the box visibility's adjoint. Allocates two planes of per-pixel terms and the bands.
pub(super) fn backward(layer: &Layer, s: &RenderSettings, taps: &[Tap], cot: &[super::RawCot]) -> Vec<PixelGrad> {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let p = s.lens / 2;
    let d: Vec<f32> = img.data.chunks_exact(CHANNELS).map(|px| px[D] - s.focus).collect();
    let sigma: Vec<f32> = d.iter().map(|&d| scatter_radius(d, s.blur)).collect();
    // The forward's weight unit: W and ΣRGB scale with unit², their cotangents with unit⁻²,
    // so the products below are those of the forward's own numbers.
    let unit = weight_unit(min_visible_radius(img, &sigma));
    let mut grads = accum::scatter_rows(w, h, p, |y, band| {
        for x in 0..w {
            let i = y * w + x;
            let [g0, g1, g2, g_w, ..] = cot[i];
            if g0 == 0.0 && g1 == 0.0 && g2 == 0.0 && g_w == 0.0 {
                continue;
            }
            let dx = d[i];
            let q = if s.occlusion { focal_defocus(dx, s.blur) } else { 1.0 };
            let (mut g_dx, mut g_q) = (0f64, 0f64);
            for t in taps {
                let yy = (y as i64 + t.di as i64).clamp(0, h as i64 - 1) as usize;
                let xx = (x as i64 + t.dj as i64).clamp(0, w as i64 - 1) as usize;
                let j = yy * w + xx;
                let px = &img.data[j * CHANNELS..(j + 1) * CHANNELS];
                let (e, de) = energy_with_grad(sigma[j], t.r, unit);
                let centre = t.di == 0 && t.dj == 0;
                let (v, front) = if centre || q == 1.0 {
                    (1.0, None)
                } else {
                    let (f, df) = in_front_with_grad(d[j], dx);
                    ((1.0 - q) * f + q, Some((f, df)))
                };
                let g_k = g0 * px[0] as f64 + g1 * px[1] as f64 + g2 * px[2] as f64 + g_w;
                let src = band.at(j);
                src.alpha += g_k * (e * v) as f64;
                let a = px[A];
                if a == 0.0 {
                    continue;
                }
                let k = (a * e * v) as f64;
                src.colour[0] += g0 * k;
                src.colour[1] += g1 * k;
                src.colour[2] += g2 * k;
                src.radius += g_k * (a * v * de) as f64;
                if let Some((f, df)) = front {
                    let g_v = g_k * (a * e) as f64;
                    let g_d = g_v * ((1.0 - q) * df) as f64;
                    src.disparity += g_d;
                    g_dx -= g_d;
                    g_q += g_v * (1.0 - f) as f64;
                }
            }
            let own = band.at(i);
            own.disparity += g_dx;
            own.defocus += g_q;
        }
    });
    let half: Vec<usize> = sigma.iter().map(|&s| visibility_half_size(s, p)).collect();
    let g_vis: Vec<f64> = cot.iter().map(|c| c[4]).collect();
    accum::box_mean_adjoint(w, h, p, &half, &g_vis, &mut grads);
    empty_targets(layer, s, &half, cot, &mut grads);
    grads
}

/// Where a layer has neither weight nor visibility at a target `x` (its whole window is
/// transparent), its contribution `C·o·T` is 0 and `C = ΣRGB/W` is 0/0. Giving a source `y`
/// alpha ε there adds ε·(its box cells)/(2n + 1)² to `o` and, if `y` is also one of `x`'s
/// taps, makes `C = c_y`: the right derivative in `α_y` is `T·(g·c_y)·cells/(2n + 1)²`. This
/// adds it (the cotangent's `e = g·T`), box cell by box cell: O(n²) per such target only.
fn empty_targets(layer: &Layer, s: &RenderSettings, half: &[usize], cot: &[super::RawCot], grads: &mut [PixelGrad]) {
    let img = layer.image();
    let (w, h) = (img.width as i64, img.height as i64);
    let p = (s.lens / 2) as i64;
    // The tap offsets that read clamped coordinate `c` from `x` along one axis of length `len`:
    // an interval of offsets; the one closest to 0 decides whether some tap reaches it.
    let nearest = |x: i64, c: i64, len: i64| -> i64 {
        let (lo, hi) = (if c == 0 { i64::MIN / 4 } else { c - x }, if c == len - 1 { i64::MAX / 4 } else { c - x });
        if lo <= 0 && 0 <= hi { 0 } else { lo.abs().min(hi.abs()) }
    };
    for (i, c) in cot.iter().enumerate() {
        let e = [c[5], c[6], c[7]];
        if e == [0.0; 3] {
            continue;
        }
        let (x, y) = ((i as i64) % w, (i as i64) / w);
        let n = half[i] as i64;
        let cell = 1.0 / ((2 * n + 1) * (2 * n + 1)) as f64;
        for yy in y - n..=y + n {
            let cy = yy.clamp(0, h - 1);
            for xx in x - n..=x + n {
                let cx = xx.clamp(0, w - 1);
                let (dy, dx) = (nearest(y, cy, h), nearest(x, cx, w));
                // A tap of the strict disk (see `aperture::disk_taps`) reads this source.
                if (((dy * dy + dx * dx) as f32).sqrt()) < p as f32 {
                    let j = (cy * w + cx) as usize;
                    let px = &img.data[j * CHANNELS..j * CHANNELS + 3];
                    grads[j].alpha += cell * (e[0] * px[0] as f64 + e[1] * px[1] as f64 + e[2] * px[2] as f64);
                }
            }
        }
    }
}
