//! Losses of the paper's depth-from-defocus objective (Eqn. 7), each with its gradient:
//! L1 between a render and its target, the hierarchical SSIM (HSSIM) over several window
//! sizes, and a gradient-smoothness term on the estimated disparity.
//!
//! Every loss is a mean (so its scale does not depend on the image size), evaluated in f64,
//! and returns its gradient with respect to its first argument as an image of that argument's
//! shape. Cost: O(pixels·channels) each (SSIM: summed-area tables, whatever the window).

use crate::image::Image;
use rayon::prelude::*;

/// A loss value and its gradient with respect to the image it was given first.
#[derive(Clone, Debug, PartialEq)]
pub struct LossGrad {
    /// The loss (a mean, ≥ 0).
    pub value: f64,
    /// `∂loss/∂image`, the shape of the image.
    pub grad: Image,
}

/// The windows of the paper's hierarchical SSIM, pixels (odd sides).
pub const HSSIM_WINDOWS: [usize; 5] = [3, 5, 11, 21, 31];

/// SSIM's stabilizers `C1 = (0.01·L)²`, `C2 = (0.03·L)²` for a dynamic range `L = 1` (linear
/// colours of a non-HDR photo).
const C1: f64 = 1e-4;
const C2: f64 = 9e-4;

/// `mean |image - target|` over every value; gradient `sign(image - target)/n` (0 where equal).
/// Panics if the shapes differ (the caller checks sizes and names the inputs).
pub fn l1(image: &Image, target: &Image) -> LossGrad {
    assert_same_shape(image, target);
    let n = image.data.len().max(1) as f64;
    let mut grad = Image::new(image.width, image.height, image.channels);
    let mut sum = 0f64;
    for ((g, &a), &b) in grad.data.iter_mut().zip(&image.data).zip(&target.data) {
        let d = a as f64 - b as f64;
        sum += d.abs();
        *g = (d.signum() * (d != 0.0) as u8 as f64 / n) as f32;
    }
    LossGrad { value: sum / n, grad }
}

/// A render as the camera that took `target` would have stored it, where the target lost light
/// above white: at every sample that `clipped` marks (> 0: the share of the sample's footprint
/// that was stored at or above the clip level, resized with the photo), a render brighter than
/// the target is taken as the target itself (a clipped sample says only "at least this much").
/// Elsewhere the render passes unchanged. Returns the censored render and, per sample, whether
/// the render passed (the loss's gradient flows there and is 0 where it was censored).
/// Allocates a copy of the render and a flag per sample. Panics if the shapes differ.
pub fn censor(render: &Image, target: &Image, clipped: &Image) -> (Image, Vec<bool>) {
    assert_same_shape(render, target);
    assert_same_shape(render, clipped);
    let mut out = render.clone();
    let passed = out
        .data
        .iter_mut()
        .zip(target.data.iter().zip(&clipped.data))
        .map(|(r, (&t, &c))| {
            let over = c > 0.0 && *r > t;
            if over {
                *r = t;
            }
            !over
        })
        .collect();
    (out, passed)
}

/// `1 - mean SSIM` over every channel and every `window × window` box that lies wholly inside
/// the image (uniform weights, population variances). `None` when the window does not fit.
pub fn ssim(image: &Image, target: &Image, window: usize) -> Option<LossGrad> {
    let (value, grad) = windowed_ssim(image, target, &[window]).pop()?;
    Some(LossGrad { value, grad })
}

/// The hierarchical SSIM loss: the mean of [`ssim`] over `windows` that fit the image (the
/// paper uses [`HSSIM_WINDOWS`]); 0 with a zero gradient if none fits.
pub fn hssim(image: &Image, target: &Image, windows: &[usize]) -> LossGrad {
    let parts = windowed_ssim(image, target, windows);
    let mut grad = Image::new(image.width, image.height, image.channels);
    if parts.is_empty() {
        return LossGrad { value: 0.0, grad };
    }
    let k = parts.len() as f32;
    for (_, g) in &parts {
        grad.data.iter_mut().zip(&g.data).for_each(|(o, v)| *o += v / k);
    }
    LossGrad { value: parts.iter().map(|p| p.0).sum::<f64>() / parts.len() as f64, grad }
}

