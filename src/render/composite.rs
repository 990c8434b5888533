//! Front-to-back compositing of rendered layers (eq. 2).

use super::RawLayer;
use crate::image::Image;

/// The official compositing epsilon: keeps an empty layer (W = 0) at exactly 0, never NaN.
pub const EPS: f32 = 1e-8;

/// `out = Σ_l C_l·V_l·Π_{k<l}(1 - V_k)` with `C_l = ΣRGB_l / (W_l + ε)`, layers front first.
///
/// As in the official code there is no renormalisation by the remaining transmittance, and a
/// pixel whose layers all have zero weight is black. Returns linear RGB (3 channels).
pub fn composite(raws: &[RawLayer]) -> Image {
    let (w, h) = (raws[0].width(), raws[0].height());
    let mut out = Image::new(w, h, 3);
    for (i, px) in out.data.chunks_exact_mut(3).enumerate() {
        let mut t = 1f32;
        for raw in raws {
            let r = raw.pixel(i);
            let (weight, vis) = (r[3], r[4]);
            let cover = t * vis;
            for c in 0..3 {
                px[c] += r[c] / (weight + EPS) * cover;
            }
            t *= 1.0 - vis;
        }
    }
    out
}
