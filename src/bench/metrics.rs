//! Image-comparison metrics of the paper's evaluation: RMSE, scale-invariant RMSE, PSNR, SSIM
//! and ZNCC. All take two images of equal shape (any channel count) and an optional `border`
//! in pixels that is left out (frame borders, where the input lacks off-frame content).
//! Sums run in f64.

use crate::color::linear_to_srgb;
use crate::image::Image;

/// Values of `a` and `b` inside the frame minus `border` pixels, in matching order.
fn cropped<'a>(a: &'a Image, b: &'a Image, border: usize) -> impl Iterator<Item = (f64, f64)> + 'a {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels), "metric: shape mismatch");
    let (w, h, c) = (a.width, a.height, a.channels);
    let (x0, x1) = (border.min(w), w.saturating_sub(border).max(border.min(w)));
    let (y0, y1) = (border.min(h), h.saturating_sub(border).max(border.min(h)));
    (y0..y1).flat_map(move |y| {
        let row = y * w * c;
        (row + x0 * c..row + x1 * c).map(move |i| (a.data[i] as f64, b.data[i] as f64))
    })
}

/// Root mean square error.
pub fn rmse(a: &Image, b: &Image, border: usize) -> f64 {
    let (mut s, mut n) = (0f64, 0usize);
    for (x, y) in cropped(a, b, border) {
        s += (x - y) * (x - y);
        n += 1;
    }
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

/// RMSE after the best scalar gain `g` on `a` (`min_g ||g·a − b||`): insensitive to exposure.
pub fn si_rmse(a: &Image, b: &Image, border: usize) -> f64 {
    let (mut ab, mut aa, mut bb, mut n) = (0f64, 0f64, 0f64, 0usize);
    for (x, y) in cropped(a, b, border) {
        ab += x * y;
        aa += x * x;
        bb += y * y;
        n += 1;
    }
    if n == 0 {
        return 0.0;
    }
    let g = if aa > 0.0 { ab / aa } else { 0.0 };
    ((bb - 2.0 * g * ab + g * g * aa).max(0.0) / n as f64).sqrt()
}

/// PSNR in dB for a signal peak of `peak` (1 for [0, 1] images). Identical images give +inf.
pub fn psnr(a: &Image, b: &Image, peak: f64, border: usize) -> f64 {
    let e = rmse(a, b, border);
    if e == 0.0 { f64::INFINITY } else { 20.0 * (peak / e).log10() }
}

/// Zero-normalized cross-correlation over all values, in [-1, 1] (1 = identical up to gain
/// and offset). 0 when either image is constant.
pub fn zncc(a: &Image, b: &Image, border: usize) -> f64 {
    let v: Vec<(f64, f64)> = cropped(a, b, border).collect();
    let n = v.len().max(1) as f64;
    let (ma, mb) = (v.iter().map(|p| p.0).sum::<f64>() / n, v.iter().map(|p| p.1).sum::<f64>() / n);
    let (mut cov, mut va, mut vb) = (0f64, 0f64, 0f64);
    for (x, y) in v {
        cov += (x - ma) * (y - mb);
        va += (x - ma) * (x - ma);
        vb += (y - mb) * (y - mb);
    }
    if va == 0.0 || vb == 0.0 { 0.0 } else { cov / (va * vb).sqrt() }
}

/// Rec. 709 luminance of an RGB image (one channel); a one-channel image is returned as is.
pub fn luminance(img: &Image) -> Image {
    if img.channels == 1 {
        return img.clone();
    }
    let data = img.data.chunks_exact(img.channels).map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]).collect();
    Image::from_vec(img.width, img.height, 1, data).expect("size")
}