/// [`ssim`] for each of `windows` that fits the image, in order. The moments' tables are built
/// once per channel for every window, and the (window, channel) pairs run in parallel (a
/// sequential HSSIM was ~18% of a 512² dfd step on two threads).
fn windowed_ssim(image: &Image, target: &Image, windows: &[usize]) -> Vec<(f64, Image)> {
    assert_same_shape(image, target);
    let (w, h, ch) = (image.width, image.height, image.channels);
    let fits: Vec<usize> = windows.iter().copied().filter(|&k| k > 0 && k <= w && k <= h).collect();
    if fits.is_empty() {
        return Vec::new();
    }
    let moments: Vec<Moments> = (0..ch).into_par_iter().map(|c| Moments::new(image, target, c)).collect();
    let jobs: Vec<(usize, usize)> = fits.iter().flat_map(|&k| (0..ch).map(move |c| (k, c))).collect();
    let planes: Vec<(f64, Vec<f32>)> = jobs.par_iter().map(|&(k, c)| moments[c].ssim(k, ch)).collect();
    fits.iter()
        .zip(planes.chunks(ch.max(1)))
        .map(|(&k, planes)| {
            let count = ((w - k + 1) * (h - k + 1) * ch) as f64;
            let mut grad = Image::new(w, h, ch);
            let mut total = 0f64;
            for (c, (t, plane)) in planes.iter().enumerate() {
                total += t;
                grad.data.iter_mut().skip(c).step_by(ch).zip(plane).for_each(|(o, &v)| *o = v);
            }
            (1.0 - total / count, grad)
        })
        .collect()
}

/// One channel of an image and of its target, with the summed-area tables of the moments
/// SSIM reads (`x`, `y`, `x²`, `y²`, `xy`): shared by every window.
struct Moments {
    w: usize,
    h: usize,
    x: Vec<f64>,
    y: Vec<f64>,
    sums: [Sat; 5],
}

impl Moments {
    fn new(image: &Image, target: &Image, c: usize) -> Self {
        let (w, h, ch) = (image.width, image.height, image.channels);
        let x: Vec<f64> = image.data.iter().skip(c).step_by(ch).map(|&v| v as f64).collect();
        let y: Vec<f64> = target.data.iter().skip(c).step_by(ch).map(|&v| v as f64).collect();
        let sums = [
            Sat::new(w, h, |i| x[i]),
            Sat::new(w, h, |i| y[i]),
            Sat::new(w, h, |i| x[i] * x[i]),
            Sat::new(w, h, |i| y[i] * y[i]),
            Sat::new(w, h, |i| x[i] * y[i]),
        ];
        Moments { w, h, x, y, sums }
    }

    /// This channel's SSIM summed over every `window × window` box inside the image, and its
    /// gradient plane of `1 - mean SSIM` where the mean runs over the boxes of `channels`
    /// channels.
    fn ssim(&self, window: usize, channels: usize) -> (f64, Vec<f32>) {
        let (w, h, x, y) = (self.w, self.h, &self.x, &self.y);
        let (cw, chh) = (w - window + 1, h - window + 1);
        let n = (window * window) as f64;
        let count = (cw * chh * channels) as f64;
        let mut total = 0f64;
        // Per window (indexed by its top-left corner): ∂S/∂ of the raw moments E[x], E[x²], E[xy].
        let mut coef = vec![[0f64; 3]; w * h];
        for cy in 0..chh {
            for cx in 0..cw {
                let [mx, my, mxx, myy, mxy] = self.sums.each_ref().map(|s| s.sum(cx, cy, window) / n);
                let (vx, vy, cov) = (mxx - mx * mx, myy - my * my, mxy - mx * my);
                let (a1, a2, b1, b2) = (2.0 * mx * my + C1, 2.0 * cov + C2, mx * mx + my * my + C1, vx + vy + C2);
                let s = a1 * a2 / (b1 * b2);
                total += s;
                let ds_dmx = 2.0 * my * a2 / (b1 * b2) - s * 2.0 * mx / b1;
                let ds_dvx = -s / b2;
                let ds_dcov = 2.0 * a1 / (b1 * b2);
                coef[cy * w + cx] = [ds_dmx - 2.0 * mx * ds_dvx - my * ds_dcov, ds_dvx, ds_dcov];
            }
        }
        // Each pixel gathers the coefficients of the windows that contain it: corners within
        // `window - 1` above and left of it.
        let gather: [Sat; 3] = std::array::from_fn(|k| Sat::new(w, h, |i| coef[i][k]));
        let scale = -1.0 / (count * n);
        let mut grad = vec![0f32; w * h];
        for py in 0..h {
            for px in 0..w {
                let (x0, y0) = (px.saturating_sub(window - 1), py.saturating_sub(window - 1));
                let (x1, y1) = (px.min(cw - 1), py.min(chh - 1));
                let [g1, g2, g3] = gather.each_ref().map(|s| s.rect(x0, y0, x1, y1));
                let i = py * w + px;
                grad[i] = (scale * (g1 + 2.0 * x[i] * g2 + y[i] * g3)) as f32;
            }
        }
        (total, grad)
    }
}

