//! The physical profile in the fast kernel: each source spreads its premultiplied value over a
//! uniform disk of radius `r = K·|d|` with a one-pixel ramp edge, normalized to unit flux
//! ([`lens::disk_coverage`] / [`lens::disk_norm`]), as [`super::super::exact`]'s physical
//! kernel does tap by tap.
//!
//! Drawing: below `stencil_max` the exact taps ([`Stencil::coverage_weights`]); up to `2·r0`
//! (and for bright sources at any radius) the exact disk, its plateau as one span per row and
//! its ramp as taps ([`coverage_disk`], O(r) writes); beyond, the coarse grids, as for the
//! official footprint. Each finished pixel's sum `[P, A]` becomes the raw `[P_r, P_g, P_b, A,
//! V]` by [`lens::over_groups`] ([`finish_rows`]).
//!
//! In-layer depth groups (occlusion on): [`lens::over_groups`] fills a pixel's coverage front to
//! back, so the groups change a target only where the coverage reaching it exceeds 1 (below,
//! every group is taken whole and their sum is the one-group result, exactly) and the sources
//! reaching it lie at different depths. What exceeds 1 is a blurred part of a layer spilling
//! over a sharper part at another depth, and the groups exist so that a sharp surface receives
//! no light from a blurred part of its layer behind it (colour bleeding). So the targets
//! re-split are the sharp ones: the on-focal band of the official profile (CoC below
//! `band_coc`, about 2 px), with the same interpolation nodes over their disparities. Each
//! band stripe scatters, besides the one-group sum, the sources in front of the band targets
//! (weight `g(d_y - δ_k)`, [`lens::in_front`]) and those behind them (`g(δ_k - d_y)`) as
//! extra passes (see [`super::band`]); [`split_row`] interpolates both at a target's disparity
//! and takes the rest of the sum as the target's own surface, as [`lens::depth_groups`] splits
//! tap by tap in the exact kernel. The cost is that of the extra passes in the band stripes
//! (a few scatters, whatever the blur), so the band is kept small: a blurred target keeps one
//! group, a layer whose visible disparities span at most `NEAR` has no band, a sharp target
//! that no source more than `SPREAD` from its disparity can reach is not in it
//! ([`DepthReach`]), and a target whose coverage is at most `1 + COVER_EPS` is not re-split.
//! This replaced a gather of each re-split target's window, which cost up to 44x the
//! one-group render at CoC 64 and had to be switched off for large blurs.

use super::band::Side;
use super::binned;
use super::bright::is_bright;
use super::footprint::{EDGE, coverage_disk};
use super::scratch::Scratch;
use super::survey::Survey;
use super::{Counts, Ctx};
use crate::render::aperture::shape::POINT_COC_PX;
use crate::render::aperture::sources::ShapedSources;
use crate::render::layer::{A, CHANNELS, D, max_rgb};
use crate::render::lens::{self, disk_norm};
use crate::render::{RenderSettings, Role, raw};
use rayon::prelude::*;
use std::sync::atomic::Ordering;

