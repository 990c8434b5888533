//! Image-guided matting: a coarse matte's outline moved onto the photo's edges.
//!
//! Without a user's matte the foreground is a split of the depth map (or a saliency model's
//! mask). An estimator's depth map is coarser and smoother than the photo, so that outline
//! follows the depth's blurry edge: jagged where the map was upsampled, off by the ramp's width,
//! and hard where the subject's own edge is soft (hair, fur, feathered blobs). This stage keeps
//! the coarse matte where it is sure and solves alpha from the photo where it is not:
//!
//! - **Trimap.** Pixels within the band around the coarse outline are unknown; beyond it, inside
//!   is foreground (α = 1) and outside background (α = 0). The band's half-widths are the depth
//!   map's measured ramp on each side ([`super::depth_edges::measure`]: the true edge lies
//!   within the ramp) plus [`MIN_BAND_PX`] (an antialiased or feathered edge is that wide even
//!   with an exact depth map). A part thinner than the band (a bar a smoothed depth map
//!   widened) keeps its ridge as foreground, where no thick core is near.
//! - **Alpha.** In each window of radius `r` (the band's wider half plus one, so a window centred
//!   in the band reaches known pixels on both sides) alpha is a linear function of colour,
//!   `α ≈ a·I + b` (the colour-line model behind closed-form matting, Levin et al. 2008, and the
//!   guided filter, He et al. 2010), fitted by ridge regression to the window's *known* pixels
//!   only, with the photo's linear values (clipped to [0, 1]) as `I`: light mixes linearly
//!   across an edge, so a mixed pixel lies on the line between its sides there (an sRGB guide
//!   bent that line: a 30% pixel came out at 40%).
//!   An unknown pixel takes the mean of the models of the windows that cover it, each weighted
//!   by how much of both sides it saw (`min(fg, bg)` known pixels, plus a little of its known
//!   count): a window that saw one side only predicts that side everywhere and would smear
//!   the edge. Where the colours cannot tell the sides apart the ridge term flattens `a` and
//!   the model falls back to the known pixels' mean, a ramp across the band.
//!   A window's fit counts as far as it explains its known pixels (R² from [`R2_LOW`] to
//!   [`R2_FULL`]); a pixel's as far as its colour predicts 0 … 1 (a light behind the edge
//!   predicts far beyond and keeps the prior). Elsewhere the coarse matte stands.
//! - **Outline.** [`refine`] keeps where the fit crosses one half, softened as the split is;
//!   [`fit`] gives the fit's own soft values (the bench's layers scored worse with them).
//! - **Colours.** The foreground's colour at the new soft edge is separated from the background
//!   by the peel's existing rule ([`super::foreground`]), as for a user's soft matte.
//!
//! Cost: two distance transforms capped at the band on the outline's box, then tiles of
//! [`TILE`] px that hold unknown pixels, in parallel: each tile's window sums come from f64
//! summed-area tables of its grown region (14 planes), so a window of any radius costs the
//! same. Allocates the refined matte and, per tile, its tables (a few MB per thread at most).
//! Output is in [0, 1], finite for every finite input; a matte without an outline (empty or
//! full) comes back unchanged.

use super::depth_edges::EdgeWidths;
use super::mask::{dilate, gaussian_blur, grown_bbox, root, sq_distance_upto};
use crate::image::Image;
use rayon::prelude::*;
use serde::Serialize;

/// How the coarse matte is refined (`[segment] refine`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RefineMethod {
    /// Guided refinement of the depth split's and a model's matte; a user's matte as given.
    #[default]
    Auto,
    /// Every matte as it comes.
    Off,
    /// The colour-line fit of this module, on every matte (a user's too).
    Guided,
    /// Closed-form matting on the same trimap (`stages::closed_form`), on every matte.
    ClosedForm,
}

