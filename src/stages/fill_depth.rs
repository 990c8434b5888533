//! Depth filling: extend the foreground layer's disparity beyond the foreground.
//!
//! A blurred foreground edge spreads over pixels where the photo shows the background; the
//! foreground layer needs its own (foreground) disparity there, or those pixels would scatter
//! as if they were far away. As in the official pipeline, the disparity inside a slightly
//! shrunk hard mask is kept and everything outside it is Telea-inpainted from it.

use super::inpaint::{TeleaOptions, inpaint_telea};
use super::mask::{BoxDistance, CAPPED_MAX, dilate, erode, visible_box};
use crate::error::Result;
use crate::image::Image;
use crate::render::lens::coc_radius;
use rayon::prelude::*;
use std::borrow::Cow;

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
    /// Whether depth edges softer than the matte's are measured and kept out of both layers.
    pub edges: DepthEdges,
}

impl Default for FillDepthOptions {
    fn default() -> Self {
        FillDepthOptions { threshold: 0.5, erode: 2.0, radius: 5.0, edges: DepthEdges::default() }
    }
}

/// How the stages treat a depth map whose edges are softer than the matte's
/// ([`super::depth_edges`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DepthEdges {
    /// Measure the ramp on each side of the outline; the foreground's disparity is taken from
    /// beyond it inside, the background's re-synthesized beyond it outside.
    #[default]
    Snapped,
    /// Trust the depth map up to `erode` pixels from the outline.
    AsGiven,
}

/// Result of the fill: the foreground layer's disparity and how much work was done.
pub struct FilledDepth {
    /// The foreground layer's disparity (one channel, normalized).
    pub disparity: Image,
    /// Pixels whose disparity was inpainted.
    pub filled: usize,
    /// Pixels outside the foreground that no blur can show: set to the core's disparity
    /// nearest the focus instead of being inpainted.
    pub skipped: usize,
    /// How far (pixels) from the core the fill reached.
    pub reach: f32,
    /// How far (pixels) outside its visible pixels the foreground layer can show: its largest
    /// visibility box half-size, plus one.
    pub visible_reach: f32,
    /// The shrink of the hard mask, pixels (`erode`), when the core is the shrunk mask.
    pub erode: f32,
    /// True when the core is where the ramp model solved the foreground's disparity
    /// ([`super::depth_edges::foreground_estimate`]) instead of the shrunk mask.
    pub ramp_model: bool,
    /// The value given to the pixels that no blur can show (`skipped`): the core's disparity
    /// nearest the focus; None when there is no core (the map is kept as given).
    pub quiet: Option<f32>,
}

/// The foreground's hard mask: `alpha > threshold`.
pub fn hard_mask(alpha: &Image, opts: &FillDepthOptions) -> Vec<bool> {
    alpha.data.par_iter().map(|&a| a > opts.threshold).collect()
}

/// The pixels whose disparity is trusted: `hard` shrunk by `erode` pixels (its edge pixels mix
/// depths), except that parts thinner than the erosion (bars, wires) keep their pixels instead
/// of vanishing: without them a thin part would take the disparity of the nearest thick part,
/// however far. A thin part is a hard pixel farther than `erode + 1` from the shrunk mask.
pub fn core_of(hard: &[bool], w: usize, h: usize, erode_px: f32) -> Vec<bool> {
    let mut core = erode(hard, w, h, erode_px);
    if erode_px <= 0.0 {
        return core;
    }
    let near = dilate(&core, w, h, erode_px + 1.0);
    core.par_iter_mut().zip(hard).zip(&near).for_each(|((c, &hd), &n)| *c = *c || (hd && !n));
    core
}

