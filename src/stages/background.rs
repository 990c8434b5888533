//! Background inpainting: colour and disparity behind the foreground.
//!
//! The background layer is opaque, so every pixel the foreground may hide (its soft edge
//! included) is re-synthesized from the visible background with Telea inpainting, for RGB and
//! disparity alike. Around the matte, a band of `dilate` pixels is re-synthesized too where its
//! colour is contaminated by the foreground ([`super::contamination`]); the rest of the band is
//! visible background and keeps its light. Point-like highlights next to the hole are kept but
//! not used as fill sources ([`super::highlights`]), so no bright blob is spread behind the
//! foreground.

use super::inpaint::{TeleaOptions, inpaint_telea, inpaint_telea_many};
use super::mask::dilate;
use crate::error::Result;
use crate::image::Image;
use crate::render::lens;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

/// Which pixels of the band of `dilate` pixels around the matte are re-synthesized.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EdgeBand {
    /// Only those whose colour is a mix with the foreground's ([`super::contamination`]).
    #[default]
    Tested,
    /// All of them (the plain dilation; loses visible highlights next to the subject).
    Replaced,
    /// None of them: the matte is taken as exact (what the pipeline does with a binary matte
    /// given by the user, which says that no pixel outside it is mixed).
    Kept,
}

/// Whether visible point-like highlights near the hole feed the fill.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HighlightSources {
    /// They do not, and those the hole cuts are completed as discs behind it
    /// ([`super::highlight_completion`]).
    #[default]
    Completed,
    /// They do not: the hole is filled from their surroundings ([`super::highlights`]).
    Excluded,
    /// They do, like any pixel (a highlight is smeared across the hole).
    Included,
}

/// `[inpaint]` options of the classical (Telea) background fill.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InpaintOptions {
    /// Alpha above which a pixel counts as (partly) covered by the foreground.
    pub threshold: f32,
    /// Width (pixels) of the band around the covered region whose pixels may carry foreground
    /// colour; which of them are re-synthesized is `edge_band`'s rule.
    pub dilate: f32,
    /// Which band pixels are re-synthesized.
    pub edge_band: EdgeBand,
    /// Whether visible point-like highlights feed the fill.
    pub highlights: HighlightSources,
    /// The foreground layer's colour at soft matte edges.
    pub foreground: ForegroundColour,
    /// Telea neighbourhood radius, pixels.
    pub radius: f32,
    /// "telea" (this module), "patchmatch" (Telea, then [`super::patchmatch`] on the colour) or
    /// "onnx" (the `[inpaint.onnx]` model, `stages::inpaint_onnx`).
    pub method: super::inpaint_onnx::InpaintMethod,
    /// `[inpaint.onnx]`: the model used by `method = "onnx"`.
    pub onnx: crate::onnx::ModelSpec,
    /// Set by the pipeline, never by `pipeline.toml`: where the highlights stage (`auto`) put
    /// back an 8/16-bit photo's clipped lights, a sample above this (the photo's white, 1) is
    /// such a light, and the fill keeps it out of its sources like a point highlight. The point test
    /// misses a recovered light's rim: in a window the light itself fills, the rim is not 3x the
    /// window's upper quartile, and Telea smeared it across the hole behind the subject, where
    /// a blurred subject's edge shows it (held-out Mitsuba `ho_profile`, background in focus,
    /// `srgb8-psf`: 26.07 dB with the stage, 28.46 without).
    #[serde(skip)]
    pub lights_above: Option<f32>,
}

impl Default for InpaintOptions {
    fn default() -> Self {
        InpaintOptions {
            threshold: 0.02,
            dilate: 3.0,
            edge_band: EdgeBand::default(),
            highlights: HighlightSources::default(),
            foreground: ForegroundColour::default(),
            radius: 5.0,
            method: Default::default(),
            onnx: Default::default(),
            lights_above: None,
        }
    }
}

/// The foreground layer's colour where the matte is soft.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ForegroundColour {
    /// The photo's mix split between the carried foreground colour and the filled background
    /// ([`super::foreground::split`]).
    #[default]
    Unmixed,
    /// The photo's colour as it is (edges carry background colour: a halo when blurred).
    Photo,
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
    /// Pixels of the edge band around the matte, and how many of them were re-synthesized.
    pub band: (usize, usize),
    /// Visible highlights kept out of the fill's sources.
    pub highlights_kept: usize,
    /// Highlights the mask cuts, completed as discs behind it ([`super::highlight_completion`]).
    pub highlights_completed: usize,
    /// How deep (fast-marching pixels) the fill went; infinite for the whole region.
    pub reach: f32,
}