impl RefineMethod {
    /// Whether a matte is refined: `user_matte` says it is the user's (refined only when
    /// `Guided` is asked for by name), not the depth split's or a model's.
    pub fn applies_to(self, user_matte: bool) -> bool {
        match self {
            RefineMethod::Off => false,
            RefineMethod::Auto => !user_matte,
            RefineMethod::Guided | RefineMethod::ClosedForm => true,
        }
    }

    /// The solver this method uses on the band. `Auto`'s is the colour-line fit: closed-form
    /// matting's alpha error is 11-14% lower on the bench (seeds 3, 4, no matte), but it loses
    /// 0.28-0.41 dB sRGB and 1.1-1.6 dB of linear PSNR on the linear inputs (it has no rule for
    /// lights behind the edge).
    pub fn solver(self) -> Solver {
        match self {
            RefineMethod::ClosedForm => Solver::ClosedForm,
            _ => Solver::Guided,
        }
    }
}

/// How the band's alpha is solved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// The colour-line fit to the known pixels of each window (this module).
    #[default]
    Guided,
    /// Closed-form matting (`stages::closed_form`).
    ClosedForm,
}

/// Unknown band added to the measured depth ramp on each side, pixels: a feathered or
/// antialiased edge spans about this much even where the depth map's edge is exact.
pub const MIN_BAND_PX: f32 = 2.0;
/// Ridge term of the colour fit (linear units squared): colour differences much smaller than
/// √ε ≈ 0.03 between the sides do not move alpha.
pub const EPS: f64 = 1e-3;
/// Share of a window's known count that weighs its model even when it saw one side only: with
/// no window seeing both sides a pixel still gets the known pixels' mean.
const ONE_SIDED: f64 = 0.01;
/// A window whose colour fit explains less of its known pixels' variance than this is not
/// trusted (textures on both sides that share colours).
const R2_LOW: f64 = 0.8;
/// From this share on, a window's fit is trusted fully.
const R2_FULL: f64 = 0.97;
/// How far beyond 0 … 1 a pixel's colour may predict alpha before its colour is taken for
/// neither side's (the prediction is then not used at all).
const OUTLIER: f64 = 0.5;
/// A pixel with a channel this bright (linear) is a light, not a mix of the sides' colours:
/// it keeps the prior (the guide clips it to white, where a bright side's line would take it).
const LIGHT: f32 = 0.98;
/// Tile side, pixels: tiles without unknown pixels cost nothing.
pub const TILE: usize = 64;

/// What the refinement did, for the report.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Refined {
    /// The unknown band's half-width inside the coarse outline, pixels.
    pub band_inside_px: f32,
    /// Its half-width outside, pixels.
    pub band_outside_px: f32,
    /// Window radius of the colour fit, pixels.
    pub radius: usize,
    /// Unknown pixels solved.
    pub unknown_px: usize,
    /// The solver.
    pub solver: Solver,
    /// The box `(x0, y0, x1, y1)` (exclusive ends) that holds the outline and every pixel of
    /// alpha ≥ 0.5 (None without an outline).
    #[serde(skip)]
    pub bbox: Option<(usize, usize, usize, usize)>,
}

/// The unknown band's half-widths (inside, outside) for the depth map's measured ramp.
pub fn band_for(edges: &EdgeWidths) -> (f32, f32) {
    (edges.inside_px + MIN_BAND_PX, edges.outside_px + MIN_BAND_PX)
}