/// Gradient smoothness of a one-channel map (the estimated disparity): the mean over
/// horizontal and vertical neighbour pairs of `|D(p) - D(q)|`, an L1 (total-variation) prior
/// that keeps depth edges; gradient `±1/pairs` per pair.
pub fn gradient_smoothness(map: &Image) -> LossGrad {
    assert_eq!(map.channels, 1, "gradient_smoothness takes a one-channel map");
    let (w, h) = (map.width, map.height);
    let pairs = ((w.saturating_sub(1)) * h + w * h.saturating_sub(1)).max(1) as f64;
    let mut grad = vec![0f64; w * h];
    let mut sum = 0f64;
    let mut pair = |i: usize, j: usize| {
        let d = map.data[i] as f64 - map.data[j] as f64;
        sum += d.abs();
        let s = d.signum() * (d != 0.0) as u8 as f64 / pairs;
        grad[i] += s;
        grad[j] -= s;
    };
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                pair(y * w + x, y * w + x + 1);
            }
            if y + 1 < h {
                pair(y * w + x, (y + 1) * w + x);
            }
        }
    }
    LossGrad { value: sum / pairs, grad: Image::from_vec(w, h, 1, grad.into_iter().map(|v| v as f32).collect()).expect("map size") }
}

fn assert_same_shape(a: &Image, b: &Image) {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels), "loss inputs differ in shape");
}

/// A summed-area table of one f64 plane, `(w + 1) × (h + 1)`.
struct Sat {
    w: usize,
    t: Vec<f64>,
}

impl Sat {
    fn new(w: usize, h: usize, f: impl Fn(usize) -> f64) -> Sat {
        let mut t = vec![0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut row = 0f64;
            for x in 0..w {
                row += f(y * w + x);
                t[(y + 1) * (w + 1) + x + 1] = t[y * (w + 1) + x + 1] + row;
            }
        }
        Sat { w, t }
    }

    /// Sum over the inclusive rectangle `[x0, x1] × [y0, y1]`.
    fn rect(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> f64 {
        let s = self.w + 1;
        self.t[(y1 + 1) * s + x1 + 1] - self.t[y0 * s + x1 + 1] - self.t[(y1 + 1) * s + x0] + self.t[y0 * s + x0]
    }

    /// Sum over the `k × k` box whose top-left corner is `(x, y)`.
    fn sum(&self, x: usize, y: usize, k: usize) -> f64 {
        self.rect(x, y, x + k - 1, y + k - 1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(w: usize, h: usize, c: usize, seed: u64) -> Image {
        let mut s = seed;
        Image::from_vec(
            w,
            h,
            c,
            (0..w * h * c)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 40) as f32 / (1u64 << 24) as f32
                })
                .collect(),
        )
        .unwrap()
    }

    /// Central differences of `f` in every value of `img` against `grad`.
    fn check(img: &Image, f: impl Fn(&Image) -> f64, grad: &Image, what: &str) {
        let scale = grad.data.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
        for k in 0..img.data.len() {
            let (mut up, mut down) = (img.clone(), img.clone());
            up.data[k] += 1e-3;
            down.data[k] -= 1e-3;
            let fd = (f(&up) - f(&down)) / (up.data[k] as f64 - down.data[k] as f64);
            let g = grad.data[k] as f64;
            assert!((fd - g).abs() <= 1e-3 * fd.abs().max(1e-2 * scale), "{what}[{k}]: fd {fd:e} vs {g:e}");
        }
    }