/// Foreground disparity: `disp` inside the eroded mask `alpha > threshold` (the core),
/// Telea-inpainted outside it as far as a blur can show the result, and clamped to the core's
/// disparity range (the foreground extended, not extrapolated past its own depths).
///
/// Why the fill can stop: a pixel of the foreground layer that is not visible (alpha 0) only
/// matters through its visibility (eq. 4), the mean alpha over a box of half-size σ/2 sized by
/// its own disparity. With every disparity in the core's range `[lo, hi]`, that box is at most
/// `r = trunc((max|D - focus|·K + 1)/2)` pixels, so only pixels within `r` of a visible pixel
/// can show the layer. The fill covers those (measured from the core: the farthest visible
/// pixel's distance plus `r`, with a margin for the fast-marching metric); every pixel beyond
/// gets the core disparity nearest the focus, which keeps its box small and its value unseen.
///
/// `ramp` is the measured soft depth edge ([`super::depth_edges`]): with a ramp, the core is
/// where the foreground's own disparity can be solved from the smoothed map
/// ([`super::depth_edges::foreground_estimate`]), with those values.
pub fn foreground_disparity(
    disp: &Image,
    alpha: &Image,
    opts: &FillDepthOptions,
    (focus, blur): (f32, f32),
    ramp: &super::depth_edges::EdgeWidths,
) -> Result<FilledDepth> {
    let (w, h) = (disp.width, disp.height);
    let hard = hard_mask(alpha, opts);
    let erode = opts.erode;
    let (disp, core, ramp_model) = match super::depth_edges::foreground_estimate(disp, alpha, ramp, opts.radius)? {
        Some((est, valid)) if valid.iter().any(|&v| v) => (Cow::Owned(est), valid, true),
        _ => (Cow::Borrowed(disp), core_of(&hard, w, h, erode), false),
    };
    drop(hard);
    let mut out = disp.into_owned();
    if !core.iter().any(|&m| m) {
        return Ok(FilledDepth { disparity: out, filled: 0, skipped: 0, reach: 0.0, visible_reach: 0.0, erode, ramp_model, quiet: None });
    }
    let (lo, hi) = core
        .par_iter()
        .zip(&out.data)
        .filter(|(c, _)| **c)
        .fold(|| (f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), (_, &d)| (lo.min(d), hi.max(d)))
        .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    let coc = coc_radius(lo - focus, blur).max(coc_radius(hi - focus, blur)).min(1e9);
    let visible_reach = ((coc + 1.0) / 2.0).trunc() + 1.0;
    // Distances from the core, on the visible pixels' box grown by the visibility reach (the
    // core lies inside it): exact wherever the fill can matter.
    let bb = visible_box(alpha, visible_reach + 2.0).unwrap_or((0, 0, w, h));
    // The farthest visible pixel from the core.
    let farthest = |to_core: &BoxDistance| {
        alpha
            .data
            .par_chunks(w)
            .enumerate()
            .map_init(
                || vec![0.0; w],
                |dist, (y, alpha)| {
                    to_core.row_into(y, dist);
                    alpha.iter().zip(dist.iter()).filter(|(a, _)| **a > 0.0).map(|(_, &d)| d).fold(0.0, f32::max)
                },
            )
            .reduce(|| 0.0, f32::max)
    };
    // Every test below reads distances up to `edge + visible_reach`: distances exact up to
    // CAPPED_MAX answer when that is within it (about half the exact transform's cost).
    let capped = BoxDistance::upto(&core, w, bb, CAPPED_MAX);
    let (to_core, edge) = match farthest(&capped) {
        edge if edge + visible_reach <= CAPPED_MAX => (capped, edge),
        _ => {
            drop(capped);
            let exact = BoxDistance::new(&core, w, bb);
            let edge = farthest(&exact);
            (exact, edge)
        }
    };
    let reach = super::mask::marching_reach(edge + visible_reach);
    let unknown: Vec<bool> = core.par_iter().map(|&m| !m).collect();
    drop(core);
    let filled = inpaint_telea(&mut out, &unknown, TeleaOptions { max_distance: Some(reach), ..TeleaOptions::new(opts.radius) })?;
    let quiet = focus.clamp(lo, hi);
    let skipped = out
        .data
        .par_chunks_mut(w)
        .zip(unknown.par_chunks(w))
        .enumerate()
        .map_init(
            || vec![0.0; w],
            |dist, (y, (out, unknown))| {
                to_core.row_into(y, dist);
                let mut skipped = 0;
                for ((v, &u), &d) in out.iter_mut().zip(unknown).zip(dist.iter()) {
                    if !u {
                        continue;
                    }
                    if d <= edge + visible_reach {
                        *v = v.clamp(lo, hi);
                    } else {
                        *v = quiet;
                        skipped += 1;
                    }
                }
                skipped
            },
        )
        .sum();
    Ok(FilledDepth { disparity: out, filled, skipped, reach, visible_reach, erode, ramp_model, quiet: Some(quiet) })
}
