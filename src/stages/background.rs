//! Background inpainting: colour and disparity behind the foreground.
//!
//! The background layer is opaque, so every pixel the foreground may hide (its soft edge
//! included, plus a margin for colour contamination at the edge) is re-synthesized from the
//! visible background with Telea inpainting, for RGB and disparity alike.

use super::inpaint::{inpaint_telea, TeleaOptions};
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
    pub rgb: Image,
    pub disparity: Image,
    /// The region that was (or would have been) inpainted.
    pub mask: Vec<bool>,
    pub filled: usize,
    pub skipped: usize,
}

/// Inpaints `rgb` and `disp` under the dilated foreground, up to `reach` pixels from the
/// visible background (deeper pixels cannot be seen through any blur and keep their input).
pub fn inpaint_background(rgb: &Image, disp: &Image, alpha: &Image, opts: &InpaintOptions, reach: f32) -> Result<Background> {
    let (w, h) = (rgb.width, rgb.height);
    let covered: Vec<bool> = alpha.data.iter().map(|&a| a > opts.threshold).collect();
    let mask = dilate(&covered, w, h, opts.dilate);
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
