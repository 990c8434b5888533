//! Coarse grids: the large-blur sources of a pass, aggregated per cell and radius bin on a
//! grid `2^ℓ` times coarser than the image, where their radius is again below `2·r0`,
//! scattered there as disks (by radius-bin templates, [`super::binned`]) and upsampled
//! bilinearly by the stripes (cost O(1) per source).
//!
//! Level ℓ ≥ 1 takes drawn radii in `[r0·2^ℓ, r0·2^(ℓ+1))`; a layer keeps one grid per level
//! present and per pass, `16/4^ℓ` bytes per pixel each.

use super::band;
use super::binned::{Bins, RowBatch, Shape, SharedTemplates, Templates, flush};
use super::bright::{BRIGHT_MIN, is_bright};
use super::footprint::equivalent;
use super::{Counts, Ctx, Presence};
use crate::render::layer::max_rgb;
use crate::render::splat::{Grid4, Window, accumulate, flux_scale};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Coarse level of a source: level ℓ ≥ 1 takes σ in `[r0·2^ℓ, r0·2^(ℓ+1))`; None below `2·r0`.
#[inline]
pub(super) fn level_of(sigma: f32, r0: f32) -> Option<usize> {
    (sigma >= 2.0 * r0).then(|| ((sigma / r0).log2().floor() as usize).clamp(1, 63))
}

/// The coarse grids' radius bins are this fraction of the full-resolution ones
/// ([`super::FastParams::radius_bin`]), in grid pixels: every cell of a surface at one depth
/// has the same radius, so a bin's rounding moves the whole blurred edge of that surface
/// (physical ground-truth portrait, focus on the background, max abs error vs exact with
/// 8 / 16 centre positions: 0.043 / – at bins of 1/8 grid pixel, 0.031 / 0.029 at 1/64; 0.026
/// drawn one by one).
const COARSE_BIN: f32 = 1.0 / 8.0;

/// The radius bins of a non-disc aperture's coarse templates, grid pixels (see
/// `binned::SHAPE_PHASES`).
const COARSE_SHAPE_BIN: f32 = 1.0 / 8.0;

/// One coarse level of a pass: a grid `factor` times coarser than the image.
pub(super) struct Coarse {
    /// `2^ℓ`.
    pub(super) factor: f32,
    /// The level's scattered sums (R, G, B, W), in grid pixels.
    pub(super) grid: Grid4,
}

/// One aggregated source on a coarse grid: value-weighted centroid and equivalent radius (grid
/// pixels) and the summed value times density.
#[derive(Clone, Copy)]
struct Agg {
    cx: f32,
    cy: f32,
    rho: f32,
    v: [f32; 4],
    /// A non-disc aperture's sources in front of the focal plane (the shape point-reflected)
    /// aggregate apart from those behind it.
    flip: bool,
}

/// The coarse levels of every pass, indexed by slot (0 = `A`, 1 = `F`, `2 + k` = `U_k`); a
/// pass without sources of its class gets none. Adds the sources and writes to `counts`.
pub(super) fn passes(ctx: &Ctx, presence: &Presence, counts: &Counts) -> Vec<Vec<Coarse>> {
    let mut coarse = vec![levels(ctx, 0, presence.levels_all, counts)];
    let n = ctx.band.map_or(0, |b| b.n);
    if n == 0 {
        return coarse;
    }
    // In slot order (see `band::slot`): per side used, its full pass, then its partial ones.
    for &side in ctx.sides_used() {
        let sp = &presence.sides[side.index()];
        coarse.push(if sp.has_full { levels(ctx, band::slot(side, None, n), sp.levels_full, counts) } else { Vec::new() });
        for k in 0..n {
            coarse.push(if sp.has_partial { levels(ctx, band::slot(side, Some(k), n), sp.levels_partial, counts) } else { Vec::new() });
        }
    }
    coarse
}