/// Scatters the physical sources that reach rows `[y0, y1)` at full resolution (stencils and
/// exact disks) into the stripe accumulators: the one-group sum `sc.accs[0]`, and with band
/// `nodes` in the stripe the depth groups' passes ([`Ctx::dests`]).
// Out of line, as the official scan: profiles show the phase apart.
#[inline(never)]
pub(super) fn scan_sources(ctx: &Ctx, nodes: Option<(usize, usize)>, y0: usize, y1: usize, sc: &mut Scratch, counts: &Counts) {
    let (w, h) = (ctx.w, ctx.h);
    let pr = ctx.params;
    if !ctx.has_full && ctx.bright_max <= 0.0 {
        return;
    }
    // The widest full-resolution footprint: a disk (or bright disk) and its ramp; a shape's
    // tent reaches a pixel further.
    let is_disc = ctx.s.aperture.is_disc();
    let edge = if is_disc { EDGE } else { 1.0 };
    let pad0 = ctx.pad(ctx.full_max.max(ctx.bright_max) + edge);
    let stencil_p = ctx.stencil.p;
    let (y0i, y1i) = (y0 as i64, y1 as i64);
    let (mut n_st, mut n_sp, mut n_br, mut ops) = (0u64, 0u64, 0u64, 0u64);
    // The stencil in sc.stencil_w is for radius sc.stencil_sigma only once filled here.
    sc.stencil_w.clear();
    for sy in (y0i - pad0).max(-pad0)..(y1i + pad0).min(h as i64 + pad0) {
        let own_row = sy >= y0i && sy < y1i;
        for sx in -pad0..w as i64 + pad0 {
            let own = (own_row && sx >= 0 && sx < w as i64) as u64;
            let j = ctx.clamp_index(sx, sy);
            // Footprint from the drawn radius, flux norm from the true one.
            let (r, true_r) = (ctx.drawn(ctx.sigma[j]), ctx.sigma[j]);
            // A disc's footprint (stencil, binned or exact disk, bright or not) ends at
            // `r + EDGE`: a source that far from the stripe's rows or the image's columns adds
            // nothing. The pad is sized for the widest source, so most sources in it are such
            // (a third of a 2 MP preview's scan at background focus).
            if is_disc && (y0i - sy).max(sy + 1 - y1i).max(-sx).max(sx + 1 - w as i64) as f32 >= r + EDGE {
                continue;
            }
            if r >= 2.0 * pr.r0 && r > ctx.bright_max {
                continue;
            }
            let Some(v) = ctx.base(j) else { continue };
            let bright = is_bright(max_rgb(&v), v[3], ctx.bright_level);
            if r >= 2.0 * pr.r0 && !bright {
                continue;
            }
            ctx.dests(nodes, j, &mut sc.dests);
            if let (Some(g), Some(bins)) = (ctx.s.aperture.geometry(), ctx.bins.as_ref()) {
                // A non-disc aperture: every full-resolution source through its shape's
                // templates (per radius bin, point-reflected in front of the focal plane).
                n_sp += own;
                if true_r < POINT_COC_PX {
                    // Its own pixel's light whole: a cat's eye's gain there is divided out.
                    let g = if own == 1 { 1.0 / ctx.gain(sx as usize, sy as usize) } else { 1.0 };
                    for &(slot, f) in &sc.dests {
                        sc.accs[slot].pixels(sy, sx, sx, v.map(|c| c * f * g));
                    }
                    ops += sc.dests.len() as u64;
                } else {
                    // A cat's eye's cut from the source's position (a replicated source
                    // beyond the border takes its border pixel's, as the exact kernel).
                    let at = (sx.clamp(0, w as i64 - 1) as f32, sy.clamp(0, h as i64 - 1) as f32);
                    let (key, _) = bins.bin_flipped(r, ctx.d(j) > 0.0, at);
                    // Capped at the window: the flux of the true radius.
                    let factor = if r == true_r { 1.0 } else { g.norm(r) / g.norm(true_r) };
                    for &(slot, f) in &sc.dests {
                        sc.bins.push(slot, key, (sx, sy), v.map(|c| c * f * factor));
                    }
                }
                continue;
            }
            if r < pr.stencil_max {
                n_st += own;
                if r < 0.5 && r == true_r {
                    // In focus: its own pixel alone, weight `(r + ½) / disk_norm(r)`, exactly 1
                    // (the stencil's one tap); spares a stencil per source on a focused ramp.
                    for &(slot, f) in &sc.dests {
                        sc.accs[slot].tap_row(sx, sy, &[1.0], v.map(|c| c * f));
                    }
                    ops += sc.dests.len() as u64;
                    continue;
                }
                if true_r != sc.stencil_sigma || sc.stencil_w.is_empty() {
                    ctx.stencil.coverage_weights(r, disk_norm(true_r), &mut sc.stencil_w);
                    sc.stencil_sigma = true_r;
                }
                let (ra, rb) = ((y0i - sy).max(-stencil_p), (y1i - 1 - sy).min(stencil_p));
                for di in ra..=rb {
                    let (jm, ref e) = sc.stencil_w[(di + stencil_p) as usize];
                    if !e.is_empty() {
                        for &(slot, f) in &sc.dests {
                            sc.accs[slot].tap_row(sx - jm, sy + di, e, v.map(|c| c * f));
                        }
                        ops += (e.len() * sc.dests.len()) as u64;
                    }
                }
            } else if let Some(bins) = ctx.bins.as_ref().filter(|_| !bright && r == true_r && r < 2.0 * pr.r0) {
                // A medium disk: batched per radius bin, drawn with its row's run below.
                n_sp += own;
                // Factor 1: the bin's template carries the flux norm.
                let (k, _) = bins.bin(r);
                for &(slot, f) in &sc.dests {
                    sc.bins.push(slot, k, (sx, sy), v.map(|c| c * f));
                }
            } else {
                if bright && r >= 2.0 * pr.r0 {
                    n_br += own;
                } else {
                    n_sp += own;
                }
                let norm = disk_norm(true_r);
                for &(slot, f) in &sc.dests {
                    ops += coverage_disk(&mut sc.accs[slot], (sx, sy), r, norm, ctx.p as i64, v.map(|c| c * f), &mut sc.rim);
                }
            }
        }
        if let Some(bins) = &ctx.bins {
            ops += binned::flush(bins, &mut sc.templates, &mut sc.bins, &mut sc.accs);
        }
    }
    counts.stencil.fetch_add(n_st, Ordering::Relaxed);
    counts.span.fetch_add(n_sp, Ordering::Relaxed);
    counts.bright.fetch_add(n_br, Ordering::Relaxed);
    counts.ops.fetch_add(ops, Ordering::Relaxed);
}

