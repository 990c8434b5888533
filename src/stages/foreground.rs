//! Foreground colour at soft matte edges.
//!
//! A pixel the matte covers partly shows `C = α·F + (1 - α)·B`. Used as the foreground layer's
//! colour, `C` carries the background into the foreground: blurred, the subject's edge gets a
//! halo of background colour (issue 12: on the bench, the foreground layer's colour was the
//! largest error after the background fill). Two guesses are at hand: the colour of the
//! nearest solid foreground, carried outwards by a Telea fill, and the background filled behind
//! the subject. [`split`] corrects both by what the photo shows, in proportion to how far each
//! can be off, and keeps the foreground within its solid neighbours' colours: the light of a
//! highlight half hidden behind the edge, which the fill cannot know, stays in the background.
use super::inpaint::{TeleaOptions, inpaint_telea};
use crate::error::Result;
use crate::image::Image;
use rayon::prelude::*;

/// Alpha from which a pixel's colour is the foreground's own.
pub const SOLID_ALPHA: f32 = 0.98;
/// How far (pixels) solid colour is carried outwards: mixed edges are a few pixels wide.
pub const CARRY_PX: f32 = 8.0;
/// Spread of the foreground's colour around the carried one, relative to it (see [`split`]).
pub const FG_SPREAD: f64 = 1.0;
/// Spread of the foreground's colour that does not scale with it (linear units).
pub const FG_FLOOR: f64 = 0.02;
/// Spread of the background's colour around the filled one, relative to the larger of the
/// fill and the pixel's own colour (a pixel brighter than the fill says the fill missed light).
pub const BG_SPREAD: f64 = 0.5;
/// Spread of the background's colour that does not scale with it (linear units).
pub const BG_FLOOR: f64 = 0.05;
/// Radius (pixels, a square window) of the solid neighbours whose colours bound a soft pixel's
/// foreground colour.
pub const RANGE_PX: usize = 3;
/// How far (linear units) a soft pixel's foreground colour may exceed its solid neighbours'.
pub const RANGE_MARGIN: f32 = 0.05;
/// Spread (linear units) of the foreground's colour around that bound once it is exceeded.
pub const HELD_SPREAD: f64 = 0.1;

/// Splits one channel of a soft pixel, `c = α·F + (1 - α)·B`, into the foreground's colour `F`
/// and the background's `B` (both linear, straight), given the colour carried from the nearest
/// solid foreground `f0`, the filled background `b0`, and the brightest colour of the solid
/// neighbours plus [`RANGE_MARGIN`] when there are any (see [`solid_max`]).
///
/// The two estimates are corrected by the residual `r = c - α·f0 - (1 - α)·b0`, shared in
/// proportion to their uncertainty (the least-squares answer with Gaussian priors on `F` and
/// `B`, spreads [`FG_SPREAD`]·f0 + [`FG_FLOOR`] and [`BG_SPREAD`]·max(b0, c) + [`BG_FLOOR`]):
/// the mix is kept exactly, near α = 1 the residual is the foreground's, near α = 0 the
/// background's. A foreground brighter than the bound is split again around the bound with
/// the tight spread [`HELD_SPREAD`], so most of the excess goes to `B`: the light of a
/// highlight half hidden behind the edge (which the fill cannot know) stays in the background
/// instead of making the subject's rim glow (issue 12). A hard clamp (to the neighbours' range,
/// or their maximum) moves α/(1 - α) times the excess into `B`: 16x for a nearly solid pixel
/// (α 0.94) whose texture exceeds its neighbours, -3.4 dB on one bench scene; the soft bound
/// scored best of the four forms on the tuning seeds 3-6 (20 scenes at 128x128 each). Both
/// results are clamped at 0 (light is never negative) and to the largest finite f32: finite
/// for every finite input with `0 < α < 1`.
pub fn split(c: f32, alpha: f32, f0: f32, b0: f32, bound: Option<f32>) -> (f32, f32) {
    let (c, a, f0, b0) = (c as f64, alpha as f64, f0 as f64, b0 as f64);
    // In f64: the variances of HDR values near f32's limit stay finite.
    let vb = (BG_SPREAD * b0.max(c) + BG_FLOOR).powi(2);
    let share = |f0: f64, vf: f64| {
        let r = c - a * f0 - (1.0 - a) * b0;
        // ≥ (1 - α)²·BG_FLOOR² > 0: bounded away from zero for α < 1.
        let den = a * a * vf + (1.0 - a) * (1.0 - a) * vb;
        (f0 + a * vf * r / den, b0 + (1.0 - a) * vb * r / den)
    };
    let (mut f, mut b) = share(f0, (FG_SPREAD * f0 + FG_FLOOR).powi(2));
    if let Some(hi) = bound.map(f64::from).filter(|&hi| f > hi) {
        (f, b) = share(hi, HELD_SPREAD * HELD_SPREAD);
    }
    let finite = |v: f64| v.clamp(0.0, f32::MAX as f64) as f32;
    (finite(f), finite(b))
}

