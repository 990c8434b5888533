//! Foreground colour at soft matte edges.
//!
//! A pixel the matte covers partly shows `C = α·F + (1 - α)·B`. Used as the foreground layer's
//! colour, `C` carries the background into the foreground: blurred, the subject's edge gets a
//! halo of background colour (issue 12: on the bench, the foreground layer's colour was the
//! largest error after the background fill). With the background colour `B` estimated behind
//! the subject (the inpainted background layer), the mix is solved for `F`; where `α` is small
//! that solution amplifies every error by `1/α`, so it is blended with the colour of the
//! nearest solid foreground, carried outwards by a Telea fill.

use super::inpaint::{TeleaOptions, inpaint_telea};
use crate::error::Result;
use crate::image::Image;
use rayon::prelude::*;

/// Alpha from which a pixel's colour is the foreground's own.
pub const SOLID_ALPHA: f32 = 0.98;
/// Below this alpha the unmixed colour gets no weight (the nearest solid colour is used);
/// above [`TRUST_ALPHA`] it gets all of it; linear in between.
pub const UNTRUSTED_ALPHA: f32 = 0.1;
/// See [`UNTRUSTED_ALPHA`].
pub const TRUST_ALPHA: f32 = 0.6;
/// How far (pixels) solid colour is carried outwards: mixed edges are a few pixels wide.
pub const CARRY_PX: f32 = 8.0;
/// Up to this alpha the background is the one unmixed from the photo; from
/// [`FILL_ALPHA`] on, the fill; linear in between.
pub const UNMIXED_BG_ALPHA: f32 = 0.1;
/// See [`UNMIXED_BG_ALPHA`]. The unmixed background amplifies an error of the carried
/// foreground colour by α/(1 - α), but the blend weight falls linearly to 0 here, so their
/// product stays below 0.4 of that error. Measured on bench seed 3 (20 scenes at 128x128),
/// pipeline PSNR sRGB / linear: 36.51 / 18.59 dB with 0.5, 36.95 / 19.27 with 0.7,
/// 37.37 / 19.95 with 0.9, 37.54 / 20.23 with 0.98 (a highlight half under a soft edge
/// keeps its light).
pub const FILL_ALPHA: f32 = SOLID_ALPHA;

/// The unmixed foreground colour of one pixel: `(C - (1 - α)·B)/α`, clamped at 0 (light is
/// never negative). `α` must be positive.
#[inline]
pub fn unmix(c: f32, b: f32, alpha: f32) -> f32 {
    ((c - (1.0 - alpha) * b) / alpha).max(0.0)
}

/// The foreground layer's colour on a window of the frame, where it differs from the photo:
/// the box of the visible (`α > 0`) pixels grown by two. Outside it the foreground colour is
/// the photo's (those pixels are transparent: only their alpha matters).
pub struct EdgeColour {
    /// The window's first column in the frame.
    pub x0: usize,
    /// The window's first row in the frame.
    pub y0: usize,
    /// The colour on the window (linear RGB, straight).
    pub rgb: Image,
}

impl EdgeColour {
    /// `frame` (a frame-sized image with at least 3 channels, colour first) with this window's
    /// colour written over its first three channels.
    pub fn paste_into(&self, frame: &mut Image) {
        let (c, cw) = (frame.channels, self.rgb.width);
        for (y, src) in self.rgb.data.chunks_exact(cw * 3).enumerate() {
            let i = frame.index(self.x0, self.y0 + y);
            for (dst, px) in frame.data[i..i + cw * c].chunks_exact_mut(c).zip(src.chunks_exact(3)) {
                dst[..3].copy_from_slice(px);
            }
        }
    }
}

/// Separates the photo `rgb` at the soft pixels of `alpha` (0 < α < [`SOLID_ALPHA`]) into the
/// foreground layer's colour (linear RGB, straight, not premultiplied; returned) and the
/// background's (`bg`, the filled background layer, corrected in place) as the module doc
/// says. Solid pixels keep the photo's colour; transparent pixels near the soft edge get the
/// carried solid colour (their colour only matters through rounding). Returns the foreground
/// colour and the number of soft pixels. Cost: [`carried_colour`] (which needs no background:
/// run it beside the background fill) then [`unmix_edges`], and a copy of the photo.
pub fn separate(rgb: &Image, alpha: &Image, bg: &mut Image, radius: f32) -> Result<(Image, usize)> {
    let (edge, changed) = unmix_edges(rgb, alpha, carried_colour(rgb, alpha, radius)?, bg);
    let mut out = rgb.clone();
    if let Some(e) = edge {
        e.paste_into(&mut out);
    }
    Ok((out, changed))
}