/// The physical profile's input to [`finish_rows`] in place of eq. 4's visibility: the own
/// alpha of rows `[y0, y1)` (what a backdrop layer's visibility is at least). O(pixels).
pub(super) fn own_alpha_rows(ctx: &Ctx, y0: usize, y1: usize, out: &mut Vec<f32>) {
    out.clear();
    out.extend(ctx.img.data[y0 * ctx.w * CHANNELS..y1 * ctx.w * CHANNELS].chunks_exact(CHANNELS).map(|px| px[A]));
}

/// Turns the stripe's raw pixels `[ΣP_r, ΣP_g, ΣP_b, ΣA, own α]` of rows from `y0` on into
/// `[P_r, P_g, P_b, A, V]`: the sum composited by [`lens::over_groups`] as one group (the
/// band targets that needed depth groups were re-split by [`split_row`] and hold at most
/// full coverage, which one group leaves unchanged), `V = A`, or `max(A, own α)` for the
/// backdrop layer (see [`Role::Backdrop`]).
pub(super) fn finish_rows(ctx: &Ctx, raw: &mut [f32]) {
    for o in raw.chunks_exact_mut(raw::CHANNELS) {
        let sum = [o[0] as f64, o[1] as f64, o[2] as f64, o[raw::WEIGHT] as f64];
        let p = lens::over_groups(&[[0.0; 4], sum, [0.0; 4]]);
        let a = p[3] as f32;
        let vis = match ctx.role {
            Role::Front => a,
            Role::Backdrop => a.max(o[raw::VISIBILITY]),
        };
        o.copy_from_slice(&[p[0] as f32, p[1] as f32, p[2] as f32, a, vis]);
    }
}

/// Coverage above `1 + COVER_EPS` re-splits a band target into depth groups; below, the
/// one-group result differs from the groups' by at most `COVER_EPS` times the colours' range
/// (the groups can only drop that much coverage, of some colour, where one group rescales it).
/// Above the coarse grids' coverage error on a uniform opaque surface (between 0.01 and 0.03
/// on the timing scene at 1 MP, CoC 64).
const COVER_EPS: f64 = 1e-3;
/// A layer whose visible disparities all lie within `NEAR` is one surface: no band, one
/// group (the depth groups' weights differ across it by at most ~0.5% of a source's).
const NEAR: f32 = 0.002;