/// The brightest colour (per channel, plus [`RANGE_MARGIN`]) of the solid pixels
/// (α ≥ [`SOLID_ALPHA`]) within [`RANGE_PX`] of `(x, y)` in the square sense; None when there
/// is none. Reads `(2·RANGE_PX + 1)²` pixels; allocates nothing.
pub fn solid_max(rgb: &Image, alpha: &Image, x: usize, y: usize) -> Option<[f32; 3]> {
    let (w, h) = (alpha.width, alpha.height);
    let mut hi = [f32::NEG_INFINITY; 3];
    let mut any = false;
    for yy in y.saturating_sub(RANGE_PX)..(y + RANGE_PX + 1).min(h) {
        let row = yy * w;
        for xx in x.saturating_sub(RANGE_PX)..(x + RANGE_PX + 1).min(w) {
            if alpha.data[row + xx] >= SOLID_ALPHA {
                any = true;
                for (m, v) in hi.iter_mut().zip(&rgb.data[(row + xx) * 3..(row + xx) * 3 + 3]) {
                    *m = m.max(*v);
                }
            }
        }
    }
    any.then(|| hi.map(|v| v + RANGE_MARGIN))
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
    // (A margin of 1 grows the box by two pixels: the carry's values depend on the box.)
    let Some((x0, y0, x1, y1)) = super::mask::visible_box(alpha, 1.0) else { return Ok(None) };
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

/// The second half of [`separate`], given [`carried_colour`]'s answer: [`split`]s the soft
/// pixels (rows of the window in parallel) and returns the foreground colour's window and the number of
/// soft pixels; without a carried colour, None (the photo's colour as it is).
pub fn unmix_edges(rgb: &Image, alpha: &Image, carried: Option<EdgeColour>, bg: &mut Image) -> (Option<EdgeColour>, usize) {
    let Some(mut edge) = carried else { return (None, 0) };
    let (w, cw, ch, x0, y0) = (alpha.width, edge.rgb.width, edge.rgb.height, edge.x0, edge.y0);
    let bg_rows = bg.data[y0 * w * 3..(y0 + ch) * w * 3].par_chunks_exact_mut(w * 3);
    let changed = edge
        .rgb
        .data
        .par_chunks_exact_mut(cw * 3)
        .zip(bg_rows)
        .enumerate()
        .map(|(y, (out, bg_row))| {
            let gy = y0 + y;
            let mut n = 0;
            for (x, &a) in alpha.data[gy * w + x0..gy * w + x0 + cw].iter().enumerate() {
                if !(a > 0.0 && a < SOLID_ALPHA) {
                    continue;
                }
                let bound = solid_max(rgb, alpha, x0 + x, gy);
                for c in 0..3 {
                    let (o, k) = (x * 3 + c, (x0 + x) * 3 + c);
                    let (f, b) = split(rgb.data[gy * w * 3 + k], a, out[o], bg_row[k], bound.map(|m| m[c]));
                    out[o] = f;
                    bg_row[k] = b;
                }
                n += 1;
            }
            n
        })
        .sum();
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

    /// A highlight behind the soft edge that the background fill knows nothing of (the fill is
    /// dark there): its light goes to the background, the rim stays near the subject's colour
    /// (the photo's colour there is 5-25x the subject's).
    #[test]
    fn a_highlight_behind_the_edge_stays_in_the_background() {
        let (w, h) = (14, 5);
        let (f, b, spot) = ([0.30, 0.05, 0.05], [0.1, 0.1, 0.1], 30.0);
        let mut rgb = Image::new(w, h, 3);
        let mut alpha = Image::new(w, h, 1);
        let mut truth = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let a = (1.0 - (x as f32 - 4.0) / 6.0).clamp(0.0, 1.0);
                alpha.data[y * w + x] = a;
                for k in 0..3 {
                    let bt = if (5..9).contains(&x) { spot } else { b[k] };
                    truth.pixel_mut(x, y)[k] = bt;
                    rgb.pixel_mut(x, y)[k] = a * f[k] + (1.0 - a) * bt;
                }
            }
        }
        let mut bg = Image::from_vec(w, h, 3, (0..w * h).flat_map(|_| b).collect()).unwrap();
        let (out, changed) = separate(&rgb, &alpha, &mut bg, 5.0).unwrap();
        assert_eq!(changed, 5 * h);
        for y in 0..h {
            for x in 5..9 {
                let a = alpha.data[y * w + x];
                for (k, fk) in f.iter().enumerate() {
                    let (fo, bo, bt) = (out.pixel(x, y)[k], bg.pixel(x, y)[k], truth.pixel(x, y)[k]);
                    assert!(fo <= fk + 0.3, "F({x},{y})[{k}] = {fo}");
                    assert!((bo - bt).abs() <= 0.05 * bt, "B({x},{y})[{k}] = {bo}, truth {bt}");
                    let mix = a * fo + (1.0 - a) * bo;
                    assert!((mix - rgb.pixel(x, y)[k]).abs() <= 1e-4 * mix, "light at ({x},{y}) {mix}");
                }
            }
        }
    }

    /// The split keeps the photo's light (α·F + (1 - α)·B = C) wherever neither result is
    /// clamped (at 0 or at the largest f32), and is finite and non-negative for every finite
    /// input, however extreme.
    #[test]
    fn the_split_keeps_the_light_and_stays_finite() {
        let values = [0.0, 1e-30, 1e-6, 0.02, 0.5, 1.0, 50.0, 6.5e4, 1e30, f32::MAX];
        let alphas = [1e-30, 1e-6, 0.01, 0.5, 0.9, SOLID_ALPHA - 1e-6];
        for &c in &values {
            for &a in &alphas {
                for &f0 in &values {
                    for &b0 in &values {
                        for bound in [None, Some(f0 + RANGE_MARGIN), Some(0.0), Some(f32::MAX)] {
                            let (f, b) = split(c, a, f0, b0, bound);
                            assert!(f.is_finite() && b.is_finite() && f >= 0.0 && b >= 0.0, "{c} {a} {f0} {b0}: {f} {b}");
                            let (cf, af) = (c as f64, a as f64);
                            let mix = af * f as f64 + (1.0 - af) * b as f64;
                            let unclamped = f > 0.0 && b > 0.0 && f < f32::MAX && b < f32::MAX;
                            // (Rounding scales with the largest value that enters the sums.)
                            let scale = cf.max(f0 as f64).max(b0 as f64).max(1e-3);
                            if unclamped && scale < 1e30 {
                                assert!((mix - cf).abs() <= 1e-5 * scale, "{c} {a} {f0} {b0}: mix {mix}");
                            }
                        }
                    }
                }
            }
        }
    }
}
