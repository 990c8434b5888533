//! A Gaussian-PSF renderer (GaussPSF-style, Gur & Wolf 2019): the depth-from-defocus ablation
//! of the paper's Table 2. It has no occlusion and no disk: every pixel `j` of an all-in-focus
//! photo spreads a normalized Gaussian, and each output pixel is the weighted mean of what
//! reaches it,
//!
//! ```text
//! σ_j   = sqrt((SIGMA_PER_COC · coc_radius(d_j − focus, K))² + SIGMA_MIN²)      (pixels)
//! w_j(p) = exp(−|p − j|² / 2σ_j²) / N_j,   N_j = Σ_{|t|∞ ≤ R} exp(−|t|² / 2σ_j²)
//! out(p) = Σ_j w_j(p)·c_j / Σ_j w_j(p)     (j over the image, |p − j|∞ ≤ R)
//! ```
//!
//! `N_j` sums the Gaussian over the whole `(2R+1)²` window (not clipped at the border), so
//! each source carries the same energy wherever it is; the division by the total weight keeps
//! flat regions flat at the border. σ is a smooth function of `d` (the floor `SIGMA_MIN` makes
//! it differentiable on the focal plane), and so is the whole render: [`GaussTape::vjp`] is its
//! exact derivative with respect to the disparity (checked against central differences below).
//!
//! Cost: forward and VJP each O(pixels·(2R+1)²) with one `exp` per tap, parallel over rows;
//! the tape keeps 3 floats per pixel besides the output.

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::lens::coc_radius;
use rayon::prelude::*;

/// σ per pixel of CoC radius: a uniform disk of radius r has a per-axis standard deviation of
/// r/2, so the Gaussian has the thin-lens kernel's second moment.
pub const SIGMA_PER_COC: f32 = 0.5;
/// Smallest σ, pixels: keeps σ differentiable on the focal plane and an in-focus pixel nearly
/// a delta (its neighbours get `exp(−2) / N ≈ 10%` of its weight each).
pub const SIGMA_MIN: f32 = 0.5;
/// The window reaches this many σ of the widest Gaussian (the tail beyond holds < 0.3%).
pub const WINDOW_SIGMAS: f32 = 3.0;

/// The Gaussian's σ (pixels) at relative disparity `d` for blur `k`, and `∂σ/∂d`.
#[inline]
pub fn sigma_with_grad(d: f32, k: f32) -> (f32, f32) {
    let s = SIGMA_PER_COC * coc_radius(d, k);
    let sigma = (s * s + SIGMA_MIN * SIGMA_MIN).sqrt();
    // σ² = (SIGMA_PER_COC·K)²·d² + SIGMA_MIN²  ⇒  ∂σ/∂d = (SIGMA_PER_COC·K)²·d / σ.
    (sigma, SIGMA_PER_COC * SIGMA_PER_COC * k * k * d / sigma)
}

/// The half-size R (pixels) of the window that disparities in [0, 1] need at `focus`, `blur`.
pub fn window_radius(blur: f32, focus: f32) -> usize {
    let (sigma, _) = sigma_with_grad(focus.max(1.0 - focus), blur);
    (WINDOW_SIGMAS * sigma).ceil() as usize
}

/// A recorded Gaussian-PSF render of one disparity map, ready for [`GaussTape::vjp`].
pub struct GaussTape {
    image: Image,
    radius: usize,
    /// Per source pixel: its Gaussian's constants (see [`Source`]).
    sources: Vec<Source>,
    /// Per output pixel: the total weight Σ_j w_j(p).
    total: Vec<f32>,
    /// The photo rendered (a copy).
    colours: Image,
}

/// One source pixel's Gaussian.
#[derive(Clone, Copy)]
struct Source {
    /// 1 / (2σ²).
    inv_two_var: f32,
    /// 1 / N.
    inv_norm: f32,
    /// σ.
    sigma: f32,
    /// (∂N/∂σ)·σ³ / N: the mean squared tap distance under the window's Gaussian.
    mean_sq: f32,
    /// ∂σ/∂d.
    dsigma: f32,
}

