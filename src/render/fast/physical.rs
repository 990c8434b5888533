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
//! reaching it lie at different depths (with one depth, every source splits the same way and
//! each group has the same mean colour). Both are rare: a uniform surface has coverage 1, a
//! smoothly slanted one within a hair of it; what exceeds 1 is a blurred part of a layer
//! spilling over a sharper part at another depth. So the stripes scatter one group, as with
//! occlusion off, and [`finish_rows`] re-splits only the targets whose coverage exceeds
//! `1 + COVER_EPS` and whose neighbourhood spans more than `SPREAD` in disparity
//! ([`DepthTiles`]): it gathers the sources of the depth tiles that are not within `NEAR` of
//! the target's disparity tap by tap, with [`lens::depth_groups`] as the exact kernel does, and
//! splits the rest (the scattered sum minus the gathered part: the target's own surface) as
//! sources at the target's depth. A layer whose visible disparities span at most `NEAR` never
//! builds the tiles; a target that is not re-split costs one comparison.

use super::bright::is_bright;
use super::footprint::{EDGE, coverage_disk};
use super::stripe::Scratch;
use super::survey::Survey;
use super::{Counts, Ctx};
use crate::render::layer::{A, CHANNELS, D, max_rgb};
use crate::render::lens::{self, disk_norm};
use crate::render::{Role, raw};
use std::sync::atomic::Ordering;