/// The first half of [`separate`]: the photo's colour with the solid pixels' colour carried
/// over the soft ones (Telea, up to [`CARRY_PX`]), on the visible pixels' box grown by one
/// ([`EdgeColour`]); None when there is nothing to separate (no soft pixel with α > 0, or no
/// solid colour to carry). Nothing outside the box is read but alpha. Cost: one Telea fill
/// over the soft pixels of the box; allocates the box's colour and masks.
pub fn carried_colour(rgb: &Image, alpha: &Image, radius: f32) -> Result<Option<EdgeColour>> {
    let (w, h) = (alpha.width, alpha.height);
    let visible: Vec<bool> = alpha.data.par_iter().map(|&a| a > 0.0).collect();
    // (A margin of 1 grows the box by two pixels: the carry's values depend on the box.)
    let Some((x0, y0, x1, y1)) = super::mask::grown_bbox(&visible, w, h, 1.0) else { return Ok(None) };
    drop(visible);
    let (cw, ch) = (x1 - x0, y1 - y0);
    let a = alpha.crop(x0, y0, cw, ch);
    let soft: Vec<bool> = a.data.iter().map(|&a| a < SOLID_ALPHA).collect();
    // Outside the box every pixel is soft (α = 0): with no solid pixel in it, none anywhere.
    if soft.iter().all(|&s| s) || !a.data.iter().any(|&a| a > 0.0 && a < SOLID_ALPHA) {
        return Ok(None);
    }
    let mut crop = rgb.crop(x0, y0, cw, ch);
    inpaint_telea(&mut crop, &soft, TeleaOptions { max_distance: Some(CARRY_PX), ..TeleaOptions::new(radius) })?;
    Ok(Some(EdgeColour { x0, y0, rgb: crop }))
}

/// The second half of [`separate`], given [`carried_colour`]'s answer: unmixes the soft pixels
/// (one pass over the window) and returns the foreground colour's window and the number of
/// soft pixels; without a carried colour, None (the photo's colour as it is).
pub fn unmix_edges(rgb: &Image, alpha: &Image, carried: Option<EdgeColour>, bg: &mut Image) -> (Option<EdgeColour>, usize) {
    let Some(mut edge) = carried else { return (None, 0) };
    let (w, cw) = (alpha.width, edge.rgb.width);
    let mut changed = 0;
    for (y, out) in edge.rgb.data.chunks_exact_mut(cw * 3).enumerate() {
        let row = (edge.y0 + y) * w + edge.x0;
        for (x, &a) in alpha.data[row..row + cw].iter().enumerate() {
            if !(a > 0.0 && a < SOLID_ALPHA) {
                continue;
            }
            let w_bg = ((FILL_ALPHA - a) / (FILL_ALPHA - UNMIXED_BG_ALPHA)).clamp(0.0, 1.0);
            let w_fg = ((a - UNTRUSTED_ALPHA) / (TRUST_ALPHA - UNTRUSTED_ALPHA)).clamp(0.0, 1.0);
            for c in 0..3 {
                let (k, o) = ((row + x) * 3 + c, x * 3 + c);
                let carried = out[o];
                // 1 - α ≥ 1 - SOLID_ALPHA here: the division is bounded.
                let b_mix = ((rgb.data[k] - a * carried) / (1.0 - a)).max(0.0);
                bg.data[k] = w_bg * b_mix + (1.0 - w_bg) * bg.data[k];
                out[o] = w_fg * unmix(rgb.data[k], bg.data[k], a) + (1.0 - w_fg) * carried;
            }
            changed += 1;
        }
    }
    (Some(edge), changed)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_soft_edge_is_separated() {
        // Red foreground over green background, alpha ramping 1 → 0 across x = 3..8.
        let (w, h) = (12, 6);
        let (f, b) = ([0.8, 0.1, 0.1], [0.1, 0.6, 0.2]);
        let mut rgb = Image::new(w, h, 3);
        let mut alpha = Image::new(w, h, 1);
        let mut bg = Image::from_vec(w, h, 3, (0..w * h).flat_map(|_| b).collect()).unwrap();
        for y in 0..h {
            for x in 0..w {
                let a = (1.0 - (x as f32 - 3.0) / 5.0).clamp(0.0, 1.0);
                alpha.data[y * w + x] = a;
                for k in 0..3 {
                    rgb.pixel_mut(x, y)[k] = a * f[k] + (1.0 - a) * b[k];
                }
            }
        }
        let (out, changed) = separate(&rgb, &alpha, &mut bg, 5.0).unwrap();
        assert_eq!(changed, 4 * h);
        for y in 0..h {
            for x in 0..8 {
                for k in 0..3 {
                    assert!((out.pixel(x, y)[k] - f[k]).abs() < 1e-4, "F({x},{y})[{k}] = {}", out.pixel(x, y)[k]);
                    assert!((bg.pixel(x, y)[k] - b[k]).abs() < 1e-4, "B({x},{y})[{k}] = {}", bg.pixel(x, y)[k]);
                }
            }
        }
    }
}
