//! Depth filling: extend the foreground layer's disparity beyond the foreground.
//!
//! A blurred foreground edge spreads over pixels where the photo shows the background; the
//! foreground layer needs its own (foreground) disparity there, or those pixels would scatter
//! as if they were far away. As in the official pipeline, the disparity inside a slightly
//! shrunk hard mask is kept and everything outside it is Telea-inpainted from it.

use super::inpaint::{inpaint_telea, TeleaOptions};
use super::mask::erode;
use crate::error::Result;
use crate::image::Image;

/// `[fill_depth]` options.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FillDepthOptions {
    /// Alpha above which a pixel is certainly foreground.
    pub threshold: f32,
    /// Shrink the hard mask by this many pixels first: edge pixels mix depths.
    pub erode: f32,
    /// Telea neighbourhood radius, pixels.
    pub radius: f32,
}

impl Default for FillDepthOptions {
    fn default() -> Self {
        FillDepthOptions { threshold: 0.5, erode: 2.0, radius: 5.0 }
    }
}

/// Result of the fill: the foreground layer's disparity and how much work was done.
pub struct FilledDepth {
    pub disparity: Image,
    /// Pixels whose disparity was inpainted.
    pub filled: usize,
    /// Pixels outside the foreground left as they were because no blur can reach them.
    pub skipped: usize,
}

/// Foreground disparity: `disp` inside the eroded mask `alpha > threshold`, inpainted outside
/// up to `reach` pixels away (beyond that the layer is invisible; those pixels keep `disp`).
pub fn foreground_disparity(disp: &Image, alpha: &Image, opts: &FillDepthOptions, reach: f32) -> Result<FilledDepth> {
    let (w, h) = (disp.width, disp.height);
    let hard: Vec<bool> = alpha.data.iter().map(|&a| a > opts.threshold).collect();
    let mut core = erode(&hard, w, h, opts.erode);
    if !core.iter().any(|&m| m) {
        // A foreground thinner than the erosion: keep its unshrunk pixels instead.
        core = hard;
    }
    let mut out = disp.clone();
    if !core.iter().any(|&m| m) {
        return Ok(FilledDepth { disparity: out, filled: 0, skipped: 0 });
    }
    let unknown: Vec<bool> = core.iter().map(|&m| !m).collect();
    let filled = inpaint_telea(&mut out, &unknown, TeleaOptions { max_distance: Some(reach), ..TeleaOptions::new(opts.radius) })?;
    out.map_inplace(|v| v.clamp(0.0, 1.0));
    let total = unknown.iter().filter(|&&u| u).count();
    Ok(FilledDepth { disparity: out, filled, skipped: total.saturating_sub(filled) })
}
