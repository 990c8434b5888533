//! Background inpainting with a model (LaMa-style: image + binary mask → image), behind the
//! same interface as the classical Telea stage ([`super::background::inpaint_background`]).
//!
//! The region to fill is the classical one (alpha > threshold, dilated). A dynamic-size model
//! sees the whole image (shrunk to its `max_side` if needed); a fixed-size model sees the
//! mask's bounding box plus context, resized to its size, and the result is resized back.
//! Only masked pixels are replaced, with a feathered seam of `feather` pixels outside the mask.
//! The disparity behind the foreground is Telea-filled, or (`depth = "model"`) filled by the
//! same model on the disparity replicated to three channels, as the official pipeline does.

use super::background::{Background, InpaintOptions};
use super::inpaint::{TeleaOptions, inpaint_telea};
use super::mask::distance_to;
use crate::error::Result;
use crate::image::Image;
use crate::onnx::contract::SizeSpec;
use crate::onnx::{self, DepthFill, ModelKind, OnnxConfig, OnnxReport};
use crate::timing::ms_since;
use std::time::Instant;

/// The rectangle (x0, y0, w, h) the model works on: the whole image for a dynamic-size model,
/// else the mask's bounding box grown by `context` × its larger side (at least 16 px) on every
/// side, clipped to the image. `None` when the mask is empty.
pub fn region(mask: &[bool], w: usize, h: usize, fixed_size: bool, context: f32) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0usize, 0usize);
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let (x, y) = (i % w, i / w);
        x0 = x0.min(x);
        y0 = y0.min(y);
        x1 = x1.max(x);
        y1 = y1.max(y);
    }
    if x0 == usize::MAX {
        return None;
    }
    if !fixed_size {
        return Some((0, 0, w, h));
    }
    let side = (x1 - x0 + 1).max(y1 - y0 + 1) as f32;
    let m = (context * side).max(16.0).ceil() as usize;
    let (ax, ay) = (x0.saturating_sub(m), y0.saturating_sub(m));
    let (bx, by) = ((x1 + m).min(w - 1), (y1 + m).min(h - 1));
    Some((ax, ay, bx - ax + 1, by - ay + 1))
}

/// Blend weight of the model's result at distance `d` from the mask (0 inside): 1 inside,
/// falling linearly to 0 at `feather + 1` pixels outside.
pub fn seam_weight(d: f32, feather: f32) -> f32 {
    if d <= 0.0 { 1.0 } else { (1.0 - d / (feather + 1.0)).max(0.0) }
}

/// Pastes `filled` (the region's size) into `dst` at (x0, y0) with seam weights; `dist` is
/// the distance to the mask over the region.
fn paste(dst: &mut Image, filled: &Image, x0: usize, y0: usize, dist: &[f32], feather: f32) {
    let c = dst.channels;
    for y in 0..filled.height {
        for x in 0..filled.width {
            let (gx, gy) = (x0 + x, y0 + y);
            let wgt = seam_weight(dist[y * filled.width + x], feather);
            if wgt <= 0.0 {
                continue;
            }
            let i = dst.index(gx, gy);
            let j = (y * filled.width + x) * c;
            for k in 0..c {
                dst.data[i + k] = dst.data[i + k] * (1.0 - wgt) + filled.data[j + k] * wgt;
            }
        }
    }
}

/// A fill (model space: sRGB in [0, 1] once `output_range` is mapped) is implausible when it
/// is almost black while the photo is not (the raw output never reaches 2% of the declared
/// range: typically a model giving [0, 1] declared as [0, 255]) or far above the range (the
/// opposite mistake). Returns the warning's text, naming the declared range and what the
/// model gave.
pub fn implausible_fill(fill: &Image, photo: &Image, [lo, hi]: [f32; 2]) -> Option<String> {
    let max = |img: &Image| img.data.iter().copied().filter(|v| v.is_finite()).fold(f32::NEG_INFINITY, f32::max);
    let (got, seen) = (max(fill), max(photo));
    let raw = lo + got * (hi - lo);
    let fix = "check the model's output_range in [inpaint.onnx]";
    if got < 0.02 && seen > 0.2 {
        return Some(format!(
            "the inpainting model's output never exceeds {raw} while its declared output range is [{lo}, {hi}]: the fill is almost black; {fix}"
        ));
    }
    (got > 4.0).then(|| {
        format!(
            "the inpainting model's output reaches {raw}, far above its declared output range [{lo}, {hi}]: the fill is blown out; {fix}"
        )
    })
}