impl Source {
    fn new(d: f32, focus: f32, blur: f32, radius: usize) -> Source {
        let (sigma, dsigma) = sigma_with_grad(d - focus, blur);
        let inv_two_var = 0.5 / (sigma * sigma);
        // The window's sum is separable: N = n1², n1 = Σ_t exp(−t²/2σ²).
        let (mut n1, mut m1) = (0f64, 0f64);
        for t in -(radius as i64)..=radius as i64 {
            let e = (-(t * t) as f64 * inv_two_var as f64).exp();
            n1 += e;
            m1 += e * (t * t) as f64;
        }
        // Σ_t∈window |t|² e(t) / N = 2·(m1·n1)/n1² for the 2-D window.
        Source { inv_two_var, inv_norm: (1.0 / (n1 * n1)) as f32, sigma, mean_sq: (2.0 * m1 / n1) as f32, dsigma }
    }
}

impl GaussTape {
    /// Renders `aif` (linear RGB) with the disparity `disparity` (one channel, same size) at
    /// `focus`, `blur`, window half-size `radius` (see [`window_radius`]), keeping what the
    /// VJP needs. Errors (usage): sizes or channel counts that do not match.
    pub fn record(aif: &Image, disparity: &Image, focus: f32, blur: f32, radius: usize) -> Result<GaussTape> {
        if (aif.width, aif.height, aif.channels) != (disparity.width, disparity.height, 3) || disparity.channels != 1 {
            return Err(Error::usage(format!(
                "gauss_psf: the photo is {}x{}x{} and the disparity {}x{}x{}: they must be the same size, RGB and one channel",
                aif.width, aif.height, aif.channels, disparity.width, disparity.height, disparity.channels
            )));
        }
        let (w, h) = (aif.width, aif.height);
        let sources: Vec<Source> = disparity.data.iter().map(|&d| Source::new(d, focus, blur, radius)).collect();
        let mut image = Image::new(w, h, 3);
        let mut total = vec![0f32; w * h];
        let r = radius as isize;
        image.data.par_chunks_mut(w * 3).zip(total.par_chunks_mut(w)).enumerate().for_each(|(y, (row, tot))| {
            for x in 0..w {
                let (mut acc, mut b) = ([0f64; 3], 0f64);
                for_window(w, h, x, y, r, |j, dist2| {
                    let s = &sources[j];
                    let wt = ((-dist2 * s.inv_two_var).exp() * s.inv_norm) as f64;
                    b += wt;
                    for (a, &v) in acc.iter_mut().zip(&aif.data[j * 3..j * 3 + 3]) {
                        *a += wt * v as f64;
                    }
                });
                for c in 0..3 {
                    row[x * 3 + c] = (acc[c] / b) as f32;
                }
                tot[x] = b as f32;
            }
        });
        Ok(GaussTape { image, radius, sources, total, colours: aif.clone() })
    }

    /// The rendered image (linear RGB, the photo's size).
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// `∂L/∂disparity` (one channel, the photo's size) for `cotangent` = `∂L/∂image` (RGB).
    /// Panics if the cotangent's shape differs from the image's (an internal error).
    pub fn vjp(&self, cotangent: &Image) -> Image {
        let (w, h) = (self.image.width, self.image.height);
        assert_eq!((cotangent.width, cotangent.height, cotangent.channels), (w, h, 3), "gauss_psf cotangent shape");
        // ∂L/∂w_j(p) = Σ_c g_c(p)·(c_jc − out_c(p)) / B(p) = G(p)·c_j − s(p).
        let per_target: Vec<([f32; 3], f32)> = (0..w * h)
            .map(|p| {
                let b = self.total[p];
                let g = [0, 1, 2].map(|c| cotangent.data[p * 3 + c] / b);
                (g, (0..3).map(|c| g[c] * self.image.data[p * 3 + c]).sum())
            })
            .collect();
        let r = self.radius as isize;
        let mut grad = Image::new(w, h, 1);
        grad.data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, out) in row.iter_mut().enumerate() {
                let j = y * w + x;
                let s = &self.sources[j];
                let c = &self.colours.data[j * 3..j * 3 + 3];
                // ∂w/∂σ = w·(|t|² − mean_sq)/σ³.
                let mut acc = 0f64;
                for_window(w, h, x, y, r, |p, dist2| {
                    let wt = (-dist2 * s.inv_two_var).exp() * s.inv_norm;
                    let (g, sp) = &per_target[p];
                    let dl_dw = g[0] * c[0] + g[1] * c[1] + g[2] * c[2] - sp;
                    acc += (dl_dw * wt * (dist2 - s.mean_sq)) as f64;
                });
                *out = (acc / (s.sigma as f64).powi(3)) as f32 * s.dsigma;
            }
        });
        grad
    }
}

