//! Background inpainting: colour and disparity behind the foreground.
//!
//! The background layer is opaque, so every pixel the foreground may hide (its soft edge
//! included, plus a margin for colour contamination at the edge) is re-synthesized from the
//! visible background with Telea inpainting, for RGB and disparity alike.

use super::inpaint::{TeleaOptions, inpaint_telea};
use super::mask::dilate;
use crate::error::Result;
use crate::image::Image;

/// `[inpaint]` options of the classical (Telea) background fill.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InpaintOptions {
    /// Alpha above which a pixel counts as (partly) covered by the foreground.
    pub threshold: f32,
    /// Grow the covered region by this many pixels: edge pixels carry foreground colour.
    pub dilate: f32,
    /// Telea neighbourhood radius, pixels.
    pub radius: f32,
    /// "telea" (this module) or "onnx" (the `[inpaint.onnx]` model, `stages::inpaint_onnx`).
    pub method: super::inpaint_onnx::InpaintMethod,
    /// `[inpaint.onnx]`: the model used by `method = "onnx"`.
    pub onnx: crate::onnx::ModelSpec,
}

impl Default for InpaintOptions {
    fn default() -> Self {
        InpaintOptions { threshold: 0.02, dilate: 3.0, radius: 5.0, method: Default::default(), onnx: Default::default() }
    }
}

/// The background layer's colour and disparity, and the work done.
pub struct Background {
    /// Background colour: the photo, inpainted under the foreground; linear RGB.
    pub rgb: Image,
    /// Background disparity: inpainted the same way, clamped to [0, 1].
    pub disparity: Image,
    /// The region that was (or would have been) inpainted.
    pub mask: Vec<bool>,
    /// Pixels inpainted.
    pub filled: usize,
    /// Pixels of the mask left as they were: too deep under the foreground for any blur to show.
    pub skipped: usize,
}

/// The pixels the background fill replaces: covered by the foreground (`alpha > threshold`),
/// grown by `dilate`.
pub fn inpaint_mask(alpha: &Image, opts: &InpaintOptions) -> Vec<bool> {
    let covered: Vec<bool> = alpha.data.iter().map(|&a| a > opts.threshold).collect();
    dilate(&covered, alpha.width, alpha.height, opts.dilate)
}

/// The region a background fill must cover, as a fast-marching reach from the visible
/// background: background values are seen through the foreground wherever its visibility is
/// below 1, i.e. within `see` pixels (visibility box plus a background scatter radius) of a
/// pixel whose alpha is below 1. Translucent pixels deep inside the mask (fur, glass) push the
/// reach inward accordingly. Computes the dilated mask and one distance transform.
pub fn fill_reach(alpha: &Image, opts: &InpaintOptions, see: f32) -> f32 {
    let (w, h) = (alpha.width, alpha.height);
    let mask = inpaint_mask(alpha, opts);
    // Every masked pixel's nearest outside pixel lies within the mask's box grown by 1.
    let Some(bb) = super::mask::grown_bbox(&mask, w, h, 1.0) else { return super::mask::marching_reach(see) };
    let outside: Vec<bool> = mask.iter().map(|&m| !m).collect();
    let to_outside = super::mask::distance_in(&outside, w, h, bb);
    let deep = to_outside.iter().zip(&alpha.data).filter(|(d, a)| d.is_finite() && **a < 1.0).map(|(&d, _)| d).fold(0.0, f32::max);
    super::mask::marching_reach(deep + see)
}

/// Inpaints `rgb` and `disp` under the dilated foreground, up to `reach` pixels from the
/// visible background (deeper pixels cannot be seen through any blur and keep their input).
pub fn inpaint_background(rgb: &Image, disp: &Image, alpha: &Image, opts: &InpaintOptions, reach: f32) -> Result<Background> {
    let mask = inpaint_mask(alpha, opts);
    let mut rgb_out = rgb.clone();
    let mut disp_out = disp.clone();
    let topts = TeleaOptions { max_distance: Some(reach), ..TeleaOptions::new(opts.radius) };
    let (filled, filled_disp) = rayon::join(|| inpaint_telea(&mut rgb_out, &mask, topts), || inpaint_telea(&mut disp_out, &mask, topts));
    let filled = filled?;
    filled_disp?;
    disp_out.map_inplace(|v| v.clamp(0.0, 1.0));
    let total = mask.iter().filter(|&&m| m).count();
    Ok(Background { rgb: rgb_out, disparity: disp_out, mask, filled, skipped: total.saturating_sub(filled) })
}