/// Mean SSIM (Wang et al. 2004) on luminance: 11×11 Gaussian window (σ = 1.5),
/// K1 = 0.01, K2 = 0.03, dynamic range `peak`; windows are evaluated where they fit inside
/// the frame minus `border`. Identical images give 1.
pub fn ssim(a: &Image, b: &Image, peak: f64, border: usize) -> f64 {
    let (la, lb) = (luminance(a), luminance(b));
    let (w, h) = (la.width, la.height);
    const R: usize = 5;
    let g: Vec<f64> = (0..=2 * R).map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
    let gs: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / gs).collect();
    let (c1, c2) = ((0.01 * peak).powi(2), (0.03 * peak).powi(2));
    // Separable blur of a plane, valid region only.
    let blur = |f: &dyn Fn(usize) -> f64| -> (Vec<f64>, usize, usize) {
        if w < 2 * R + 1 || h < 2 * R + 1 {
            return (Vec::new(), 0, 0);
        }
        let (ow, oh) = (w - 2 * R, h - 2 * R);
        let mut tmp = vec![0f64; ow * h];
        for y in 0..h {
            for x in 0..ow {
                tmp[y * ow + x] = (0..=2 * R).map(|k| g[k] * f(y * w + x + k)).sum();
            }
        }
        let mut out = vec![0f64; ow * oh];
        for y in 0..oh {
            for x in 0..ow {
                out[y * ow + x] = (0..=2 * R).map(|k| g[k] * tmp[(y + k) * ow + x]).sum();
            }
        }
        (out, ow, oh)
    };
    let pa = |i: usize| la.data[i] as f64;
    let pb = |i: usize| lb.data[i] as f64;
    let (ma, ow, oh) = blur(&pa);
    if ow == 0 {
        return if la.data == lb.data { 1.0 } else { 0.0 };
    }
    let (mb, _, _) = blur(&pb);
    let (saa, _, _) = blur(&|i| pa(i) * pa(i));
    let (sbb, _, _) = blur(&|i| pb(i) * pb(i));
    let (sab, _, _) = blur(&|i| pa(i) * pb(i));
    let (mut sum, mut n) = (0f64, 0usize);
    let lo = border.saturating_sub(R);
    for y in lo..oh.saturating_sub(lo) {
        for x in lo..ow.saturating_sub(lo) {
            let i = y * ow + x;
            let (mua, mub) = (ma[i], mb[i]);
            let (va, vb, cov) = (saa[i] - mua * mua, sbb[i] - mub * mub, sab[i] - mua * mub);
            sum += ((2.0 * mua * mub + c1) * (2.0 * cov + c2)) / ((mua * mua + mub * mub + c1) * (va + vb + c2));
            n += 1;
        }
    }
    if n == 0 { 1.0 } else { sum / n as f64 }
}

/// sRGB-encodes a linear image, clipped to [0, 1].
pub fn srgb(img: &Image) -> Image {
    let mut o = img.clone();
    o.map_inplace(|v| linear_to_srgb(v.clamp(0.0, 1.0)));
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(w: usize, h: usize, seed: u64) -> Image {
        let mut s = seed;
        let data = (0..w * h * 3)
            .map(|_| {
                s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (s >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        Image::from_vec(w, h, 3, data).unwrap()
    }

    #[test]
    fn known_values() {
        let a = noise(32, 24, 1);
        assert_eq!(psnr(&a, &a, 1.0, 0), f64::INFINITY);
        assert!((ssim(&a, &a, 1.0, 0) - 1.0).abs() < 1e-12);
        assert!((zncc(&a, &a, 0) - 1.0).abs() < 1e-12);
        let mut b = a.clone();
        b.map_inplace(|v| v * 0.5);
        assert!(si_rmse(&b, &a, 0) < 1e-6);
        assert!((zncc(&a, &b, 0) - 1.0).abs() < 1e-9);
        // A uniform offset of 0.1 → RMSE 0.1 → PSNR 20 dB.
        let mut c = a.clone();
        c.map_inplace(|v| v + 0.1);
        assert!((psnr(&a, &c, 1.0, 0) - 20.0).abs() < 1e-4);
        let d = noise(32, 24, 2);
        assert!(ssim(&a, &d, 1.0, 0) < 0.2);
        // Borders are excluded.
        let mut e = a.clone();
        e.data[0] = 100.0;
        assert_eq!(rmse(&a, &e, 1), 0.0);
    }
}