/// Whether a layer can need depth groups (and so the band passes): occlusion on, something
/// visible in a window wider than one pixel, and visible disparities spanning more than
/// `NEAR`. `p` is the window half-size.
pub(super) fn groups_wanted(s: &RenderSettings, p: usize, survey: &Survey) -> bool {
    s.occlusion && survey.visible > 0 && p > 0 && survey.d_hi - survey.d_lo > NEAR
}

/// A band target whose neighbourhood's visible disparities all lie within `SPREAD` of its own
/// keeps one group: there the depth groups' weights move by at most ~4% of a source's weight
/// across the sources, and the coverage barely exceeds 1 (a smoothly slanted surface).
const SPREAD: f32 = 0.02;
/// Side of a depth tile, pixels.
const TILE: usize = 8;

/// The range of visible disparities that can reach each `TILE × TILE` tile of a layer: the
/// tiles' own ranges dilated by the largest reach of a source. A band target whose tile's
/// range lies within `SPREAD` of its disparity cannot need depth groups, so it is not a band
/// target (its stripe may then need no band passes at all). 8 bytes per tile. O(pixels).
pub(super) struct DepthReach {
    /// Tiles per row.
    nx: usize,
    /// Per tile: lowest and highest relative disparity of a visible source that can reach it
    /// (lo > hi: none).
    lo: Vec<f32>,
    hi: Vec<f32>,
}

impl DepthReach {
    /// The reach ranges of a layer (`img`, relative to `focus`) whose sources reach at most
    /// `reach` pixels.
    pub(super) fn new(img: crate::ImageRef<'_>, focus: f32, reach: f32) -> Self {
        let (w, h) = (img.width, img.height);
        let (nx, ny) = (w.div_ceil(TILE), h.div_ceil(TILE));
        // Rows of tiles in parallel: the layer is read once, on every core (a serial read of a
        // 12 MP layer was ~80 ms on the render's critical path).
        let (mut lo, mut hi) = (vec![f32::INFINITY; nx * ny], vec![f32::NEG_INFINITY; nx * ny]);
        lo.par_chunks_mut(nx).zip(hi.par_chunks_mut(nx)).enumerate().for_each(|(ty, (lo, hi))| {
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                let row = &img.data[y * w * CHANNELS..(y + 1) * w * CHANNELS];
                for ((lo, hi), px) in lo.iter_mut().zip(hi.iter_mut()).zip(row.chunks(TILE * CHANNELS)) {
                    for p in px.chunks_exact(CHANNELS) {
                        if p[A] > 0.0 {
                            let d = p[D] - focus;
                            *lo = lo.min(d);
                            *hi = hi.max(d);
                        }
                    }
                }
            }
        });
        // Separable min / max over the tiles within `reach` pixels of any pixel of a tile.
        let rt = (reach.max(0.0).ceil() as usize).div_ceil(TILE);
        let dilate = |v: &[f32], pick: fn(f32, f32) -> f32| {
            let mut rows = v.to_vec();
            rows.par_chunks_mut(nx).zip(v.par_chunks(nx)).for_each(|(out, v)| {
                for (tx, o) in out.iter_mut().enumerate() {
                    let (a, b) = (tx.saturating_sub(rt), (tx + rt).min(nx - 1));
                    *o = v[a..=b].iter().copied().fold(v[tx], pick);
                }
            });
            let mut out = rows.clone();
            out.par_chunks_mut(nx).enumerate().for_each(|(ty, out)| {
                let (a, b) = (ty.saturating_sub(rt), (ty + rt).min(ny - 1));
                for (tx, o) in out.iter_mut().enumerate() {
                    *o = (a..=b).map(|t| rows[t * nx + tx]).fold(rows[ty * nx + tx], pick);
                }
            });
            out
        };
        DepthReach { nx, lo: dilate(&lo, f32::min), hi: dilate(&hi, f32::max) }
    }

    /// Whether sources more than `SPREAD` away from `d` (relative disparity) can reach pixel
    /// (x, y).
    #[inline]
    pub(super) fn mixed(&self, x: usize, y: usize, d: f32) -> bool {
        let t = (y / TILE) * self.nx + x / TILE;
        self.hi[t] - d > SPREAD || d - self.lo[t] > SPREAD
    }
}