/// Refines `alpha` (one channel, [0, 1]) on the edges of `photo` (linear RGB, same size): the
/// outline `alpha ≥ 0.5` moved to where the band's fitted alpha ([`fit`]) crosses 0.5, softened
/// as the depth split is (a Gaussian of `softness` px). The fit's own soft values are not kept:
/// fed to the layers they cost 0.2-1.4 dB on the bench (seeds 3, 4, 20 scenes each, no matte,
/// realistic depth; a partly transparent veil of the fit over textured background shows sharp
/// where the truth is blurred), the hard outline gains 0.2-0.4 dB sRGB there. Returns the matte
/// and what was done; a matte without an outline comes back unchanged.
pub fn refine(photo: &Image, alpha: &Image, band: (f32, f32), softness: f32, solver: Solver) -> (Image, Refined) {
    let (fitted, info) = fit(photo, alpha, band, solver);
    let Some(bb) = info.bbox.filter(|_| info.unknown_px > 0) else { return (fitted, info) };
    // Beyond the trimap's box every pixel is background: only the box (grown by the blur's
    // reach) is softened.
    let (w, h) = (alpha.width, alpha.height);
    let m = (3.0 * softness.max(0.0)).ceil() as usize + 1;
    let (x0, y0, x1, y1) = (bb.0.saturating_sub(m), bb.1.saturating_sub(m), (bb.2 + m).min(w), (bb.3 + m).min(h));
    let mut hard = fitted.crop(x0, y0, x1 - x0, y1 - y0);
    hard.map_inplace(|a| (a >= 0.5) as u8 as f32);
    let mut soft = gaussian_blur(&hard, softness);
    soft.map_inplace(|a| a.clamp(0.0, 1.0));
    let mut out = Image::new(w, h, 1);
    out.paste(&soft, x0, y0);
    (out, info)
}

/// The band's alpha fitted to the photo's colours (see the module header) in the band
/// `(inside, outside)` pixels around the outline `alpha ≥ 0.5`: known pixels exactly 0 or 1, the
/// band's pixels the fit, trusted as far as its windows explained their known pixels (else
/// `alpha`'s own value).
pub fn fit(photo: &Image, alpha: &Image, (inside, outside): (f32, f32), solver: Solver) -> (Image, Refined) {
    let (w, h) = (alpha.width, alpha.height);
    debug_assert_eq!((photo.width, photo.height, photo.channels, alpha.channels), (w, h, 3, 1));
    let hard: Vec<bool> = alpha.data.par_iter().map(|&a| a >= 0.5).collect();
    let radius = inside.max(outside).ceil() as usize + 1;
    let mut info = Refined { band_inside_px: inside, band_outside_px: outside, radius, unknown_px: 0, solver, bbox: None };
    let Some(trimap) = Trimap::new(&hard, w, h, (inside, outside)) else { return (alpha.clone(), info) };
    info.unknown_px = trimap.unknown.par_iter().filter(|&&u| u).count();
    info.bbox = Some(trimap.bbox);
    if info.unknown_px == 0 {
        return (alpha.clone(), info);
    }
    let guide = Guide(&photo.data);
    let mut out = Image::from_vec(w, h, 1, hard.par_iter().map(|&m| m as u8 as f32).collect()).expect("matte size");
    if solver == Solver::ClosedForm {
        // Known pixels their side, unknown ones start from the coarse matte.
        let start: Vec<f32> =
            out.data.par_iter().zip(&trimap.unknown).zip(&alpha.data).map(|((&k, &u), &a)| if u { a } else { k }).collect();
        for (i, a) in super::closed_form::solve(w, h, &trimap.unknown, &start, &|i| guide.at(i)) {
            out.data[i] = a;
        }
        return (out, info);
    }
    // Tiles of the trimap's box that hold unknown pixels, each solved from its own tables.
    let (bx0, by0, bx1, by1) = trimap.bbox;
    let tiles: Vec<(usize, usize)> = (by0..by1)
        .step_by(TILE)
        .flat_map(|y| (bx0..bx1).step_by(TILE).map(move |x| (x, y)))
        .filter(|&(x, y)| (y..(y + TILE).min(by1)).any(|yy| trimap.unknown[yy * w + x..yy * w + (x + TILE).min(bx1)].iter().any(|&u| u)))
        .collect();
    let solved: Vec<Vec<(usize, f32)>> = tiles
        .par_iter()
        .map(|&(x, y)| solve_tile(&guide, &alpha.data, &trimap, &hard, (w, h), (x, y, (x + TILE).min(bx1), (y + TILE).min(by1)), radius))
        .collect();
    for (i, a) in solved.into_iter().flatten() {
        out.data[i] = a;
    }
    (out, info)
}