/// Scatters the physical sources that reach rows `[y0, y1)` at full resolution (stencils and
/// exact disks) into the stripe accumulator `sc.accs[0]`.
// Out of line, as the official scan: profiles show the phase apart.
#[inline(never)]
pub(super) fn scan_sources(ctx: &Ctx, y0: usize, y1: usize, sc: &mut Scratch, counts: &Counts) {
    let (w, h) = (ctx.w, ctx.h);
    let pr = ctx.params;
    if !ctx.has_full && ctx.bright_max <= 0.0 {
        return;
    }
    // The widest full-resolution footprint: a disk (or bright disk) and its ramp.
    let pad0 = ctx.pad(ctx.full_max.max(ctx.bright_max) + EDGE);
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
            if r >= 2.0 * pr.r0 && r > ctx.bright_max {
                continue;
            }
            let Some(v) = ctx.base(j) else { continue };
            let bright = is_bright(max_rgb(&v), v[3], ctx.bright_level);
            if r >= 2.0 * pr.r0 && !bright {
                continue;
            }
            if r < pr.stencil_max {
                n_st += own;
                if true_r != sc.stencil_sigma || sc.stencil_w.is_empty() {
                    ctx.stencil.coverage_weights(r, disk_norm(true_r), &mut sc.stencil_w);
                    sc.stencil_sigma = true_r;
                }
                let (ra, rb) = ((y0i - sy).max(-stencil_p), (y1i - 1 - sy).min(stencil_p));
                for di in ra..=rb {
                    let (jm, ref e) = sc.stencil_w[(di + stencil_p) as usize];
                    if !e.is_empty() {
                        sc.accs[0].tap_row(sx - jm, sy + di, e, v);
                        ops += e.len() as u64;
                    }
                }
            } else {
                if bright && r >= 2.0 * pr.r0 {
                    n_br += own;
                } else {
                    n_sp += own;
                }
                ops += coverage_disk(&mut sc.accs[0], (sx, sy), r, disk_norm(true_r), ctx.p as i64, v, &mut sc.rim);
            }
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
/// `[P_r, P_g, P_b, A, V]`: the groups composited by [`lens::over_groups`] (one group, or the
/// depth groups where they matter: see the module doc), `V = A`, or `max(A, own α)` for the
/// backdrop layer (see [`Role::Backdrop`]).
pub(super) fn finish_rows(ctx: &Ctx, y0: usize, raw: &mut [f32], counts: &Counts) {
    let (mut n_groups, mut ops) = (0u64, 0u64);
    for (k, o) in raw.chunks_exact_mut(raw::CHANNELS).enumerate() {
        let sum = [o[0] as f64, o[1] as f64, o[2] as f64, o[raw::WEIGHT] as f64];
        let split = if ctx.groups_wanted && sum[3] > 1.0 + COVER_EPS && ctx.sigma[y0 * ctx.w + k] <= SHARP_TARGET_PX {
            ctx.groups.get_or_init(|| DepthTiles::new(ctx)).split(ctx, k % ctx.w, y0 + k / ctx.w, sum)
        } else {
            None
        };
        // Two calls, so that the common one-group case keeps its constant zero groups.
        let p = match split {
            Some((groups, taps)) => {
                n_groups += 1;
                ops += taps;
                lens::over_groups(&groups)
            }
            None => lens::over_groups(&[[0.0; 4], sum, [0.0; 4]]),
        };
        let a = p[3] as f32;
        let vis = match ctx.role {
            Role::Front => a,
            Role::Backdrop => a.max(o[raw::VISIBILITY]),
        };
        o.copy_from_slice(&[p[0] as f32, p[1] as f32, p[2] as f32, a, vis]);
    }
    if n_groups > 0 {
        counts.groups.fetch_add(n_groups, Ordering::Relaxed);
        counts.ops.fetch_add(ops, Ordering::Relaxed);
    }
}

/// Coverage above `1 + COVER_EPS` re-splits a target into depth groups; below, the one-group
/// result differs from the groups' by at most `COVER_EPS` times the colours' range (the groups
/// can only drop that much coverage, of some colour, where one group rescales it). Above the
/// coarse grids' coverage error on a uniform opaque surface (between 0.01 and 0.03 on the
/// timing scene at 1 MP, CoC 64: at 0.01 it re-split 7 168 targets of the slanted background,
/// whose groups do not matter, at 0.001 half the image and the render took minutes).
const COVER_EPS: f64 = 0.03;
/// Only targets this sharp (CoC radius, pixels) are re-split: the groups exist so that a sharp
/// or nearly sharp surface receives no light from a blurred part of its layer behind it
/// (colour bleeding, issue 11). A blurred target keeps one group, which also bounds the cost
/// of layers with depth edges under a blur (each re-split target gathers its whole window).
const SHARP_TARGET_PX: f32 = 2.0;
/// A re-split target gathers its whole window (up to (2·CoC + 1)² taps), so a layer whose
/// largest CoC exceeds this (pixels) keeps one group everywhere: a stopgap bound on the cost
/// until the re-split is scattered instead of gathered. Measured on the 12.2 MP end-to-end
/// scene (`scripts/e2e_timing.sh`, CoC 64): its background layer re-split 168 631 sharp
/// targets (the `SHARP_TARGET_PX` bound alone kept them all) and the render took 20.6 s; with
/// this bound, 0.82 s. The tests' in-layer cases (CoC 16 and 32) keep their groups.
const GROUPS_MAX_COC: f32 = 48.0;
/// A target whose neighbourhood's visible disparities all lie within `SPREAD` of its own keeps
/// one group: there the depth groups' weights move by at most ~4% of a source's weight across
/// the sources, and the coverage barely exceeds 1 (a smoothly slanted surface).
const SPREAD: f32 = 0.02;
/// Depth tiles whose visible disparities all lie within `NEAR` of the target's are split as
/// the target's own depth (their weights differ from it by at most ~0.5% of a source's).
const NEAR: f32 = 0.002;
/// Side of a depth tile, pixels.
const TILE: usize = 8;

/// The visible disparity range of every `TILE × TILE` tile of a layer, and that range dilated
/// by the largest reach of a source: what [`finish_rows`] needs to find the targets whose depth
/// groups matter and the sources to gather for them. 16 bytes per tile (1/4 byte per pixel).
pub(super) struct DepthTiles {
    /// Tiles per row and per column.
    nx: usize,
    ny: usize,
    /// Per tile: lowest and highest relative disparity of a visible pixel (lo > hi: none).
    lo: Vec<f32>,
    hi: Vec<f32>,
    /// The same over every tile a source reaching the tile can lie in.
    reach_lo: Vec<f32>,
    reach_hi: Vec<f32>,
    /// Largest tap offset (rows and columns) a source reaching a target can have.
    q: i64,
}

impl DepthTiles {
    /// Whether a layer can need depth groups at all: occlusion on and visible disparities
    /// spanning more than `NEAR`.
    pub(super) fn wanted(ctx: &Ctx, survey: &Survey) -> bool {
        ctx.s.occlusion && survey.visible > 0 && ctx.p > 0 && survey.d_hi - survey.d_lo > NEAR && ctx.sigma_max <= GROUPS_MAX_COC
    }

    /// The tiles of a layer (see [`DepthTiles::wanted`]), built by [`finish_rows`] on the first
    /// target whose coverage exceeds `1 + COVER_EPS` (a layer with none never builds them).
    /// O(pixels).
    fn new(ctx: &Ctx) -> Self {
        let (w, h) = (ctx.w, ctx.h);
        let (nx, ny) = (w.div_ceil(TILE), h.div_ceil(TILE));
        // Taps are strictly inside the window (r < p), and a source reaches r < radius + ½.
        let q = (ctx.p as i64 - 1).min((ctx.sigma_max + EDGE).ceil() as i64).max(0);
        let (mut lo, mut hi) = (vec![f32::INFINITY; nx * ny], vec![f32::NEG_INFINITY; nx * ny]);
        // Sequential: built from inside a stripe's worker (see `finish_rows`).
        for (ty, (lo, hi)) in lo.chunks_mut(nx).zip(hi.chunks_mut(nx)).enumerate() {
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                let row = &ctx.img.data[y * w * CHANNELS..(y + 1) * w * CHANNELS];
                for ((lo, hi), px) in lo.iter_mut().zip(hi.iter_mut()).zip(row.chunks(TILE * CHANNELS)) {
                    for p in px.chunks_exact(CHANNELS) {
                        if p[A] > 0.0 {
                            let d = p[D] - ctx.s.focus;
                            *lo = lo.min(d);
                            *hi = hi.max(d);
                        }
                    }
                }
            }
        }
        // Separable min / max over the tiles within q pixels of any pixel of a tile.
        let rt = (q as usize).div_ceil(TILE);
        let dilate = |v: &[f32], max: bool| {
            let pick = |a: f32, b: f32| if max { a.max(b) } else { a.min(b) };
            let mut rows = v.to_vec();
            for ty in 0..ny {
                for tx in 0..nx {
                    let (a, b) = (tx.saturating_sub(rt), (tx + rt).min(nx - 1));
                    rows[ty * nx + tx] = v[ty * nx + a..=ty * nx + b].iter().copied().fold(v[ty * nx + tx], pick);
                }
            }
            let mut out = rows.clone();
            for ty in 0..ny {
                for tx in 0..nx {
                    let (a, b) = (ty.saturating_sub(rt), (ty + rt).min(ny - 1));
                    out[ty * nx + tx] = (a..=b).map(|t| rows[t * nx + tx]).fold(rows[ty * nx + tx], pick);
                }
            }
            out
        };
        let (reach_lo, reach_hi) = (dilate(&lo, false), dilate(&hi, true));
        DepthTiles { nx, ny, lo, hi, reach_lo, reach_hi, q }
    }

    /// The depth groups of target (x, y), whose scattered one-group sum is `sum` (`[ΣP, ΣA]`),
    /// and the taps gathered; None where they cannot matter (the neighbourhood within `SPREAD`
    /// of the target's disparity). Gathers the sources of the tiles not within `NEAR` of the
    /// target's disparity as the exact kernel does (window taps, replicate padding,
    /// [`lens::depth_groups`]); the rest of `sum` (the target's own surface) is split as
    /// sources at the target's depth, the target's own tap as the same surface.
    // Out of line: rare, and finish_rows' loop stays small.
    #[inline(never)]
    fn split(&self, ctx: &Ctx, x: usize, y: usize, sum: [f64; 4]) -> Option<([[f64; 4]; 3], u64)> {
        let i = y * ctx.w + x;
        let dx = ctx.d(i);
        let t = (y / TILE) * self.nx + x / TILE;
        if self.reach_hi[t] - dx <= SPREAD && dx - self.reach_lo[t] <= SPREAD {
            return None;
        }
        let p = ctx.p as f32;
        let (xi, yi, q, tile) = (x as i64, y as i64, self.q, TILE as i64);
        let mut groups = [[0f64; 4]; 3];
        // The gathered sources' one-group sum, to take out of `sum`.
        let mut far = [0f64; 4];
        let mut taps = 0u64;
        // The last source's radius and norm, and the sum of a run of sources at one depth
        // (runs of equal values are common: the depth groups are evaluated once per run).
        let mut norm_memo = (f32::NAN, 0f32);
        let mut run = Run(f32::NAN, [0.0; 4]);
        // Whether a tile of sources at the target's depth was left to the rest.
        let mut any_near = false;
        for ty in (yi - q).div_euclid(tile)..=(yi + q).div_euclid(tile) {
            let cty = ty.clamp(0, self.ny as i64 - 1) as usize;
            for tx in (xi - q).div_euclid(tile)..=(xi + q).div_euclid(tile) {
                let ct = cty * self.nx + tx.clamp(0, self.nx as i64 - 1) as usize;
                let (lo, hi) = (self.lo[ct], self.hi[ct]);
                if lo > hi {
                    continue;
                }
                if lo >= dx - NEAR && hi <= dx + NEAR {
                    any_near = true;
                    continue;
                }
                for sy in (ty * tile).max(yi - q)..((ty + 1) * tile).min(yi + q + 1) {
                    let di = sy - yi;
                    for sx in (tx * tile).max(xi - q)..((tx + 1) * tile).min(xi + q + 1) {
                        let dj = sx - xi;
                        if di == 0 && dj == 0 {
                            continue;
                        }
                        let j = ctx.clamp_index(sx, sy);
                        let px = &ctx.img.data[j * CHANNELS..(j + 1) * CHANNELS];
                        if px[A] == 0.0 {
                            continue;
                        }
                        let radius = ctx.sigma[j];
                        let r2 = (di * di + dj * dj) as f32;
                        // Beyond the ramp's outer edge (cheap test first, then the exact one).
                        if r2 >= (radius + EDGE) * (radius + EDGE) + 1.0 {
                            continue;
                        }
                        let r = r2.sqrt();
                        let cov = lens::disk_coverage(radius, r);
                        if r >= p || cov == 0.0 {
                            continue;
                        }
                        // A source at the target's depth in a mixed tile: the rest, as its tile
                        // would be.
                        let dj_rel = px[D] - ctx.s.focus;
                        if (dj_rel - dx).abs() <= NEAR {
                            any_near = true;
                            continue;
                        }
                        if norm_memo.0 != radius {
                            norm_memo = (radius, disk_norm(radius));
                        }
                        if run.0 != dj_rel {
                            run.flush(dx, &mut groups, &mut far);
                            run.0 = dj_rel;
                        }
                        taps += 1;
                        // As the exact kernel: cov / norm, then alpha.
                        let wt = (px[A] * (cov / norm_memo.1)) as f64;
                        for (acc, v) in run.1.iter_mut().zip([wt * px[0] as f64, wt * px[1] as f64, wt * px[2] as f64, wt]) {
                            *acc += v;
                        }
                    }
                }
            }
        }
        run.flush(dx, &mut groups, &mut far);
        // The target's own tap: the same surface, whatever the split.
        let own = match ctx.base(i) {
            Some(v) => {
                let r = ctx.sigma[i];
                let wt = lens::disk_coverage(r, 0.0) / disk_norm(r);
                v.map(|c| (c * wt) as f64)
            }
            None => [0.0; 4],
        };
        // The rest: the sources of the target's own depth (fast sums, so clamped at 0). Where
        // every source was gathered there is none, and what the rest would hold is the fast
        // sum's own error (the coarse grids'), which must not join the front group.
        let mut near = [0f64; 4];
        for c in 0..4 {
            if any_near {
                near[c] = (sum[c] - far[c] - own[c]).max(0.0);
            }
            groups[1][c] += own[c];
        }
        for (acc, &gk) in groups.iter_mut().zip(&lens::depth_groups(dx, dx)) {
            for c in 0..4 {
                acc[c] += gk as f64 * near[c];
            }
        }
        Some((groups, taps))
    }
}

/// The gathered sources of one depth (`.0`, relative disparity) not yet split into groups:
/// their one-group sum `[ΣP, ΣA]` (`.1`).
struct Run(f32, [f64; 4]);

impl Run {
    /// Adds the run to the depth groups of a target at `dx` and to the gathered total `far`,
    /// and empties it.
    #[inline]
    fn flush(&mut self, dx: f32, groups: &mut [[f64; 4]; 3], far: &mut [f64; 4]) {
        if self.1[3] == 0.0 && self.1[..3].iter().all(|&v| v == 0.0) {
            return;
        }
        for (acc, g) in groups.iter_mut().zip(lens::depth_groups(self.0, dx)) {
            for (a, v) in acc.iter_mut().zip(self.1) {
                *a += g as f64 * v;
            }
        }
        for (f, v) in far.iter_mut().zip(self.1) {
            *f += v;
        }
        self.1 = [0.0; 4];
    }
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