/// The coarse levels of pass `slot`, for the levels in `mask` (bit ℓ = level ℓ present).
fn levels(ctx: &Ctx, slot: usize, mask: u64, counts: &Counts) -> Vec<Coarse> {
    let (w, h) = (ctx.w, ctx.h);
    let r0 = ctx.params.r0;
    let mut out = Vec::new();
    for level in 1..64u32 {
        if mask & (1 << level) == 0 {
            continue;
        }
        let f = (1u64 << level) as f32;
        let aggs = aggregate(ctx, level, slot);
        let n: usize = aggs.iter().map(|r| r.len()).sum();
        counts.coarse.fetch_add(n as u64, Ordering::Relaxed);
        if n == 0 {
            continue;
        }
        let (cw, ch) = ((w as f32 / f).ceil() as usize, (h as f32 / f).ceil() as usize);
        let mut grid = Grid4::new(cw, ch);
        // The aggregates' disks through radius-bin templates (contiguous adds per run of
        // cells, as the full-resolution medium disks): radii within a bin of the level's
        // range [r0, 2·r0) (equivalent radius, grid pixels), centres to 1/PHASES of a cell.
        let radius = ctx.p as f32 / f;
        let window = Window::Disk(radius);
        let shape = ctx.s.aperture.geometry();
        let bins = match shape {
            None => Bins::new(Shape::Coarse { window: radius }, ctx.params.radius_bin * COARSE_BIN, 0),
            // A shape's template costs O(ρ²) to build: bins of 1/8 grid pixel.
            Some(g) => Bins::new(Shape::CoarseAperture { shape: g, window: radius }, COARSE_SHAPE_BIN, 0)
                .with_cat_eye(ctx.s.aperture.cat_eye(w, h), f),
        };
        // An aggregate's full-resolution position, for a cat's eye's cut (clamped to the frame,
        // as a replicated source's).
        let at = |a: &Agg| (((a.cx + 0.5) * f - 0.5).clamp(0.0, w as f32 - 1.0), ((a.cy + 0.5) * f - 0.5).clamp(0.0, h as f32 - 1.0));
        let reach = 2.0 * r0 + 2.0;
        let pad = ctx.pad(ctx.sigma_max + 3.0) as f32;
        let writes = AtomicU64::new(0);
        let shared = std::sync::Arc::new(SharedTemplates::default());
        accumulate(&mut grid, |st| {
            let (y0, y1) = st.rows();
            let (mut batch, mut templates, mut places) = (RowBatch::default(), Templates::sharing(&shared), Vec::new());
            let mut ops = 0;
            for (i, row) in aggs.iter().enumerate() {
                // Centres of cell row i lie within ±1 of this coarse coordinate.
                let cy = (i as f32 * f - pad + 0.5 * f) / f - 0.5;
                if cy + 1.0 + reach < y0 as f32 || cy - 1.0 - reach > y1 as f32 {
                    continue;
                }
                places.clear();
                places.extend(row.iter().map(|a| bins.place(a.cx, a.cy, a.rho, a.flip, at(a))));
                for (k, (a, &(key, x, y, factor))) in row.iter().zip(&places).enumerate() {
                    // A template pays where a run forms (its neighbours in the row share it);
                    // an aggregate alone, or of bright light (the rounding errs in proportion
                    // to it; the bright sources' lowest level), is drawn at its own centre and
                    // radius.
                    let shared = |j: Option<usize>| j.and_then(|j| places.get(j)).is_some_and(|p| p.0 == key);
                    let alone = !(shared(k.checked_sub(1)) || shared(Some(k + 1))) || is_bright(max_rgb(&a.v), a.v[3], BRIGHT_MIN);
                    if alone && shape.is_none() {
                        // The value stands for the flux of a disk of area π·ρ².
                        let norm = flux_scale(a.rho, a.cy - a.cy.floor());
                        st.disk(a.cx, a.cy, a.rho, window, a.v.map(|c| c * norm));
                        ops += 1;
                    } else {
                        batch.push(0, key, (x, y), a.v.map(|c| c * factor));
                    }
                }
                ops += flush(&bins, &mut templates, &mut batch, std::slice::from_mut(st));
            }
            writes.fetch_add(ops, Ordering::Relaxed);
        });
        counts.ops.fetch_add(writes.into_inner() + (w * h) as u64, Ordering::Relaxed);
        out.push(Coarse { factor: f, grid });
    }
    out
}