impl Background {
    /// Assembles a background: `filled` of the `mask` pixels were computed (the rest are
    /// `skipped`), `band` = (edge band pixels, of which re-synthesized, highlights kept), as
    /// deep as `reach` (fast-marching pixels).
    pub fn new(rgb: Image, disparity: Image, mask: Vec<bool>, filled: usize, band: (usize, usize, usize), reach: f32) -> Self {
        let total = mask.iter().filter(|&&m| m).count();
        Background {
            rgb,
            disparity,
            mask,
            filled,
            skipped: total.saturating_sub(filled),
            band: (band.0, band.1),
            highlights_kept: band.2,
            highlights_completed: 0,
            reach,
        }
    }
}

fn covered(alpha: &Image, opts: &InpaintOptions) -> Vec<bool> {
    alpha.data.par_iter().map(|&a| a > opts.threshold).collect()
}

/// How deep under the foreground a background fill goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reach {
    /// Everywhere (a fill that more layers are cut from must be complete).
    Whole,
    /// As deep as a value behind the foreground can be seen: within `see` pixels (visibility
    /// box plus a background scatter radius) of a pixel whose alpha is below 1
    /// ([`FillRegion::reach`]).
    Seen(f32),
    /// This many pixels (fast-marching distance) from the visible background.
    Pixels(f32),
}

/// What a background fill replaces and what it must not spread.
pub struct FillRegion {
    /// Pixels to re-synthesize: covered by the foreground, or in the edge band and
    /// contaminated by its colour.
    pub mask: Vec<bool>,
    /// Pixels whose disparity is re-synthesized: `mask`, plus the pixels outside the matte
    /// that a soft depth edge gives foreground depth.
    pub depth_mask: Vec<bool>,
    /// Visible point-like highlights near the mask, which must not feed the fill (all false
    /// with [`HighlightSources::Included`]).
    pub highlights: Vec<bool>,
    /// Pixels of the edge band (outside the covered region).
    pub band: usize,
    /// Of those, the pixels re-synthesized.
    pub band_replaced: usize,
    /// Highlights kept out of the fill's sources.
    pub highlights_kept: usize,
    /// The pixels the foreground may cover or contaminate: covered (`alpha > threshold`), grown
    /// by `dilate`; `mask` is a subset of it.
    pub grown: Vec<bool>,
}

/// How deep (pixels) translucent pixels may lie in the mask for [`FillRegion::reach`] to find
/// the deepest with capped distances; deeper ones take the exact transform. (An 8-bit matte's
/// 254s reach 12 px into the 12.2 MP end-to-end scene's subject.)
const SHALLOW_PX: usize = super::mask::CAPPED_MAX as usize;

impl FillRegion {
    /// The fast-marching distance `reach` means for this region and `alpha`. For
    /// [`Reach::Seen`]: background values are seen through the foreground wherever its
    /// visibility is below 1, i.e. within `see` pixels of a pixel whose alpha is below 1, so
    /// translucent pixels deep inside the mask (fur, glass) push the reach inward accordingly.
    /// Cost: one distance transform on the grown mask's box.
    pub fn reach(&self, alpha: &Image, reach: Reach) -> f32 {
        let see = match reach {
            Reach::Whole => return f32::INFINITY,
            Reach::Pixels(px) => return px,
            Reach::Seen(see) => see,
        };
        let (w, h) = (alpha.width, alpha.height);
        let mask = &self.grown;
        // Every masked pixel's nearest outside pixel lies within the mask's box grown by 1.
        let Some(bb) = super::mask::grown_bbox(mask, w, h, 1.0) else { return super::mask::marching_reach(see) };
        let (x0, y0, x1, _) = bb;
        // The deepest translucent pixel's squared distance to the outside, from `d2` on the
        // box (None: one lies beyond `exact_to`, up to which `d2` is exact). Rows in parallel:
        // this scan is on the background fill's critical path.
        let deepest = |d2: &[u32], exact_to: u32| -> Option<u32> {
            d2.par_chunks(x1 - x0)
                .enumerate()
                .map(|(y, row)| {
                    row.iter()
                        .zip(&alpha.data[(y0 + y) * w + x0..(y0 + y) * w + x1])
                        .filter(|(d, a)| **d != super::mask::NONE && **a < 1.0)
                        .try_fold(0, |m: u32, (&d, _)| (d <= exact_to).then_some(m.max(d)))
                })
                .try_reduce(|| 0, |a, b| Some(a.max(b)))
        };
        // Translucent pixels sit near the outline in most mattes: distances capped a few pixels
        // deep answer then (cheaper than the exact transform), the exact ones otherwise.
        let near = super::mask::sq_distance_capped(mask, w, bb, false, SHALLOW_PX);
        let deep = deepest(&near, (SHALLOW_PX * SHALLOW_PX) as u32).unwrap_or_else(|| {
            drop(near);
            deepest(&super::mask::sq_distance_window(mask, w, bb, false), u32::MAX).expect("exact distances")
        });
        super::mask::marching_reach(super::mask::root(deep) + see)
    }

