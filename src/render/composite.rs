//! Front-to-back compositing of rendered layers (eq. 2).
//!
//! One rule, [`over`], serves both the whole-image [`composite`] of stored raw layers and the
//! streaming compositor the renderer uses (layers rendered one after another straight into an
//! RGB + transmittance accumulator, so no raw layer is ever stored whole).

use super::RawLayer;
use crate::image::Image;
use rayon::prelude::*;

/// Channels of a streaming accumulator pixel: linear R, G, B so far and the transmittance
/// `Π(1 - V_k)` of the layers composited so far.
pub const ACC_CHANNELS: usize = 4;

/// Adds one layer's raw pixel `[ΣR, ΣG, ΣB, W, o]` behind what `acc = [R, G, B, T]` holds.
///
/// `C = ΣRGB / W`, clamped to the layer's colour range `range`, weighted by `T·o`; then
/// `T *= 1 - o`. As in the official code there is no renormalisation by the remaining
/// transmittance, and a layer with zero weight at a pixel contributes nothing there (a pixel
/// whose layers all have zero weight is black). The official code divides by `W + 1e-8`
/// instead; that epsilon darkens layers whose weights are legitimately tiny (huge blur:
/// weights ∝ 1/σ²), so here `C` is the plain ratio, clamped: it is a weighted mean of the
/// layer's colours, and the clamp only removes rounding (and a fast kernel's cancellation
/// noise where `W` is close to 0).
#[inline]
pub fn over(raw: &[f32], range: &[[f32; 2]; 3], acc: &mut [f32]) {
    let (weight, vis) = (raw[super::raw::WEIGHT], raw[super::raw::VISIBILITY]);
    let t = acc[3];
    let cover = t * vis;
    // A NaN weight (a kernel bug) is carried into the result, never dropped as "no light":
    // the renderer refuses non-finite output rather than writing a black pixel.
    if (weight > 0.0 || weight.is_nan()) && cover > 0.0 {
        for c in 0..3 {
            acc[c] += (raw[c] / weight).clamp(range[c][0], range[c][1]) * cover;
        }
    }
    acc[3] = t * (1.0 - vis);
}

/// A fresh streaming accumulator: black, transmittance 1. `width * height * 4` f32.
pub fn accumulator(width: usize, height: usize) -> Vec<f32> {
    let mut acc = vec![0f32; width * height * ACC_CHANNELS];
    acc.par_chunks_exact_mut(ACC_CHANNELS).for_each(|px| px[3] = 1.0);
    acc
}

/// Turns a streaming accumulator into the linear RGB image in place: each pixel moves to a
/// lower or equal offset, so no second full-size buffer is needed at the render's memory
/// peak (12 bytes per pixel saved).
///
/// In parallel rounds: pixel `i` moves from `ACC_CHANNELS·i` to `3·i`, so a round that moves
/// the pixels `[a, b)` with `3·b ≤ ACC_CHANNELS·a` writes only where earlier rounds have
/// already read, and its copies are independent. The rounds grow by `ACC_CHANNELS / 3`: ~35
/// at 12 MP, where a serial copy was ~30 ms of one core (issue 39).
pub fn finish(width: usize, height: usize, mut acc: Vec<f32>) -> Image {
    let n = width * height;
    // The first pixels, serially (a round from `a = 0` would be empty).
    let first = n.min(FIRST_ROUND);
    for i in 0..first {
        acc.copy_within(i * ACC_CHANNELS..i * ACC_CHANNELS + 3, i * 3);
    }
    let mut a = first;
    while a < n {
        let b = n.min(a * ACC_CHANNELS / 3);
        let (head, tail) = acc.split_at_mut(a * ACC_CHANNELS);
        head[3 * a..3 * b]
            .par_chunks_exact_mut(3 * FIRST_ROUND)
            .zip(tail[..(b - a) * ACC_CHANNELS].par_chunks(ACC_CHANNELS * FIRST_ROUND))
            .for_each(|(dst, src)| {
                dst.chunks_exact_mut(3).zip(src.chunks_exact(ACC_CHANNELS)).for_each(|(d, s)| d.copy_from_slice(&s[..3]))
            });
        // `par_chunks_exact_mut` leaves the round's last partial block: copied here.
        let done = a + (b - a) / FIRST_ROUND * FIRST_ROUND;
        for i in done..b {
            acc.copy_within(i * ACC_CHANNELS..i * ACC_CHANNELS + 3, i * 3);
        }
        a = b;
    }
    acc.truncate(n * 3);
    acc.shrink_to_fit();
    Image::from_vec(width, height, 3, acc).expect("accumulator size")
}

/// Pixels of [`finish`]'s serial first round, and of each parallel task.
const FIRST_ROUND: usize = 4096;

/// `out = Σ_l C_l·V_l·Π_{k<l}(1 - V_k)` with `C_l = ΣRGB_l / W_l`, layers front first (see
/// [`over`]). Returns linear RGB (3 channels).
pub fn composite(raws: &[RawLayer]) -> Image {
    let (w, h) = (raws[0].width(), raws[0].height());
    let mut acc = accumulator(w, h);
    for raw in raws {
        let range = raw.colour_range();
        acc.par_chunks_exact_mut(ACC_CHANNELS).enumerate().for_each(|(i, px)| over(raw.pixel(i), &range, px));
    }
    finish(w, h, acc)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel rounds move every pixel where the plain serial loop does: sizes below the
    /// first round, at its boundary, and over many rounds with partial blocks.
    #[test]
    fn finish_keeps_every_pixel() {
        for (w, h) in [(1, 1), (64, 64), (4096, 1), (4097, 1), (301, 257), (1000, 333)] {
            let acc: Vec<f32> = (0..w * h * ACC_CHANNELS).map(|k| k as f32).collect();
            let want: Vec<f32> = acc.chunks_exact(ACC_CHANNELS).flat_map(|p| p[..3].to_vec()).collect();
            let got = finish(w, h, acc);
            assert_eq!((got.width, got.height, got.channels), (w, h, 3));
            assert!(got.data == want, "{w}x{h}");
        }
    }
}