/// Inpaints colour (and disparity) behind the foreground with the `[inpaint.onnx]` model.
/// Returns the same [`Background`] as the classical stage, plus the model report.
pub fn inpaint_background(
    rgb: &Image,
    disp: &Image,
    alpha: &Image,
    opts: &InpaintOptions,
    reach: super::background::Reach,
    (ramp_outside, shown): (f32, super::background::BandReach),
    cfg: &OnnxConfig,
) -> Result<(Background, OnnxReport)> {
    let (w, h) = (rgb.width, rgb.height);
    let fill = super::background::fill_region(rgb, alpha, opts, ramp_outside, shown);
    let reach = fill.reach(alpha, reach);
    let stats = (fill.band, fill.band_replaced, fill.highlights_kept);
    // The model sees kept highlights as holes too (so it copies none into the hidden region);
    // they are put back after the paste.
    let mask = fill.colour_holes();
    let mut model = onnx::load(&opts.onnx, ModelKind::Inpaint, cfg)?;
    let mut rgb_out = rgb.clone();
    let mut disp_out = disp.clone();
    let total = mask.iter().filter(|&&m| m).count();
    let fixed = model.binding.fixed.is_some() || matches!(model.contract.size, SizeSpec::Fixed { .. });
    let Some((x0, y0, cw, ch)) = region(&mask, w, h, fixed, model.contract.context) else {
        let bg = Background::new(rgb_out, disp_out, fill.mask, 0, stats, reach);
        return Ok((bg, model.report));
    };
    let t = Instant::now();
    let mask_img = Image::from_vec(w, h, 1, mask.iter().map(|&m| m as u8 as f32).collect()).expect("mask size");
    let crop_mask = mask_img.crop(x0, y0, cw, ch);
    let crop_rgb = onnx::to_model_rgb(&rgb.crop(x0, y0, cw, ch));
    // Every masked pixel is inside the region, so the distance field of the region's mask is
    // exact there.
    let dist = distance_to(&crop_mask.data.iter().map(|&m| m > 0.5).collect::<Vec<_>>(), cw, ch);
    let feather = model.contract.feather;
    model.report.pre_ms += ms_since(t);

    let mut filled = model.predict_with_mask(&crop_rgb, Some(&crop_mask), 3)?;
    if let Some(w) = implausible_fill(&filled, &crop_rgb, model.contract.output_range) {
        model.report.warnings.push(format!("{}: {w}", model.path.display()));
    }
    let t = Instant::now();
    onnx::from_model_rgb(&mut filled.data);
    paste(&mut rgb_out, &filled, x0, y0, &dist, feather);
    model.report.post_ms += ms_since(t);

    fill.restore_highlights(&mut rgb_out, rgb);
    let completed = super::background::complete_highlights(&mut rgb_out, rgb, &fill, opts);
    let mask = fill.mask;
    match model.contract.depth {
        DepthFill::Telea => {
            let topts = TeleaOptions { max_distance: Some(reach), ..TeleaOptions::new(opts.radius) };
            inpaint_telea(&mut disp_out, &fill.depth_mask, topts)?;
        }
        DepthFill::Model => {
            let t = Instant::now();
            let d = disp.crop(x0, y0, cw, ch);
            let d3 = Image::stack(&[&d, &d, &d]);
            model.report.pre_ms += ms_since(t);
            let out = model.predict_with_mask(&d3, Some(&crop_mask), 3)?;
            let t = Instant::now();
            let mean = Image::from_vec(cw, ch, 1, out.data.chunks_exact(3).map(|p| (p[0] + p[1] + p[2]) / 3.0).collect()).expect("size");
            paste(&mut disp_out, &mean, x0, y0, &dist, feather);
            model.report.post_ms += ms_since(t);
        }
    }
    disp_out.map_inplace(|v| v.clamp(0.0, 1.0));
    let mut bg = Background::new(rgb_out, disp_out, mask, total, stats, reach);
    bg.highlights_completed = completed;
    Ok((bg, model.report))
}

/// Which implementation fills the background (`[inpaint] method`, `--inpaint`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum InpaintMethod {
    /// Telea fast-marching inpainting (classical, no model).
    #[default]
    Telea,
    /// The `[inpaint.onnx]` model.
    Onnx,
    /// Telea, then an exemplar (PatchMatch) fill of the colour within reach
    /// ([`super::patchmatch`]); disparity stays Telea's.
    PatchMatch,
}