    /// The holes a colour fill is given: the mask, and the kept highlights too, so that they
    /// feed nothing (put them back with [`FillRegion::restore_highlights`]).
    pub fn colour_holes(&self) -> Vec<bool> {
        self.mask.par_iter().zip(&self.highlights).map(|(&m, &h)| m || h).collect()
    }

    /// Puts the kept highlights of `photo` back into `filled` (both linear RGB): they are
    /// visible background.
    pub fn restore_highlights(&self, filled: &mut Image, photo: &Image) {
        if self.highlights_kept == 0 {
            return;
        }
        for (i, _) in self.highlights.iter().enumerate().filter(|(_, h)| **h) {
            filled.data[i * 3..i * 3 + 3].copy_from_slice(&photo.data[i * 3..i * 3 + 3]);
        }
    }
}

/// Which pixels of the edge band a re-synthesis could change in the render a fill is for.
#[derive(Clone, Copy, Debug)]
pub enum BandReach<'a> {
    /// All of them (a caller that does not know the render).
    Any,
    /// Those a blur of the render reaches: within the foreground's largest circle of confusion
    /// of the covered region (its disks light pixels closer than `r + ½`,
    /// [`lens::disk_coverage`]), or out of focus themselves (CoC of at least
    /// [`lens::SHARP_COC_PX`]). Elsewhere the render shows the band pixel as the photo has it,
    /// so re-synthesizing it would change an in-focus pixel. `disparity` is the scene's
    /// (normalized), `focus` and `blur` (K) the render's.
    Render {
        /// The scene's normalized disparity, the frame of the fill.
        disparity: &'a Image,
        /// The render's focal plane (normalized disparity).
        focus: f32,
        /// The render's blur strength K (pixels per unit of disparity).
        blur: f32,
    },
}

impl BandReach<'_> {
    /// The `band` pixels (indices) a change could show at, in `band`'s order. Cost: one pass
    /// over the covered pixels and, when the foreground's blur is narrower than the band, one
    /// dilation of `covered`.
    fn shown(self, band: &[usize], covered: &[bool], (w, h): (usize, usize), band_width: f32) -> Vec<usize> {
        let BandReach::Render { disparity, focus, blur } = self else { return band.to_vec() };
        let coc = |i: usize| lens::coc_radius(disparity.data[i] - focus, blur);
        let fg = covered.par_iter().enumerate().filter(|(_, c)| **c).map(|(i, _)| coc(i)).reduce(|| 0.0, f32::max);
        // Strictly closer than `r + ½`: at that distance a disk's coverage is 0.
        let lit = fg + 0.5 - 1e-3;
        let near = if fg < lens::SHARP_COC_PX {
            None
        } else if lit >= band_width {
            return band.to_vec();
        } else {
            Some(dilate(covered, w, h, lit))
        };
        band.iter().copied().filter(|&i| near.as_ref().is_some_and(|n| n[i]) || coc(i) >= lens::SHARP_COC_PX).collect()
    }
}

