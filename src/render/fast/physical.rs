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
//! In-layer depth groups: the fast kernel composites one group per pixel (every source as the
//! same surface), which is the exact kernel's result with occlusion off, and its approximation
//! with occlusion on (exact where a layer's depth varies by less than the groups' 0.1 margin).

use super::bright::is_bright;
use super::footprint::{EDGE, coverage_disk};
use super::stripe::Scratch;
use super::{Counts, Ctx};
use crate::render::layer::{A, CHANNELS, max_rgb};
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

/// Turns the stripe's raw pixels `[ΣP_r, ΣP_g, ΣP_b, ΣA, own α]` into `[P_r, P_g, P_b, A, V]`:
/// the one group composited by [`lens::over_groups`] (coverage above 1 normalized), `V = A`,
/// or `max(A, own α)` for the backdrop layer (see [`Role::Backdrop`]).
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