/// The trimap [`fit`] solves for `alpha` and `band` (see the module header): 1 known foreground,
/// 0 known background, 0.5 unknown; None for a matte without an outline. For comparing other
/// matting methods on the same unknowns (`tests/matting_pymatting.rs`).
pub fn trimap(alpha: &Image, band: (f32, f32)) -> Option<Image> {
    let hard: Vec<bool> = alpha.data.par_iter().map(|&a| a >= 0.5).collect();
    let t = Trimap::new(&hard, alpha.width, alpha.height, band)?;
    let values = hard.iter().zip(&t.unknown).map(|(&m, &u)| if u { 0.5 } else { m as u8 as f32 }).collect();
    Image::from_vec(alpha.width, alpha.height, 1, values)
}

/// The fit's colours: the photo's linear values clipped to [0, 1], read where needed (a
/// frame-sized copy would be 12 bytes per pixel for the few percent of them in the band).
struct Guide<'a>(&'a [f32]);

impl Guide<'_> {
    #[inline]
    fn at(&self, i: usize) -> [f32; 3] {
        let p = &self.0[i * 3..i * 3 + 3];
        [p[0].clamp(0.0, 1.0), p[1].clamp(0.0, 1.0), p[2].clamp(0.0, 1.0)]
    }
}

/// Unknown pixels of the band around the outline of `hard`, and the box that holds them.
struct Trimap {
    unknown: Vec<bool>,
    bbox: (usize, usize, usize, usize),
}

impl Trimap {
    /// None when `hard` has no outline (empty or full).
    fn new(hard: &[bool], w: usize, h: usize, (inside, outside): (f32, f32)) -> Option<Trimap> {
        if !hard.par_iter().any(|&m| m) || hard.par_iter().all(|&m| m) {
            return None;
        }
        let reach = inside.max(outside) + 1.0;
        let bb @ (x0, y0, x1, y1) = grown_bbox(hard, w, h, reach)?;
        let bw = x1 - x0;
        let (to_out, to_in) = rayon::join(|| sq_distance_upto(hard, w, bb, false, reach), || sq_distance_upto(hard, w, bb, true, reach));
        let mut unknown = vec![false; w * h];
        unknown[y0 * w..y1 * w].par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (k, u) in row[x0..x1].iter_mut().enumerate() {
                let (i, j) = ((y0 + y) * w + x0 + k, y * bw + k);
                // A pixel's distance to the other side is at least 1: the band of half-width
                // `inside` holds the pixels within `inside + 0.5` of the outline's crack.
                *u = if hard[i] { root(to_out[j]) <= inside + 0.5 } else { root(to_in[j]) <= outside + 0.5 };
            }
        });
        // A part thinner than the band (a bar, a wire, as a smoothed depth map widens it) would
        // have no known foreground and keep its coarse outline: its ridge (the pixels farthest
        // from the outside, the middle the smoothing spread evenly) is taken as foreground
        // where no core is near.
        let core: Vec<bool> = hard.par_iter().zip(&unknown).map(|(&m, &u)| m && !u).collect();
        let near_core = dilate(&core, w, h, inside + 1.0);
        unknown[y0 * w..y1 * w].par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (k, u) in row[x0..x1].iter_mut().enumerate() {
                let i = (y0 + y) * w + x0 + k;
                if *u && hard[i] && !near_core[i] && is_ridge(&to_out, bw, (k, y), y1 - y0) {
                    *u = false;
                }
            }
        });
        Some(Trimap { unknown, bbox: bb })
    }
}

/// Whether box pixel `(x, y)` of the squared distances `d2` (row width `bw`, `bh` rows) is at
/// least as far from the outside as each of its 8 neighbours in the box.
fn is_ridge(d2: &[u32], bw: usize, (x, y): (usize, usize), bh: usize) -> bool {
    let here = d2[y * bw + x];
    (y.saturating_sub(1)..(y + 2).min(bh)).all(|yy| (x.saturating_sub(1)..(x + 2).min(bw)).all(|xx| d2[yy * bw + xx] <= here))
}