/// The region the background fill replaces, and the highlights it keeps out of its sources
/// (within `radius + 1` of the mask: Telea reads a disc of `radius`). `ramp_outside` is the
/// measured width (pixels) of a soft depth edge outside the outline
/// ([`super::depth_edges`]); above a pixel, disparity is re-synthesized that far out plus one.
/// Band pixels are tested (or replaced) only where `shown` says the render could show them.
/// Cost: a few distance transforms on the matte's grown bounding box, and window medians on
/// the band and around the mask (see the two modules); allocates a few masks.
pub fn fill_region(rgb: &Image, alpha: &Image, opts: &InpaintOptions, ramp_outside: f32, shown: BandReach) -> FillRegion {
    let (w, h) = (alpha.width, alpha.height);
    let covered = covered(alpha, opts);
    let depth_grown = (ramp_outside > 1.0).then(|| dilate(&covered, w, h, ramp_outside + 1.0));
    let grown = dilate(&covered, w, h, opts.dilate);
    // Rows in parallel (a full-frame scan at 12 MP); the order stays the raster order.
    let band: Vec<usize> = (0..h).into_par_iter().flat_map_iter(|y| (y * w..(y + 1) * w).filter(|&i| grown[i] && !covered[i])).collect();
    let candidates = match opts.edge_band {
        EdgeBand::Kept => Vec::new(),
        _ => shown.shown(&band, &covered, (w, h), opts.dilate),
    };
    let mut mask = covered;
    let replaced = match opts.edge_band {
        EdgeBand::Replaced | EdgeBand::Kept => vec![true; candidates.len()],
        EdgeBand::Tested => super::contamination::contaminated(rgb, alpha, |j| !grown[j], &candidates, opts.dilate),
    };
    for (&i, &r) in candidates.iter().zip(&replaced) {
        mask[i] = r;
    }
    let mut highlights = vec![false; w * h];
    let mut highlights_kept = 0;
    if opts.highlights != HighlightSources::Included {
        // The known pixels within `radius + 1` of the mask, in raster order (rows in parallel).
        let near = dilate(&mask, w, h, opts.radius + 1.0);
        let candidates: Vec<usize> =
            (0..h).into_par_iter().flat_map_iter(|y| (y * w..(y + 1) * w).filter(|&i| near[i] && !mask[i])).collect();
        drop(near);
        let above = |i: usize| opts.lights_above.is_some_and(|t| rgb.data[i * 3..i * 3 + 3].iter().any(|&v| v > t));
        for (&i, hl) in candidates.iter().zip(super::highlights::point_highlights(rgb, &candidates)) {
            let hl = hl || above(i);
            highlights[i] = hl;
            highlights_kept += usize::from(hl);
        }
    }
    let depth_mask = match depth_grown {
        Some(g) => g.par_iter().zip(&mask).map(|(&g, &m)| g || m).collect(),
        None => mask.clone(),
    };
    FillRegion {
        mask,
        depth_mask,
        highlights,
        band: band.len(),
        band_replaced: replaced.iter().filter(|&&r| r).count(),
        highlights_kept,
        grown,
    }
}

/// Inpaints `rgb` and `disp` over [`fill_region`]'s masks, as deep as `reach` says
/// ([`FillRegion::reach`]; deeper pixels cannot be seen through any blur and keep their input).
/// The depth used is the answer's `reach`. With `opts.method` = PatchMatch, the colour within
/// that depth (Euclidean) is then re-filled by [`super::patchmatch::fill`] from Telea's start,
/// with the filled disparity as its depth term. [`prepare_background`] then
/// [`fill_background`]: a caller that learns `reach` late can run the first half earlier.
pub fn inpaint_background(
    rgb: &Image,
    disp: &Image,
    alpha: &Image,
    opts: &InpaintOptions,
    reach: Reach,
    (ramp_outside, shown): (f32, BandReach),
) -> Result<Background> {
    fill_background(prepare_background(rgb, disp, alpha, opts, (ramp_outside, shown)), rgb, alpha, opts, reach)
}

/// The first half of [`inpaint_background`], which needs no reach: the fill region and the
/// copies of the colour and disparity the fill starts from.
pub struct PreparedFill {
    region: FillRegion,
    rgb: Image,
    disp: Image,
}

/// [`inpaint_background`]'s first half: [`fill_region`] beside the copies of `rgb` and `disp`
/// (page faults mostly).
pub fn prepare_background(
    rgb: &Image,
    disp: &Image,
    alpha: &Image,
    opts: &InpaintOptions,
    (ramp_outside, shown): (f32, BandReach),
) -> PreparedFill {
    let (region, (rgb, disp)) = rayon::join(|| fill_region(rgb, alpha, opts, ramp_outside, shown), || (rgb.clone(), disp.clone()));
    PreparedFill { region, rgb, disp }
}

