//! Where the backward pass puts its gradients: per-pixel f64 accumulators, filled in row bands
//! (each band owns a buffer covering its rows plus the window's reach, so targets scatter to
//! their sources without locks), then summed.

use rayon::prelude::*;

/// Per-pixel gradient accumulator of one layer, in f64 (gradients of HDR scenes with tiny
/// weights pass 1e38; f64 keeps them, [`saturate`] brings them back into f32).
#[derive(Clone, Copy, Debug, Default)]
pub struct PixelGrad {
    /// `∂L/∂` linear R, G, B.
    pub colour: [f64; 3],
    /// `∂L/∂α`.
    pub alpha: f64,
    /// `∂L/∂` radius: the scatter radius σ (official) or the CoC radius `K·|d|` (physical),
    /// turned into disparity, focus and K gradients by [`super::finish`].
    pub radius: f64,
    /// `∂L/∂d` through terms that read the relative disparity directly (occlusion, depth groups).
    pub disparity: f64,
    /// `∂L/∂q`, the target's on-focal defocus factor (official profile).
    pub defocus: f64,
}

impl PixelGrad {
    fn add(&mut self, o: &PixelGrad) {
        for c in 0..3 {
            self.colour[c] += o.colour[c];
        }
        self.alpha += o.alpha;
        self.radius += o.radius;
        self.disparity += o.disparity;
        self.defocus += o.defocus;
    }
}

/// A band's accumulator: rows `[row0, row0 + rows)` of a `width`-wide image.
pub struct Band {
    width: usize,
    row0: usize,
    buf: Vec<PixelGrad>,
}

impl Band {
    /// The accumulator of pixel `j` (row-major index of the whole image); `j` must lie in the
    /// band's rows (targets reach at most the window's half-size beyond their own rows).
    #[inline(always)]
    pub fn at(&mut self, j: usize) -> &mut PixelGrad {
        &mut self.buf[j - self.row0 * self.width]
    }
}

/// Runs `target_row(y, band)` for every row `y` of a `width × height` image, rows split into
/// bands run in parallel (about four per thread), each band scattering into its own buffer of
/// rows `[y0 - reach, y1 + reach)`; returns the per-pixel sums. Allocates the bands' buffers
/// (56 bytes per pixel and band row) and the result.
pub fn scatter_rows(width: usize, height: usize, reach: usize, target_row: impl Fn(usize, &mut Band) + Sync) -> Vec<PixelGrad> {
    let bands = (rayon::current_num_threads() * 4).clamp(1, height);
    let per = height.div_ceil(bands);
    let parts: Vec<Band> = (0..height.div_ceil(per))
        .into_par_iter()
        .map(|b| {
            let (y0, y1) = (b * per, ((b + 1) * per).min(height));
            let (r0, r1) = (y0.saturating_sub(reach), (y1 + reach).min(height));
            let mut band = Band { width, row0: r0, buf: vec![PixelGrad::default(); (r1 - r0) * width] };
            for y in y0..y1 {
                target_row(y, &mut band);
            }
            band
        })
        .collect();
    let mut out = vec![PixelGrad::default(); width * height];
    for band in &parts {
        let start = band.row0 * width;
        out[start..start + band.buf.len()].par_iter_mut().zip(&band.buf).for_each(|(o, g)| o.add(g));
    }
    out
}

/// The adjoint of the official visibility (eq. 4), the mean alpha over a replicate-padded box
/// of half-size `half[i]` around each pixel: adds `g[i] / (2n + 1)²` to the alpha gradient of
/// every pixel the box reads. A difference array over the image padded by `pad ≥ max(half)`,
/// one 2D prefix sum, then the padding folded onto the border pixels it replicates:
/// O((W + 2·pad)·(H + 2·pad)), whatever the box sizes.
pub fn box_mean_adjoint(width: usize, height: usize, pad: usize, half: &[usize], g: &[f64], out: &mut [PixelGrad]) {
    let (pw, ph) = (width + 2 * pad + 1, height + 2 * pad + 1);
    let mut diff = vec![0f64; pw * ph];
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            if g[i] == 0.0 {
                continue;
            }
            let n = half[i];
            let v = g[i] / ((2 * n + 1) * (2 * n + 1)) as f64;
            // Box [x - n, x + n] in padded coordinates (x + pad - n ≥ 0 since n ≤ pad).
            let (x0, x1, y0, y1) = (x + pad - n, x + pad + n + 1, y + pad - n, y + pad + n + 1);
            diff[y0 * pw + x0] += v;
            diff[y0 * pw + x1] -= v;
            diff[y1 * pw + x0] -= v;
            diff[y1 * pw + x1] += v;
        }
    }
    // 2D prefix sum: diff[py][px] becomes the summed weight of padded cell (px, py).
    for py in 0..ph {
        for px in 1..pw {
            diff[py * pw + px] += diff[py * pw + px - 1];
        }
    }
    for py in 1..ph {
        for px in 0..pw {
            diff[py * pw + px] += diff[(py - 1) * pw + px];
        }
    }
    for py in 0..ph - 1 {
        let y = (py as i64 - pad as i64).clamp(0, height as i64 - 1) as usize;
        for px in 0..pw - 1 {
            let x = (px as i64 - pad as i64).clamp(0, width as i64 - 1) as usize;
            out[y * width + x].alpha += diff[py * pw + px];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::render::exact::box_alpha;
    use crate::render::layer::{A, CHANNELS};

    /// The adjoint identity `<g, box(α)> = <boxᵀ(g), α>` against the forward's `box_alpha`,
    /// with boxes larger than the image (replicate padding) and varying sizes.
    #[test]
    fn box_adjoint_is_the_transpose_of_box_alpha() {
        let (w, h, pad) = (7usize, 5usize, 6usize);
        let mut img = Image::new(w, h, CHANNELS);
        for (i, px) in img.data.chunks_exact_mut(CHANNELS).enumerate() {
            px[A] = ((i * 37) % 11) as f32 / 10.0;
        }
        let half: Vec<usize> = (0..w * h).map(|i| (i * 5) % (pad + 1)).collect();
        let g: Vec<f64> = (0..w * h).map(|i| ((i * 13) % 7) as f64 - 3.0).collect();
        let forward: f64 = (0..w * h).map(|i| g[i] * box_alpha(img.as_image_ref(), i % w, i / w, half[i]) as f64).sum();
        let mut out = vec![PixelGrad::default(); w * h];
        box_mean_adjoint(w, h, pad, &half, &g, &mut out);
        let adjoint: f64 = (0..w * h).map(|i| out[i].alpha * img.data[i * CHANNELS + A] as f64).sum();
        assert!((forward - adjoint).abs() < 1e-5 * forward.abs().max(1.0), "{forward} vs {adjoint}");
    }

    /// Bands scatter across their row boundaries and sum to the serial result.
    #[test]
    fn bands_sum_like_one_buffer() {
        let (w, h, reach) = (6usize, 23usize, 3usize);
        let out = scatter_rows(w, h, reach, |y, band| {
            for x in 0..w {
                for dy in -(reach as i64)..=reach as i64 {
                    let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                    band.at(yy * w + x).alpha += 1.0;
                }
            }
        });
        let mut want = vec![0f64; w * h];
        for y in 0..h {
            for dy in -(reach as i64)..=reach as i64 {
                let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
                for x in 0..w {
                    want[yy * w + x] += 1.0;
                }
            }
        }
        assert!(out.iter().zip(&want).all(|(g, &v)| g.alpha == v));
    }
}