/// Number of summed planes per pixel: weight, weight·p, weight·I (3), weight·I·p (3),
/// weight·I·Iᵀ (6 of the symmetric 3×3).
const SUMS: usize = 14;
/// Planes of the model sums: c, c·b, c·a (3), and the weight a window would have with a
/// perfect fit (`c` over its fit's confidence).
const MODEL: usize = 6;

/// Summed-area tables of `planes` values per pixel over a `rw × rh` region: `(rw+1)·(rh+1)`
/// entries of `planes`, the first row and column zero.
fn summed_area(values: &[f64], planes: usize, rw: usize, rh: usize) -> Vec<f64> {
    let mut s = vec![0.0f64; (rw + 1) * (rh + 1) * planes];
    for y in 0..rh {
        let mut row = vec![0.0f64; planes];
        for x in 0..rw {
            let v = &values[(y * rw + x) * planes..][..planes];
            let (up, here) = s.split_at_mut(((y + 1) * (rw + 1) + x + 1) * planes);
            let above = &up[(y * (rw + 1) + x + 1) * planes..][..planes];
            for k in 0..planes {
                row[k] += v[k];
                here[k] = row[k] + above[k];
            }
        }
    }
    s
}

/// Sum of each plane over the region rows `y0..y1`, columns `x0..x1` of a table from
/// [`summed_area`] of width `rw`.
fn window_sum<const P: usize>(s: &[f64], rw: usize, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> [f64; P] {
    let at = |x: usize, y: usize| &s[(y * (rw + 1) + x) * P..][..P];
    let (a, b, c, d) = (at(x1, y1), at(x0, y1), at(x1, y0), at(x0, y0));
    std::array::from_fn(|k| a[k] - b[k] - c[k] + d[k])
}

/// Solves the unknown pixels of one tile (`x0, y0, x1, y1` in the frame): the window models
/// of every centre within `r` of it, from the known pixels within `2r`. Returns (frame index,
/// alpha) of the tile's unknown pixels.
fn solve_tile(
    guide: &Guide,
    coarse: &[f32],
    trimap: &Trimap,
    hard: &[bool],
    (w, h): (usize, usize),
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    r: usize,
) -> Vec<(usize, f32)> {
    // The region the windows read (tile grown by 2r) and the centres whose models are used
    // (tile grown by r), both clipped to the frame.
    let grow = |m: usize| (x0.saturating_sub(m), y0.saturating_sub(m), (x1 + m).min(w), (y1 + m).min(h));
    let (rx0, ry0, rx1, ry1) = grow(2 * r);
    let (cx0, cy0, cx1, cy1) = grow(r);
    let (rw, rh) = (rx1 - rx0, ry1 - ry0);
    let mut values = vec![0.0f64; rw * rh * SUMS];
    for y in ry0..ry1 {
        for x in rx0..rx1 {
            let i = y * w + x;
            if trimap.unknown[i] {
                continue;
            }
            let (p, g) = (hard[i] as u8 as f64, guide.at(i).map(f64::from));
            let v = &mut values[((y - ry0) * rw + x - rx0) * SUMS..][..SUMS];
            v[0] = 1.0;
            v[1] = p;
            for k in 0..3 {
                v[2 + k] = g[k];
                v[5 + k] = g[k] * p;
            }
            v[8..].copy_from_slice(&[g[0] * g[0], g[0] * g[1], g[0] * g[2], g[1] * g[1], g[1] * g[2], g[2] * g[2]]);
        }
    }
    let sums = summed_area(&values, SUMS, rw, rh);
    drop(values);
    // Each centre's model (a, b) and its weight c, as the planes c, c·b, c·a.
    let (cw, ch) = (cx1 - cx0, cy1 - cy0);
    let mut models = vec![0.0f64; cw * ch * MODEL];
    for y in cy0..cy1 {
        for x in cx0..cx1 {
            let win = (x.saturating_sub(r) - rx0, y.saturating_sub(r) - ry0, (x + r + 1).min(w) - rx0, (y + r + 1).min(h) - ry0);
            let s: [f64; SUMS] = window_sum(&sums, rw, win);
            let n = s[0];
            if n < 1.0 {
                continue;
            }
            let fg = s[1];
            let full = (fg.min(n - fg) + ONE_SIDED * n) / n;
            let (a, b, explained) = colour_line(&s);
            let c = full * confidence(explained);
            let m = &mut models[((y - cy0) * cw + x - cx0) * MODEL..][..MODEL];
            m[0] = c;
            m[5] = full;
            m[1] = c * b;
            for k in 0..3 {
                m[2 + k] = c * a[k];
            }
        }
    }
    let msums = summed_area(&models, MODEL, cw, ch);
    let mut out = Vec::new();
    for y in y0..y1 {
        for x in x0..x1 {
            let i = y * w + x;
            if !trimap.unknown[i] {
                continue;
            }
            let win = (
                x.saturating_sub(r).max(cx0) - cx0,
                y.saturating_sub(r).max(cy0) - cy0,
                (x + r + 1).min(cx1) - cx0,
                (y + r + 1).min(cy1) - cy0,
            );
            let m: [f64; MODEL] = window_sum(&msums, cw, win);
            let g = guide.at(i);
            let prior = coarse[i] as f64;
            // A light (clipped or brighter than white) is no side's colour mix.
            let light = g.iter().any(|&v| v >= LIGHT);
            let alpha = if m[0] > 1e-9 && m[5] > 0.0 && !light {
                let q = (m[1] + m[2] * g[0] as f64 + m[3] * g[1] as f64 + m[4] * g[2] as f64) / m[0];
                // Trusted as far as the windows behind it explained their known pixels, and as
                // far as the pixel's colour lies between the sides: a mix of the two predicts
                // 0 … 1, a colour of neither (a light behind the edge, clipped white) far
                // beyond, and keeps the prior.
                let beyond = (-q).max(q - 1.0).max(0.0);
                let trust = (m[0] / m[5]).min(1.0) * (1.0 - beyond / OUTLIER).max(0.0);
                prior + trust * (q.clamp(0.0, 1.0) - prior)
            } else {
                prior
            };
            out.push((i, alpha as f32));
        }
    }
    out
}

/// The ridge fit `p ≈ a·I + b` of one window from its sums (see [`SUMS`]): `a = (Σ + ε·U)⁻¹ cov`,
/// `b = p̄ − a·μ`, and the share of the known values' variance it explains (R², 0 … 1; 0 for a
/// window that saw one side only). The 3×3 system is symmetric positive definite (ε > 0),
/// solved by Cholesky.
fn colour_line(s: &[f64; SUMS]) -> ([f64; 3], f64, f64) {
    let n = s[0];
    let p = s[1] / n;
    let mu = [s[2] / n, s[3] / n, s[4] / n];
    let cov = [s[5] / n - mu[0] * p, s[6] / n - mu[1] * p, s[7] / n - mu[2] * p];
    let v = |k: usize, i: usize, j: usize| s[8 + k] / n - mu[i] * mu[j];
    // Variances can round a hair below zero: the ridge keeps the matrix definite.
    let m = [
        [v(0, 0, 0) + EPS, v(1, 0, 1), v(2, 0, 2)],
        [v(1, 0, 1), v(3, 1, 1) + EPS, v(4, 1, 2)],
        [v(2, 0, 2), v(4, 1, 2), v(5, 2, 2) + EPS],
    ];
    let a = solve3(m, cov).unwrap_or([0.0; 3]);
    let b = p - a[0] * mu[0] - a[1] * mu[1] - a[2] * mu[2];
    // Residual variance of the fit: var(p) − 2a·cov + aᵀΣa (Σ without the ridge).
    let var_p = p * (1.0 - p);
    let quad: f64 = (0..3).map(|i| (0..3).map(|j| a[i] * (m[i][j] - if i == j { EPS } else { 0.0 }) * a[j]).sum::<f64>()).sum();
    let residual = var_p - 2.0 * (a[0] * cov[0] + a[1] * cov[1] + a[2] * cov[2]) + quad;
    let explained = if var_p > 1e-9 { (1.0 - residual / var_p).clamp(0.0, 1.0) } else { 0.0 };
    (a, b, explained)
}

/// How far a window's model is trusted for the share `r2` of its known pixels' variance it
/// explains: not below [`R2_LOW`], fully from [`R2_FULL`], linearly between.
fn confidence(r2: f64) -> f64 {
    ((r2 - R2_LOW) / (R2_FULL - R2_LOW)).clamp(0.0, 1.0)
}

/// Solves the symmetric positive definite 3×3 system `m·x = v` by Cholesky; None when `m` is
/// not definite (a non-finite sum).
fn solve3(m: [[f64; 3]; 3], v: [f64; 3]) -> Option<[f64; 3]> {
    let l00 = m[0][0].sqrt();
    let l10 = m[1][0] / l00;
    let l20 = m[2][0] / l00;
    let l11 = (m[1][1] - l10 * l10).sqrt();
    let l21 = (m[2][1] - l20 * l10) / l11;
    let l22 = (m[2][2] - l20 * l20 - l21 * l21).sqrt();
    if !(l00 > 0.0 && l11 > 0.0 && l22 > 0.0) {
        return None;
    }
    let y0 = v[0] / l00;
    let y1 = (v[1] - l10 * y0) / l11;
    let y2 = (v[2] - l20 * y0 - l21 * y1) / l22;
    let x2 = y2 / l22;
    let x1 = (y1 - l21 * x2) / l11;
    let x0 = (y0 - l10 * x1 - l20 * x2) / l00;
    let x = [x0, x1, x2];
    x.iter().all(|v| v.is_finite()).then_some(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A photo of two colours split by a vertical edge at `edge` (fractional pixels: the pixel
    /// it crosses mixes both by area), and the coarse matte of an outline `off` px to its right.
    fn two_colours(w: usize, h: usize, edge: f32, off: f32, fg: [f32; 3], bg: [f32; 3]) -> (Image, Image, Vec<f32>) {
        let cover = |x: usize| (edge - x as f32).clamp(0.0, 1.0);
        let truth: Vec<f32> = (0..w * h).map(|i| cover(i % w)).collect();
        let photo: Vec<f32> = truth.iter().flat_map(|&a| (0..3).map(move |c| a * fg[c] + (1.0 - a) * bg[c])).collect();
        let coarse: Vec<f32> = (0..w * h).map(|i| (((i % w) as f32 + 0.5) < edge + off) as u8 as f32).collect();
        (Image::from_vec(w, h, 3, photo).unwrap(), Image::from_vec(w, h, 1, coarse).unwrap(), truth)
    }

    #[test]
    fn an_outline_off_the_photo_edge_moves_onto_it() {
        let (photo, coarse, truth) = two_colours(96, 40, 40.3, 3.0, [0.6, 0.3, 0.1], [0.05, 0.2, 0.5]);
        let (out, info) = fit(&photo, &coarse, (5.0, 2.0), Solver::Guided);
        assert!(info.unknown_px > 0);
        let err = |a: &[f32]| a.iter().zip(&truth).map(|(x, t)| (x - t).abs() as f64).sum::<f64>() / truth.len() as f64;
        assert!(err(&out.data) < 0.1 * err(&coarse.data), "refined {} vs coarse {}", err(&out.data), err(&coarse.data));
        // The mixed pixel keeps its share.
        assert!((out.data[10 * 96 + 40] - 0.3).abs() < 0.05, "{}", out.data[10 * 96 + 40]);
    }

    #[test]
    fn the_refined_outline_is_the_photo_edge_softened_as_the_split() {
        let (photo, coarse, truth) = two_colours(96, 40, 40.3, 3.0, [0.6, 0.3, 0.1], [0.05, 0.2, 0.5]);
        let (out, _) = refine(&photo, &coarse, (5.0, 2.0), 0.8, Solver::Guided);
        let split = gaussian_blur(&Image::from_vec(96, 40, 1, truth.iter().map(|&t| (t >= 0.5) as u8 as f32).collect()).unwrap(), 0.8);
        let worst = out.data.iter().zip(&split.data).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst < 1e-6, "{worst}");
    }

    /// A 2 px bar that a smoothed depth map widened to 8 px: the band swallows it whole, its
    /// ridge stays foreground, and the refined bar is the photo's.
    #[test]
    fn a_thin_part_narrows_to_the_photo_bar() {
        let (w, h) = (48, 32);
        let bar = |x: usize| (22..24).contains(&x);
        let photo: Vec<f32> = (0..w * h).flat_map(|i| if bar(i % w) { [0.1, 0.1, 0.15] } else { [0.7, 0.75, 0.8] }).collect();
        let photo = Image::from_vec(w, h, 3, photo).unwrap();
        let coarse = Image::from_vec(w, h, 1, (0..w * h).map(|i| (19..27).contains(&(i % w)) as u8 as f32).collect()).unwrap();
        let (out, info) = refine(&photo, &coarse, (5.0, 3.0), 0.0, Solver::Guided);
        assert!(info.unknown_px > 0);
        let row: Vec<f32> = out.data[16 * w..17 * w].to_vec();
        assert!((0..w).all(|x| row[x] == bar(x) as u8 as f32), "{row:?}");
    }

    #[test]
    fn a_matte_without_outline_comes_back_unchanged() {
        let photo = Image::filled(20, 10, 3, 0.4);
        for v in [0.0, 1.0] {
            let m = Image::filled(20, 10, 1, v);
            let (out, info) = refine(&photo, &m, (3.0, 3.0), 0.8, Solver::Guided);
            assert_eq!(out.data, m.data);
            assert_eq!(info.unknown_px, 0);
        }
    }

    #[test]
    fn colours_that_cannot_tell_the_sides_apart_keep_the_outline_where_it_was() {
        // One flat colour: no fit can move the edge; the band ramps around the coarse outline.
        let photo = Image::filled(64, 16, 3, 0.5);
        let coarse = Image::from_vec(64, 16, 1, (0..64 * 16).map(|i| ((i % 64) < 32) as u8 as f32).collect()).unwrap();
        let (out, _) = fit(&photo, &coarse, (4.0, 4.0), Solver::Guided);
        let row = &out.data[8 * 64..9 * 64];
        assert!(row.windows(2).all(|p| p[1] <= p[0] + 1e-6), "not monotone: {row:?}");
        assert!(row[31] > 0.5 && row[32] < 0.5, "{} {}", row[31], row[32]);
        assert!(out.all_finite());
    }

    #[test]
    fn extreme_colours_give_a_finite_matte_in_range() {
        let (mut photo, coarse, _) = two_colours(48, 24, 20.0, 2.0, [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]);
        photo.data.iter_mut().step_by(7).for_each(|v| *v = f32::MAX);
        let (out, _) = refine(&photo, &coarse, (3.0, 3.0), 0.8, Solver::Guided);
        assert!(out.data.iter().all(|a| (0.0..=1.0).contains(a)));
    }

    #[test]
    fn solve3_matches_a_known_system() {
        let m = [[4.0, 1.0, 0.5], [1.0, 3.0, 0.2], [0.5, 0.2, 2.0]];
        let x = [0.3, -1.2, 2.5];
        let v: [f64; 3] = std::array::from_fn(|i| (0..3).map(|j| m[i][j] * x[j]).sum());
        let got = solve3(m, v).unwrap();
        assert!(got.iter().zip(x).all(|(g, t)| (g - t).abs() < 1e-12), "{got:?}");
    }
}