/// Aggregates the sources of pass `slot` at coarse level `level` per cell and radius bin
/// (value-weighted centroid and radius, so a cell's light stays where it was); one Vec per
/// cell row. Bright sources are left out: the stripes draw them exactly.
fn aggregate(ctx: &Ctx, level: u32, slot: usize) -> Vec<Vec<Agg>> {
    let f = 1i64 << level;
    let ff = f as f32;
    let (lo, hi) = (ctx.params.r0 * ff, ctx.params.r0 * 2.0 * ff);
    let bins = ctx.params.r0 as usize;
    // A shape that is not point-symmetric: the sources in front of the focal plane in a second
    // set of bins.
    let shape = ctx.s.aperture.geometry();
    let cut = ctx.s.aperture.cat_eye(ctx.w, ctx.h).is_some();
    let sides = if shape.is_some_and(|g| !g.symmetric()) || cut { 2 } else { 1 };
    let pad = ctx.pad(ctx.sigma_max + 3.0);
    let (x0, x1) = (-pad, ctx.w as i64 + pad);
    let (y0, y1) = (-pad, ctx.h as i64 + pad);
    let cols = ((x1 - x0) + f - 1) / f;
    let rows = ((y1 - y0) + f - 1) / f;
    (0..rows)
        .into_par_iter()
        .map(|ci| {
            let mut out = Vec::new();
            // Per radius bin: Σ value·density (4), Σ weight·centre x, y, Σ weight·radius.
            let mut acc = vec![[0f64; 7]; bins * sides];
            for cj in 0..cols {
                let mut any = false;
                for sy in (y0 + ci * f)..(y0 + (ci + 1) * f).min(y1) {
                    for sx in (x0 + cj * f)..(x0 + (cj + 1) * f).min(x1) {
                        let j = ctx.clamp_index(sx, sy);
                        let sig = ctx.sigma[j];
                        let drawn = ctx.drawn(sig);
                        if drawn < lo || drawn >= hi {
                            continue;
                        }
                        let Some(v) = ctx.value(slot, j) else { continue };
                        if is_bright(max_rgb(&v), v[3], ctx.bright_level) {
                            // Drawn exactly at full resolution (stripe::scan_sources).
                            continue;
                        }
                        let dens = ctx.density(sig);
                        let wgt = (v[3] * dens) as f64;
                        if wgt <= 0.0 {
                            continue;
                        }
                        let front = sides == 2 && ctx.d(j) > 0.0;
                        let b = (((drawn - lo) / ff) as usize).min(bins - 1) + if front { bins } else { 0 };
                        let a = &mut acc[b];
                        for c in 0..4 {
                            a[c] += (v[c] * dens) as f64;
                        }
                        a[4] += wgt * ((sx as f32 + 0.5) / ff - 0.5) as f64;
                        a[5] += wgt * ((sy as f32 + 0.5) / ff - 0.5) as f64;
                        // A shape's coverage has its exact area: its own radius.
                        let rho = if shape.is_some() { drawn } else { equivalent(ctx.s.profile, drawn) };
                        a[6] += wgt * (rho / ff) as f64;
                        any = true;
                    }
                }
                if !any {
                    continue;
                }
                for (b, a) in acc.iter_mut().enumerate() {
                    if a[3] > 0.0 {
                        out.push(Agg {
                            cx: (a[4] / a[3]) as f32,
                            cy: (a[5] / a[3]) as f32,
                            rho: (a[6] / a[3]) as f32,
                            v: [a[0] as f32, a[1] as f32, a[2] as f32, a[3] as f32],
                            flip: b >= bins,
                        });
                    }
                    *a = [0.0; 7];
                }
            }
            out
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn level_brackets_the_radius() {
        let mut x = 0x5851_F42D_4C95_7F2Du64;
        for r0 in [4.0f32, 8.0, 16.0, 32.0, 256.0] {
            assert_eq!(level_of(2.0 * r0 - 1e-3, r0), None);
            assert_eq!(level_of(1.0, r0), None);
            for _ in 0..2000 {
                x ^= x >> 12;
                x ^= x << 25;
                x ^= x >> 27;
                let u = (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32;
                // Log-uniform radii from 2·r0 to 2^20·r0.
                let sigma = 2.0 * r0 * 2f32.powf(u * 19.0);
                let l = level_of(sigma, r0).expect("a coarse radius has a level");
                let f = (1u64 << l) as f32;
                assert!(l >= 1 && r0 * f <= sigma && sigma < 2.0 * r0 * f, "r0={r0} σ={sigma}: level {l}");
                // On that grid the radius is again one the stripes draw directly.
                assert!(sigma / f < 2.0 * r0);
            }
            // Every power of two starts its own level.
            for l in 1..20usize {
                let sigma = r0 * (1u64 << l) as f32;
                assert_eq!(level_of(sigma, r0), Some(l), "r0={r0} l={l}");
            }
        }
        assert_eq!(level_of(f32::MAX, 1.0), Some(63));
    }
}