/// Calls `f(index, squared distance)` for every pixel of the `w × h` image within `r`
/// (Chebyshev) of (x, y), the pixel itself included.
#[inline(always)]
fn for_window(w: usize, h: usize, x: usize, y: usize, r: isize, mut f: impl FnMut(usize, f32)) {
    let (x, y) = (x as isize, y as isize);
    for yy in (y - r).max(0)..=(y + r).min(h as isize - 1) {
        let dy = (yy - y) as f32;
        for xx in (x - r).max(0)..=(x + r).min(w as isize - 1) {
            let dx = (xx - x) as f32;
            f(yy as usize * w + xx as usize, dx * dx + dy * dy);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rnd(seed: &mut u64) -> f32 {
        *seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (*seed >> 40) as f32 / (1u64 << 24) as f32
    }

    /// The VJP against central differences of `⟨cotangent, render(d)⟩` on a random 9×7 scene,
    /// pixels on the focal plane (d = focus) and far from it included. f32 forward, step 1e-2:
    /// agreement within 2% of the largest gradient per pixel.
    #[test]
    fn vjp_matches_finite_differences() {
        let (w, h) = (9usize, 7usize);
        let mut seed = 5u64;
        let aif = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd(&mut seed)).collect()).unwrap();
        let mut d = Image::from_vec(w, h, 1, (0..w * h).map(|_| rnd(&mut seed)).collect()).unwrap();
        let (focus, blur) = (0.7f32, 6.0f32);
        d.data[10] = focus;
        d.data[20] = focus + 0.01;
        let cot = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd(&mut seed) - 0.5).collect()).unwrap();
        let r = window_radius(blur, focus);
        let f = |d: &Image| -> f64 {
            let t = GaussTape::record(&aif, d, focus, blur, r).unwrap();
            t.image().data.iter().zip(&cot.data).map(|(a, b)| *a as f64 * *b as f64).sum()
        };
        let tape = GaussTape::record(&aif, &d, focus, blur, r).unwrap();
        let g = tape.vjp(&cot);
        let scale = g.data.iter().fold(0f32, |m, v| m.max(v.abs()));
        assert!(scale > 1e-3, "gradient vanishes: {scale}");
        let eps = 1e-2f32;
        let mut bad = Vec::new();
        for i in 0..w * h {
            let (mut a, mut b) = (d.clone(), d.clone());
            a.data[i] += eps;
            b.data[i] -= eps;
            let fd = ((f(&a) - f(&b)) / (2.0 * eps as f64)) as f32;
            if (fd - g.data[i]).abs() > 0.02 * scale {
                bad.push((i, g.data[i], fd));
            }
        }
        assert!(bad.is_empty(), "VJP vs FD (pixel, vjp, fd), scale {scale}: {bad:?}");
    }

    /// A flat photo stays flat whatever the disparity (the weights are normalized), and an
    /// in-focus pixel keeps most of its own colour.
    #[test]
    fn flat_stays_flat_and_focus_is_sharp() {
        let (w, h) = (12usize, 10usize);
        let mut seed = 3u64;
        let d = Image::from_vec(w, h, 1, (0..w * h).map(|_| rnd(&mut seed)).collect()).unwrap();
        let flat = Image::filled(w, h, 3, 0.25);
        let t = GaussTape::record(&flat, &d, 0.5, 8.0, window_radius(8.0, 0.5)).unwrap();
        assert!(t.image().data.iter().all(|v| (v - 0.25).abs() < 1e-5));
        let mut dot = Image::new(w, h, 3);
        dot.pixel_mut(5, 5).copy_from_slice(&[1.0, 1.0, 1.0]);
        let t = GaussTape::record(&dot, &Image::filled(w, h, 1, 1.0), 1.0, 8.0, window_radius(8.0, 1.0)).unwrap();
        assert!(t.image().pixel(5, 5)[0] > 0.5, "{}", t.image().pixel(5, 5)[0]);
        assert!(GaussTape::record(&dot, &Image::new(3, 3, 1), 1.0, 8.0, 2).is_err());
    }
}