/// Re-splits the band targets of image row `y` (`q < 1`) whose coverage exceeds
/// `1 + COVER_EPS` into the depth groups, in place in the row's raw pixels `out` (`[ΣP, ΣA]`
/// in, `[P, A]` composited by [`lens::over_groups`] out): in front (`front`, the front passes
/// interpolated at the target, 4 values per pixel), behind (`behind`), and the rest of the sum
/// as the target's own surface. The target's own tap is taken out of both sides, where the
/// passes weigh it as a source at its own depth, and given to its surface whole, as the exact
/// kernel does. Returns the number of targets re-split.
pub(super) fn split_row(ctx: &Ctx, y: usize, q: &[f32], front: &[f32], behind: &[f32], out: &mut [f32]) -> u64 {
    let Some(band) = ctx.band else { return 0 };
    let mut n = 0;
    for (x, o) in out.chunks_exact_mut(raw::CHANNELS).enumerate() {
        if q[x] >= 1.0 || (o[raw::WEIGHT] as f64) <= 1.0 + COVER_EPS {
            continue;
        }
        let i = y * ctx.w + x;
        let dt = ctx.d(i);
        let own = ctx.base(i).map_or([0.0; 4], |v| {
            let r = ctx.sigma[i];
            // With a cat's eye's gain, as every pass got it (a point source's own light was
            // divided by it when scattered).
            let g = ShapedSources::gain_of(r, ctx.gain(x, y));
            v.map(|c| c * lens::disk_coverage(r, 0.0) / disk_norm(r) * g)
        });
        let (sf, sb) = (band.interpolated(Side::Front, dt, dt), band.interpolated(Side::Behind, dt, dt));
        let mut groups = [[0f64; 4]; 3];
        for c in 0..4 {
            let f = (front[x * 4 + c] - own[c] * sf).max(0.0) as f64;
            let b = (behind[x * 4 + c] - own[c] * sb).max(0.0) as f64;
            groups[0][c] = f;
            groups[2][c] = b;
            groups[1][c] = (o[c] as f64 - f - b).max(0.0);
        }
        let p = lens::over_groups(&groups);
        for c in 0..4 {
            o[c] = p[c] as f32;
        }
        n += 1;
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What [`finish_rows`] relies on to skip the depth groups: wherever the coverage reaching a
    /// target is at most 1, [`lens::over_groups`] takes every group whole, so any split of the
    /// sum gives the one-group result; above 1 a split can differ by at most the excess times
    /// the colours' range.
    #[test]
    fn groups_change_nothing_below_full_coverage() {
        let mut x = 0x9E37_79B9_7F4A_7C15u64;
        let mut u = move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let total = 1.2 * u();
            let fr = [u(), u(), u()];
            let s: f64 = fr.iter().sum();
            let mut groups = [[0f64; 4]; 3];
            let mut sum = [0f64; 4];
            for (g, f) in groups.iter_mut().zip(fr) {
                let a = total * f / s;
                *g = [a * u(), a * u(), a * u(), a];
                for c in 0..4 {
                    sum[c] += g[c];
                }
            }
            let split = lens::over_groups(&groups);
            let one = lens::over_groups(&[[0.0; 4], sum, [0.0; 4]]);
            let excess = (total - 1.0).max(0.0);
            for c in 0..4 {
                assert!((split[c] - one[c]).abs() <= excess + 1e-12, "total {total}: {split:?} vs {one:?}");
            }
        }
    }
}
