//! Front-to-back compositing of rendered layers (eq. 2).

use super::RawLayer;
use crate::image::Image;
use rayon::prelude::*;

/// `out = Σ_l C_l·V_l·Π_{k<l}(1 - V_k)` with `C_l = ΣRGB_l / W_l`, layers front first.
///
/// As in the official code there is no renormalisation by the remaining transmittance, and a
/// layer with zero weight at a pixel contributes nothing there (a pixel whose layers all have
/// zero weight is black). The official code divides by `W + 1e-8` instead; that epsilon
/// darkens layers whose weights are legitimately tiny (huge blur: weights ∝ 1/σ²), so here
/// `C` is the plain ratio, clamped to the layer's colour range: it is a weighted mean of those
/// colours, and the clamp only removes rounding (and a fast kernel's cancellation noise where
/// `W` is close to 0). Returns linear RGB (3 channels).
pub fn composite(raws: &[RawLayer]) -> Image {
    let (w, h) = (raws[0].width(), raws[0].height());
    let mut out = Image::new(w, h, 3);
    out.data.par_chunks_exact_mut(3).enumerate().for_each(|(i, px)| {
        let mut t = 1f32;
        for raw in raws {
            let r = raw.pixel(i);
            let (weight, vis) = (r[3], r[4]);
            let cover = t * vis;
            if weight > 0.0 && cover > 0.0 {
                let range = raw.colour_range();
                for c in 0..3 {
                    px[c] += (r[c] / weight).clamp(range[c][0], range[c][1]) * cover;
                }
            }
            t *= 1.0 - vis;
        }
    });
    out
}