/// [`inpaint_background`]'s second half, on [`prepare_background`]'s answer for the same
/// `photo` (linear RGB), `alpha` and `opts`.
pub fn fill_background(prepared: PreparedFill, photo: &Image, alpha: &Image, opts: &InpaintOptions, reach: Reach) -> Result<Background> {
    let PreparedFill { region, rgb: mut rgb_out, disp: mut disp_out } = prepared;
    let reach = region.reach(alpha, reach);
    let rgb_mask = region.colour_holes();
    let topts = TeleaOptions { max_distance: Some(reach), ..TeleaOptions::new(opts.radius) };
    let filled = if rgb_mask == region.depth_mask {
        // One march fills both (the usual case: no kept highlight, no depth ramp).
        inpaint_telea_many(&mut [&mut rgb_out, &mut disp_out], &rgb_mask, topts)
    } else {
        let (filled, filled_disp) =
            rayon::join(|| inpaint_telea(&mut rgb_out, &rgb_mask, topts), || inpaint_telea(&mut disp_out, &region.depth_mask, topts));
        filled_disp?;
        filled
    };
    disp_out.map_inplace(|v| v.clamp(0.0, 1.0));
    if opts.method == super::inpaint_onnx::InpaintMethod::PatchMatch {
        super::patchmatch::fill(&mut rgb_out, &rgb_mask, &disp_out, reach, &Default::default())?;
    }
    // Kept highlights sit next to known pixels: the fill always reached them.
    let filled = filled?.saturating_sub(region.highlights_kept);
    region.restore_highlights(&mut rgb_out, photo);
    let completed = complete_highlights(&mut rgb_out, photo, &region, opts);
    let stats = (region.band, region.band_replaced, region.highlights_kept);
    let mut bg = Background::new(rgb_out, disp_out, region.mask, filled, stats, reach);
    bg.highlights_completed = completed;
    Ok(bg)
}