    #[test]
    fn ssim_gradient_matches_differences() {
        let (a, b) = (random(9, 7, 2, 1), random(9, 7, 2, 2));
        for k in [3usize, 5, 7] {
            let lg = ssim(&a, &b, k).unwrap();
            check(&a, |x| ssim(x, &b, k).unwrap().value, &lg.grad, "ssim");
        }
        assert!(ssim(&a, &b, 9).is_none());
        assert!(ssim(&a, &a, 3).unwrap().value.abs() < 1e-12);
        let h = hssim(&a, &b, &HSSIM_WINDOWS);
        check(&a, |x| hssim(x, &b, &HSSIM_WINDOWS).value, &h.grad, "hssim");
    }

    #[test]
    fn l1_and_smoothness_gradients() {
        let (a, b) = (random(5, 4, 3, 3), random(5, 4, 3, 4));
        let lg = l1(&a, &b);
        check(&a, |x| l1(x, &b).value, &lg.grad, "l1");
        let d = random(6, 5, 1, 5);
        let lg = gradient_smoothness(&d);
        check(&d, |x| gradient_smoothness(x).value, &lg.grad, "smoothness");
        let flat = Image::filled(4, 4, 1, 0.3);
        assert_eq!(gradient_smoothness(&flat).value, 0.0);
    }

    /// The smoothness prior is a mean over every horizontal and vertical neighbour pair: a
    /// 3x2 map with one unit step between its last two columns has 7 pairs, 2 across the
    /// step, so the loss is 2/7 and each pixel at the step is pulled by 1/7 per pair (finite
    /// differences cannot see the normalization: value and gradient share it).
    #[test]
    fn smoothness_is_the_mean_over_neighbour_pairs() {
        let map = Image::from_vec(3, 2, 1, vec![0.0, 0.0, 1.0, 0.0, 0.0, 1.0]).unwrap();
        let lg = gradient_smoothness(&map);
        assert!((lg.value - 2.0 / 7.0).abs() < 1e-12, "{}", lg.value);
        let s = (1.0f64 / 7.0) as f32;
        assert_eq!(lg.grad.data, [0.0, -s, s, 0.0, -s, s]);
        // Taller than two rows, the step at the last pixel: 3 + 4 pairs, 2 across it.
        let tall = Image::from_vec(2, 3, 1, vec![0.0, 0.0, 0.0, 0.0, 0.0, 1.0]).unwrap();
        let lg = gradient_smoothness(&tall);
        assert!((lg.value - 2.0 / 7.0).abs() < 1e-12, "{}", lg.value);
        assert_eq!(lg.grad.data, [0.0, 0.0, 0.0, -s, -s, 2.0 * s]);
        // A column and a row: pairs along the one side only.
        let col = Image::from_vec(1, 3, 1, vec![0.0, 2.0, 2.0]).unwrap();
        assert!((gradient_smoothness(&col).value - 1.0).abs() < 1e-12);
        let row = Image::from_vec(3, 1, 1, vec![0.0, 0.0, 3.0]).unwrap();
        assert!((gradient_smoothness(&row).value - 1.5).abs() < 1e-12);
    }

    /// A clipped sample bounds the render from below only; unclipped samples compare both ways.
    #[test]
    fn censor_takes_a_clipped_sample_as_a_lower_bound() {
        let render = Image::from_vec(4, 1, 1, vec![3.0, 0.5, 3.0, 0.2]).unwrap();
        let target = Image::from_vec(4, 1, 1, vec![1.0, 1.0, 0.9, 0.9]).unwrap();
        let clipped = Image::from_vec(4, 1, 1, vec![1.0, 0.25, 0.0, 0.0]).unwrap();
        let (seen, passed) = censor(&render, &target, &clipped);
        // Brighter than a clipped sample: no error. Darker than one (even partly clipped): an
        // error. Unclipped: the render as it is, brighter or darker.
        assert_eq!(seen.data, [1.0, 0.5, 3.0, 0.2]);
        assert_eq!(passed, [false, true, true, true]);
        assert!((l1(&seen, &target).value - (0.0 + 0.5 + 2.1 + 0.7) / 4.0).abs() < 1e-6);
        // Nothing clipped: the render unchanged.
        let none = Image::new(4, 1, 1);
        assert_eq!(censor(&render, &target, &none).0, render);
    }
}
