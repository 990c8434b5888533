//! Clipped highlights through an inverse-tone-mapping model (`[highlights.onnx]`, ExpandNet or
//! any model with the same contract): the model sees the 8-bit photo and predicts its linear
//! light, clipped lights included.
//!
//! Such a model's output has no absolute scale (ExpandNet ends in a sigmoid and its authors
//! min-max normalize it), so it is brought to the photo by one factor: the median, over
//! well-exposed pixels ([`ANCHOR`]: no channel clipped, neither dark nor near white), of the
//! photo's luminance over the model's. Then, as in `auto`, only clipped samples change: each
//! takes the scaled model's value where that is brighter (a clipped sample says "at least
//! white"), up to [`MAX_RADIANCE`]; every other sample stays as decoded, bit for bit.
//!
//! Units: linear light, white = 1; the threshold and [`ANCHOR`] are in the photo's stored scale.

use super::highlights::luminance;
use super::light_recovery::{HighlightMode, HighlightsOptions, HighlightsReport, MAX_RADIANCE, Recovered, clipped_channels, total_light};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::onnx::{self, ModelKind, OnnxConfig};
use crate::timing::ms_since;
use rayon::prelude::*;

/// Stored (sRGB-encoded) values of a pixel's largest channel that make it an anchor of the
/// model's scale: above the dark end, where noise and the model's own floor dominate, and below
/// the shoulder near white, where cameras compress and the model expands.
pub const ANCHOR: [f32; 2] = [0.2, 0.9];
/// Anchors needed to scale the model (fewer: the photo is nearly all dark or all white, and
/// the stage refuses rather than guess).
pub const MIN_ANCHORS: usize = 64;

/// Runs `[highlights.onnx]` on `rgb` (linear RGB, an integer photo) with clip level `clip`
/// (linear). `None` when no sample is clipped (the model is not loaded). Allocates the model's
/// input and its output at the photo's size, and the result when light was added.
pub fn recover_with_model(rgb: &Image, clip: f32, opts: &HighlightsOptions, cfg: &OnnxConfig) -> Result<Option<Recovered>> {
    let (mask, clipped_pixels) = clipped_channels(rgb, clip);
    if clipped_pixels == 0 {
        return Ok(None);
    }
    let mut model = onnx::load(&opts.onnx, ModelKind::Highlights, cfg)?;
    let t = std::time::Instant::now();
    let input = onnx::to_model_rgb(rgb);
    model.report.pre_ms += ms_since(t);
    let predicted = model.predict(&input, 3)?;
    let scale = anchor_scale(rgb, &input, &mask, &predicted).ok_or_else(|| {
        Error::input(
            &model.path,
            format!(
                "cannot scale the model's output to the photo: fewer than {MIN_ANCHORS} well-exposed pixels (largest channel {} to {} \
                 stored, none clipped) where the model's light is positive; use --highlights auto or off for this photo",
                ANCHOR[0], ANCHOR[1]
            ),
        )
    })?;
    // Each clipped sample: the scaled model where brighter (NaN-safe: a non-finite product
    // fails `>` and keeps the sample).
    let lifted = |i: usize, c: usize| -> Option<f32> {
        let v = rgb.data[i * 3 + c];
        let m = (scale * predicted.data[i * 3 + c]).min(MAX_RADIANCE);
        (mask[i] >> c & 1 == 1 && m > v).then_some(m)
    };
    let added: f64 = (0..mask.len())
        .into_par_iter()
        .with_min_len(1 << 14)
        .filter(|&i| mask[i] != 0)
        .map(|i| (0..3).filter_map(|c| lifted(i, c).map(|m| (m - rgb.data[i * 3 + c]) as f64)).sum::<f64>())
        .sum();
    let out = (added > 0.0).then(|| {
        let mut out = rgb.clone();
        out.data.par_chunks_mut(3).enumerate().filter(|(i, _)| mask[*i] != 0).for_each(|(i, px)| {
            for (c, v) in px.iter_mut().enumerate() {
                if let Some(m) = lifted(i, c) {
                    *v = m;
                }
            }
        });
        out
    });
    let report = HighlightsReport {
        mode: HighlightMode::Onnx,
        threshold: opts.threshold,
        clipped_pixels,
        lights: 0,
        psf_sigma: 0.0,
        areas_left: 0,
        over_budget: 0,
        light_added: added,
        light_added_fraction: if added > 0.0 { added / total_light(rgb) } else { 0.0 },
        brightest: Vec::new(),
        occluders: None,
        model_scale: Some(scale),
        model: Some(model.report),
    };
    Ok(Some(match out {
        Some(img) => Recovered::Changed(img, report),
        None => Recovered::Examined(report),
    }))
}

/// The factor that brings `predicted` (the model's linear light) to the photo: the median over
/// anchor pixels of the photo's luminance (`rgb`, linear) over the model's. `stored` is the
/// photo as the model saw it (sRGB-encoded), `mask` its clipped channels. `None` with fewer
/// than [`MIN_ANCHORS`] anchors.
fn anchor_scale(rgb: &Image, stored: &Image, mask: &[u8], predicted: &Image) -> Option<f32> {
    let mut ratios: Vec<f32> = (rgb.data.par_chunks(3).zip(stored.data.par_chunks(3)), predicted.data.par_chunks(3))
        .into_par_iter()
        .enumerate()
        .filter_map(|(i, ((lin, s), p))| {
            let top = s[0].max(s[1]).max(s[2]);
            let m = luminance(p);
            (mask[i] == 0 && (ANCHOR[0]..=ANCHOR[1]).contains(&top) && m.is_finite() && m > 1e-6).then(|| luminance(lin) / m)
        })
        .collect();
    if ratios.len() < MIN_ANCHORS {
        return None;
    }
    let k = ratios.len() / 2;
    Some(*ratios.select_nth_unstable_by(k, f32::total_cmp).1)
}