/// With [`HighlightSources::Completed`], the highlights `region` cuts completed as discs in
/// `filled` ([`super::highlight_completion::complete`]); how many.
pub fn complete_highlights(filled: &mut Image, photo: &Image, region: &FillRegion, opts: &InpaintOptions) -> usize {
    match opts.highlights {
        HighlightSources::Completed => super::highlight_completion::complete(filled, photo, region).len(),
        HighlightSources::Excluded | HighlightSources::Included => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `FillRegion::reach` against the brute-force deepest translucent pixel: translucent
    /// pixels at the outline (the capped route) and deep inside (the exact route), and a mask
    /// with no outside in its box.
    #[test]
    fn reach_finds_the_deepest_translucent_pixel() {
        let (w, h) = (60, 50);
        let region = |grown: Vec<bool>| FillRegion {
            mask: grown.clone(),
            depth_mask: grown.clone(),
            highlights: vec![false; grown.len()],
            band: 0,
            band_replaced: 0,
            highlights_kept: 0,
            grown,
        };
        let rect: Vec<bool> = (0..w * h).map(|i| (5..55).contains(&(i % w)) && (3..47).contains(&(i / w))).collect();
        let brute = |mask: &[bool], alpha: &Image| -> f32 {
            let mut deep = 0.0f32;
            for i in (0..w * h).filter(|&i| alpha.data[i] < 1.0) {
                let d2 = (0..w * h)
                    .filter(|&j| !mask[j])
                    .map(|j| ((i % w).abs_diff(j % w).pow(2) + (i / w).abs_diff(j / w).pow(2)) as u32)
                    .min()
                    .unwrap_or(super::super::mask::NONE);
                if d2 != super::super::mask::NONE {
                    deep = deep.max(super::super::mask::root(d2));
                }
            }
            deep
        };
        for depth in [0usize, 1, 4, 14, 15, 16, 20] {
            let mut alpha = Image::from_vec(w, h, 1, rect.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect()).unwrap();
            // A translucent pixel `depth` pixels inside the rectangle's left edge, and a soft rim.
            alpha.data[25 * w + 5 + depth] = 0.5;
            alpha.data[3 * w + 20] = 0.8;
            let want = super::super::mask::marching_reach(brute(&rect, &alpha) + 2.0);
            assert_eq!(region(rect.clone()).reach(&alpha, Reach::Seen(2.0)), want, "depth {depth}");
        }
        let full = vec![true; w * h];
        let alpha = Image::from_vec(w, h, 1, vec![0.5; w * h]).unwrap();
        assert_eq!(region(full).reach(&alpha, Reach::Seen(2.0)), super::super::mask::marching_reach(2.0));
    }

    /// Which band pixels a render could show (the rule `BandReach::Render` states): those
    /// strictly closer to the covered region than the foreground's largest CoC plus ½ (a disk
    /// of radius r lights nothing at r + ½), and those out of focus themselves; all of them
    /// when that reach spans the band, or when the render is unknown. One row: covered x < 5,
    /// the band x = 5..=9 (distances 1 to 5), K = 10.
    #[test]
    fn the_band_a_render_shows_is_within_the_blur_or_out_of_focus() {
        let (w, h, k) = (12, 1, 10.0);
        let covered: Vec<bool> = (0..w).map(|x| x < 5).collect();
        let band: Vec<usize> = (5..10).collect();
        // Foreground at `fg`, the band in focus at 0.5 but for x = 9 (CoC 1 px).
        let at = |x: usize, fg: f32| match x {
            0..5 => fg,
            9 => 0.6,
            _ => 0.5,
        };
        let scene = |fg: f32| Image::from_vec(w, h, 1, (0..w).map(|x| at(x, fg)).collect()).unwrap();
        let shown = |disparity: &Image, band_width: f32| {
            BandReach::Render { disparity, focus: 0.5, blur: k }.shown(&band, &covered, (w, h), band_width)
        };
        // CoC 2.5: distances 1 and 2 are lit, 3 (= r + ½) is not.
        let d = scene(0.75);
        assert_eq!(shown(&d, 10.0), vec![5, 6, 9]);
        // A reach as wide as the band: all of it, without the dilation.
        assert_eq!(shown(&d, 2.9), band);
        // The foreground in focus: only the band's own out-of-focus pixel.
        assert_eq!(shown(&scene(0.5), 10.0), vec![9]);
        // Behind the focal plane as in front: the CoC is |d - focus|·K.
        assert_eq!(shown(&scene(0.25), 10.0), vec![5, 6, 9]);
        assert_eq!(BandReach::Any.shown(&band, &covered, (w, h), 10.0), band);
    }

    /// A solid red subject, the square `side × side`, on a grey (0.3) ground: its pixels, the
    /// matte and the linear RGB photo.
    fn red_square(w: usize, h: usize, side: std::ops::Range<usize>) -> (Vec<bool>, Image, Image) {
        let covered: Vec<bool> = (0..w * h).map(|i| side.contains(&(i % w)) && side.contains(&(i / w))).collect();
        let alpha = Image::from_vec(w, h, 1, covered.iter().map(|&c| if c { 1.0 } else { 0.0 }).collect()).unwrap();
        let mut rgb = Image::filled(w, h, 3, 0.3);
        for i in (0..w * h).filter(|&i| covered[i]) {
            rgb.data[i * 3..i * 3 + 3].copy_from_slice(&[1.0, 0.0, 0.0]);
        }
        (covered, alpha, rgb)
    }

    /// `fill_region`'s masks against their stated rules, on a red square over a grey ground:
    /// the edge band (within `dilate` = 3 px of the covered pixels) replaced whole
    /// (`"replaced"`), kept (`"kept"`), or replaced where a pixel is a mix with the subject's
    /// colour (`"tested"`, the default: one such pixel); the disparity re-synthesized a soft
    /// depth edge's width plus one beyond the outline when that width is above a pixel; a
    /// point highlight within Telea's reach of the mask kept out of the sources unless
    /// `"included"`.
    #[test]
    fn the_fill_region_follows_the_band_depth_edge_and_highlight_rules() {
        let (w, h) = (24, 24);
        let (covered, alpha, mut rgb) = red_square(w, h, 8..16);
        let (mix, light) = (12 * w + 16, 12 * w + 4);
        rgb.data[mix * 3..mix * 3 + 3].copy_from_slice(&[0.65, 0.15, 0.15]);
        // Lights as bright as `light` on the subject and beyond Telea's reach (6 px): neither
        // is a source the fill could read, so neither is kept.
        for i in [light, 12 * w + 12, 23 * w] {
            rgb.data[i * 3..i * 3 + 3].fill(20.0);
        }
        // Dim pixels with a sample above white (a recovered light's rim) and at white.
        let (rim, white) = (4 * w + 12, 19 * w + 12);
        rgb.data[rim * 3..rim * 3 + 3].copy_from_slice(&[0.3, 0.3, 1.2]);
        rgb.data[white * 3..white * 3 + 3].copy_from_slice(&[0.3, 0.3, 1.0]);
        let grown = dilate(&covered, w, h, 3.0);
        let band = (0..w * h).filter(|&i| grown[i] && !covered[i]).count();
        let region_above = |edge_band, highlights, ramp, lights_above| {
            let opts = InpaintOptions { edge_band, highlights, lights_above, ..Default::default() };
            fill_region(&rgb, &alpha, &opts, ramp, BandReach::Any)
        };
        let region = |edge_band, highlights, ramp| region_above(edge_band, highlights, ramp, None);
        let kept = |r: &FillRegion| ((0..w * h).filter(|&i| r.highlights[i]).collect::<Vec<_>>(), r.highlights_kept);
        let with = |extra: &[usize]| -> Vec<bool> { (0..w * h).map(|i| covered[i] || extra.contains(&i)).collect() };
        let r = region(EdgeBand::Replaced, HighlightSources::Completed, 0.0);
        assert_eq!((r.band, r.band_replaced), (band, band));
        assert_eq!(r.mask, grown);
        let r = region(EdgeBand::Kept, HighlightSources::Completed, 0.0);
        assert_eq!((r.band, r.band_replaced), (band, 0));
        assert_eq!(r.mask, covered);
        let r = region(EdgeBand::Tested, HighlightSources::Completed, 1.0);
        assert_eq!((r.band, r.band_replaced), (band, 1));
        assert_eq!(r.mask, with(&[mix]));
        assert_eq!(r.grown, grown);
        // A depth edge of one pixel: nothing beyond the mask; of 2.5, within 3.5 of the square.
        assert_eq!(r.depth_mask, r.mask);
        let far = dilate(&covered, w, h, 3.5);
        let r = region(EdgeBand::Tested, HighlightSources::Completed, 2.5);
        assert_eq!(r.depth_mask, (0..w * h).map(|i| far[i] || r.mask[i]).collect::<Vec<_>>());
        // The point light 4 px left of the square: kept out of the sources, alone.
        assert_eq!(kept(&r), (vec![light], 1));
        assert_eq!(r.colour_holes(), with(&[mix, light]));
        // After the highlights stage (`lights_above` white) the rim too, not the white pixel.
        assert_eq!(kept(&region_above(EdgeBand::Tested, HighlightSources::Completed, 0.0, Some(1.0))), (vec![rim, light], 2));
        let r = region(EdgeBand::Tested, HighlightSources::Included, 0.0);
        assert_eq!((r.highlights_kept, r.highlights.iter().any(|&h| h)), (0, false));
    }

    /// What the fill must leave alone: pixels deeper under the subject than the reach keep
    /// their input (no blur can show them), and a kept point light stays the visible
    /// background it is, colour and depth, while the fill next to it does not read it.
    #[test]
    fn the_fill_stops_at_its_reach_and_leaves_kept_lights_as_they_are() {
        let (w, h) = (40, 40);
        let (covered, alpha, mut rgb) = red_square(w, h, 10..30);
        let mut disp = Image::from_vec(w, h, 1, covered.iter().map(|&c| if c { 0.8 } else { 0.2 }).collect()).unwrap();
        let light = 20 * w + 5;
        rgb.data[light * 3..light * 3 + 3].fill(20.0);
        disp.data[light] = 0.9;
        let opts = InpaintOptions { highlights: HighlightSources::Excluded, ..Default::default() };
        let bg = inpaint_background(&rgb, &disp, &alpha, &opts, Reach::Pixels(3.0), (0.0, BandReach::Any)).unwrap();
        assert_eq!(bg.highlights_kept, 1);
        assert!(bg.filled > 0 && bg.skipped > 0, "filled {}, skipped {}", bg.filled, bg.skipped);
        let centre = 20 * w + 20;
        assert_eq!((bg.rgb.pixel(20, 20), bg.disparity.data[centre]), (&[1.0, 0.0, 0.0][..], 0.8), "beyond the reach");
        assert_eq!((bg.rgb.pixel(5, 20), bg.disparity.data[light]), (&[20.0; 3][..], 0.9), "the kept light");
        // The subject's first column, 5 px from the light (Telea's radius): the ground's grey
        // (the light's depth is a source of the depth fill: it is visible background).
        assert!(bg.rgb.pixel(10, 20).iter().all(|&v| (v - 0.3).abs() < 1e-3), "{:?}", bg.rgb.pixel(10, 20));
    }

    /// The whole fill on a disc of radiance 20 half behind a solid subject: by default the
    /// hidden half comes back in the background layer (light within 15% of the disc's), with
    /// `"excluded"` it does not; the visible background is the photo's either way.
    #[test]
    fn a_highlight_the_subject_cuts_is_completed_behind_it() {
        let (w, h) = (64, 48);
        let (cx, cy, r) = (32.4, 23.7, 2.6);
        let disc = super::super::highlight_completion::Disc { cx, cy, r, rgb: [20.0; 3] };
        let mut photo = Image::filled(w, h, 3, 0.3);
        let mut truth = photo.clone();
        let alpha = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w >= 33 { 1.0 } else { 0.0 }).collect()).unwrap();
        for y in 0..h {
            for x in 0..w {
                let a = disc.coverage(x, y);
                truth.pixel_mut(x, y).iter_mut().for_each(|v| *v += (20.0 - *v) * a);
                if x < 33 {
                    photo.pixel_mut(x, y).copy_from_slice(truth.pixel(x, y));
                } else {
                    photo.pixel_mut(x, y).fill(0.05);
                }
            }
        }
        let disp = Image::filled(w, h, 1, 0.0);
        let hidden_light = |img: &Image| (0..w * h).filter(|&i| i % w >= 33).map(|i| img.data[i * 3] as f64 - 0.3).sum::<f64>();
        let want = hidden_light(&truth);
        for (mode, completed) in [(HighlightSources::Completed, 1), (HighlightSources::Excluded, 0)] {
            let opts = InpaintOptions { highlights: mode, ..Default::default() };
            let bg = inpaint_background(&photo, &disp, &alpha, &opts, Reach::Whole, (0.0, BandReach::Any)).unwrap();
            assert_eq!(bg.highlights_completed, completed, "{mode:?}");
            let got = hidden_light(&bg.rgb);
            if completed == 1 {
                assert!((got - want).abs() < 0.15 * want, "hidden light {got} against {want}");
            } else {
                assert!(got.abs() < 0.1 * want, "{mode:?}: hidden light {got}");
            }
            for i in (0..w * h).filter(|&i| i % w < 30) {
                assert_eq!(bg.rgb.data[i * 3..i * 3 + 3], photo.data[i * 3..i * 3 + 3], "{mode:?}: visible pixel {i}");
            }
        }
    }

    /// A recovered light at the subject's edge whose rim (1.5, above the 8-bit photo's white)
    /// fills most of the point test's window: the test keeps only the core out of the fill's
    /// sources, and Telea smears the rim across the hole. Told the recovered lights' floor
    /// (`lights_above`, as the pipeline sets it after the highlights stage), the fill keeps
    /// the rim out too: the hole beyond the light stays the ground's level.
    #[test]
    fn recovered_lights_do_not_feed_the_fill() {
        let (w, h) = (48, 32);
        let (cx, cy) = (19.5f32, 16.0f32);
        let mut photo = Image::filled(w, h, 3, 0.2);
        for y in 0..h {
            for x in 0..w {
                let d = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
                let v = if x >= 21 {
                    0.05
                } else if d < 2.5 {
                    20.0
                } else if d < 5.0 {
                    1.5
                } else {
                    0.2
                };
                photo.pixel_mut(x, y).fill(v);
            }
        }
        let alpha = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w >= 21 { 1.0 } else { 0.0 }).collect()).unwrap();
        let disp = Image::filled(w, h, 1, 0.0);
        // The brightest filled sample well beyond the light's reach behind the subject.
        let beyond = |opts: &InpaintOptions| {
            let bg = inpaint_background(&photo, &disp, &alpha, opts, Reach::Whole, (0.0, BandReach::Any)).unwrap();
            assert!(bg.rgb.all_finite());
            (0..w * h).filter(|&i| i % w >= 27).map(|i| bg.rgb.data[i * 3]).fold(0.0f32, f32::max)
        };
        let smeared = beyond(&InpaintOptions::default());
        assert!(smeared > 0.5, "the point test alone should let the rim through: {smeared}");
        let kept = beyond(&InpaintOptions { lights_above: Some(1.0), ..Default::default() });
        assert!(kept < 0.3, "the rim fed the fill: {kept}");
    }
}
