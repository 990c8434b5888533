//! The stripes: each worker renders `STRIPE_ROWS` rows at a time. It scatters the
//! full-resolution sources that reach the stripe into reusable accumulators for every pass
//! at once (the tap weight is computed once and shared by `A`, `F` and the `U_k`), adds the
//! coarse levels, combines `q·A + (1-q)·B` and hands each finished raw pixel to the caller.

use super::band::{self, Side, band_coc, in_band};
use super::bright::is_bright;
use super::coarse::Coarse;
use super::footprint::{HARD_EDGE, SOFT_EDGE, STENCIL_TAIL, drawn_radius, equivalent_radius, rim_disk};
use super::scratch::Scratch;
use super::visibility::visibility_rows;
use super::{Counts, Ctx, physical};
use crate::render::layer::max_rgb;
use crate::render::lens::{Profile, density, energy, focal_defocus, in_front};
use crate::render::raw;
use crate::render::splat::{STRIPE_ROWS, Stripe, Window};
use rayon::prelude::*;
use std::sync::atomic::Ordering;

/// Renders every stripe in parallel and hands each finished raw pixel to `finish` with its
/// `stride` values of `out`. `empty`: nothing visible to scatter (only the visibility).
pub(super) fn render_stripes(
    ctx: &Ctx,
    coarse: &[Vec<Coarse>],
    empty: bool,
    out: &mut [f32],
    stride: usize,
    finish: &(dyn Fn(&raw::Pixel, &mut [f32]) + Sync),
    counts: &Counts,
) {
    // Scratch is pooled, not made per rayon split: a worker's first stripe sizes its buffers
    // and later stripes reuse them without new pages.
    let pool = std::sync::Mutex::new(Vec::<Scratch>::new());
    out.par_chunks_mut(STRIPE_ROWS * ctx.w * stride).enumerate().for_each(|(si, chunk)| {
        let mut sc = pool.lock().map(|mut p| p.pop()).ok().flatten().unwrap_or_default();
        if !sc.templates.shares(&ctx.templates) {
            sc.templates = super::binned::Templates::sharing(&ctx.templates);
        }
        let y0 = si * STRIPE_ROWS;
        let y1 = (y0 + STRIPE_ROWS).min(ctx.h);
        let mut sink = Sink { ctx, out: chunk, stride, finish };
        render_stripe(ctx, coarse, empty, y0, y1, &mut sc, &mut sink, counts);
        if let Ok(mut p) = pool.lock() {
            p.push(sc);
        }
    });
}

/// Where a stripe's finished rows go: each raw pixel of row `r` (of the stripe) to `finish`
/// with its `stride` values of `out` (the stripe's rows of the caller's buffer).
struct Sink<'a, 'o> {
    ctx: &'a Ctx<'a>,
    out: &'o mut [f32],
    stride: usize,
    finish: &'a (dyn Fn(&raw::Pixel, &mut [f32]) + Sync),
}

impl Sink<'_, '_> {
    /// Hands over row `r`'s raw pixels (`raw`, one row), finished first for the physical
    /// profile ([`physical::finish_rows`]).
    fn row(&mut self, r: usize, raw: &mut [f32]) {
        if self.ctx.s.profile == Profile::Physical {
            physical::finish_rows(self.ctx, raw);
        }
        let w = self.ctx.w;
        let out = &mut self.out[r * w * self.stride..(r + 1) * w * self.stride];
        for (px, o) in raw.chunks_exact(raw::CHANNELS).zip(out.chunks_exact_mut(self.stride)) {
            (self.finish)(px.try_into().expect("raw pixel"), o);
        }
    }
}

/// Renders rows `[y0, y1)` and hands each row's raw pixels to `sink` as it is finished: a
/// worker holds one row of them, not the stripe's (12.2 MP: 80 kB against 5 MB).
#[allow(clippy::too_many_arguments)]
fn render_stripe(ctx: &Ctx, coarse: &[Vec<Coarse>], empty: bool, y0: usize, y1: usize, sc: &mut Scratch, sink: &mut Sink, counts: &Counts) {
    let w = ctx.w;
    let rows = y1 - y0;
    let physical = ctx.s.profile == Profile::Physical;
    if physical {
        physical::own_alpha_rows(ctx, y0, y1, &mut sc.vis);
    } else {
        visibility_rows(ctx.img, &ctx.sigma, ctx.p, y0, y1, &mut sc.sat, &mut sc.vis);
    }
    if empty {
        let raw = &mut sc.raw;
        for r in 0..rows {
            raw.clear();
            raw.resize(w * raw::CHANNELS, 0.0);
            for (o, &v) in raw.chunks_exact_mut(raw::CHANNELS).zip(&sc.vis[r * w..(r + 1) * w]) {
                o[raw::VISIBILITY] = v;
            }
            sink.row(r, raw);
        }
        return;
    }

    // Targets of this stripe: q, and the band's nodes they need. q < 1 marks a band target;
    // the others count as q = 1 (occlusion ≡ 1). The physical profile has no q: its band
    // targets are marked 0.
    sc.q.clear();
    let bc = band_coc();
    let (mut blo, mut bhi) = (f32::INFINITY, f32::NEG_INFINITY);
    if ctx.band.is_none() {
        sc.q.resize(rows * w, 1.0);
    } else {
        for i in y0 * w..y1 * w {
            let d = ctx.d(i);
            // A physical target re-splits only where sources of other depths reach it.
            let q = if in_band(d, ctx.s, bc) && ctx.reach.as_ref().is_none_or(|r| r.mixed(i % w, i / w, d)) {
                blo = blo.min(d);
                bhi = bhi.max(d);
                if physical { 0.0 } else { focal_defocus(d, ctx.s.blur) }
            } else {
                1.0
            };
            sc.q.push(q);
        }
    }
    let any_pass = ctx.sides.iter().any(|sp| sp.has_full || sp.has_partial);
    let nodes = match ctx.band {
        Some(b) if blo <= bhi && any_pass => Some(b.nodes_for(blo, bhi)),
        _ => None,
    };
    // Slot 0, then per side used its full pass and one partial pass per node (band::slot).
    let n_acc = nodes.map_or(1, |(ka, kb)| 1 + ctx.sides_used().len() * (2 + kb - ka));
    if nodes.is_some() {
        counts.band_stripes.fetch_add(1, Ordering::Relaxed);
    }
    while sc.accs.len() < n_acc {
        sc.accs.push(Stripe::new(w));
    }
    for a in &mut sc.accs[..n_acc] {
        a.reset(y0, y1);
    }

    if physical {
        physical::scan_sources(ctx, nodes, y0, y1, sc, counts);
    } else {
        scan_sources(ctx, nodes, y0, y1, sc, counts);
    }
    combine_rows(ctx, coarse, nodes, y0, y1, sc, sink, counts);
    counts.ops.fetch_add((rows * w * n_acc) as u64, Ordering::Relaxed);
}

/// Scatters the full-resolution sources that reach rows `[y0, y1)` (exact stencils and
/// directly drawn disks) into the stripe accumulators `sc.accs`: `A`, and for a stripe with
/// band targets `F` and the `U_k` of `nodes`.
// Out of line (unchanged by the module split) so profiles show the stripe's phases apart.
#[inline(never)]
fn scan_sources(ctx: &Ctx, nodes: Option<(usize, usize)>, y0: usize, y1: usize, sc: &mut Scratch, counts: &Counts) {
    let (w, h) = (ctx.w, ctx.h);
    let rows = y1 - y0;
    let pr = ctx.params;
    if ctx.full_max <= 0.0 && ctx.bright_max <= 0.0 {
        // Every visible source lives on a coarse grid.
        return;
    }
    // The widest full-resolution footprint: a disk with its outer soft edge, a stencil, or a
    // bright source's exact rim.
    let reach0 = (equivalent_radius(ctx.full_max) + SOFT_EDGE[2].0)
        .max(pr.stencil_max.min(ctx.full_max) + STENCIL_TAIL)
        .max(ctx.bright_max + STENCIL_TAIL);
    let pad0 = ctx.pad(reach0);
    let lattice = Window::Lattice(ctx.p as i64);
    let stencil_p = ctx.stencil.p;
    let (y0i, y1i) = (y0 as i64, y1 as i64);
    let (mut n_st, mut n_sp, mut n_br, mut ops) = (0u64, 0u64, 0u64, 0u64);
    for sy in (y0i - pad0).max(-pad0)..(y1i + pad0).min(h as i64 + pad0) {
        let own_row = sy >= y0i && sy < y1i;
        for sx in -pad0..w as i64 + pad0 {
            // Counted once: in the stripe that owns it, not as a replicated border copy.
            let own = (own_row && sx >= 0 && sx < w as i64) as u64;
            let j = ctx.clamp_index(sx, sy);
            // Footprint from the drawn radius, energy density from the true one.
            let (sig, true_sig) = (drawn_radius(ctx.sigma[j], ctx.p), ctx.sigma[j]);
            if sig >= 2.0 * pr.r0 && sig > ctx.bright_max {
                continue;
            }
            let Some(v) = ctx.base(j) else { continue };
            let bright = is_bright(max_rgb(&v), v[3], ctx.bright_level);
            if sig >= 2.0 * pr.r0 && !bright {
                continue;
            }
            ctx.dests(nodes, j, &mut sc.dests);
            let dens = density(true_sig, ctx.unit);
            if sig >= pr.stencil_max && bright {
                // Bright (HDR) sources, whatever their radius: a disk's edge approximation errs
                // in proportion to the source's value (a highlight of 50 turns an LDR-sized
                // error into a visible one), so draw the exact footprint at full resolution.
                n_br += own;
                for &(slot, f) in &sc.dests {
                    ops += rim_disk(&mut sc.accs[slot], (sx, sy), sig, dens, ctx.p as i64, v.map(|c| c * f), &mut sc.rim);
                }
            } else if sig < pr.stencil_max {
                n_st += own;
                // Keyed by the true σ: two sources drawn with the same capped radius can
                // still differ in density.
                if true_sig != sc.stencil_sigma {
                    ctx.stencil.weights(sig, dens, &mut sc.stencil_w);
                    sc.stencil_sigma = true_sig;
                }
                // Visit only this stripe's rows.
                let (ra, rb) = ((y0i - sy).max(-stencil_p), (y1i - 1 - sy).min(stencil_p));
                for di in ra..=rb {
                    let (jm, ref e) = sc.stencil_w[(di + stencil_p) as usize];
                    if e.is_empty() {
                        continue;
                    }
                    for &(slot, f) in &sc.dests {
                        sc.accs[slot].tap_row(sx - jm, sy + di, e, v.map(|c| c * f));
                    }
                    ops += (e.len() * sc.dests.len()) as u64;
                }
            } else if let Some(bins) = ctx.bins.as_ref().filter(|_| sig < 2.0 * pr.r0) {
                // A medium disk: batched per radius bin, drawn with its row's run below.
                n_sp += own;
                let (k, factor) = bins.bin(sig);
                let scale = dens * factor;
                for &(slot, f) in &sc.dests {
                    sc.bins.push(slot, k, (sx, sy), v.map(|c| c * scale * f));
                }
            } else {
                n_sp += own;
                let rho = equivalent_radius(sig);
                // Small disks show their soft edge most: draw its profile there.
                let edge = if pr.soft_edge || sig < 2.0 * pr.stencil_max { &SOFT_EDGE[..] } else { &HARD_EDGE[..] };
                for &(off, wt) in edge {
                    for &(slot, f) in &sc.dests {
                        let area = sc.accs[slot].disk(sx as f32, sy as f32, rho + off, lattice, v.map(|c| c * dens * wt * f));
                        ops += (area > 0.0) as u64 * (2.0 * (rho + off)).ceil().min(rows as f32) as u64;
                    }
                }
            }
        }
        if let Some(bins) = &ctx.bins {
            ops += super::binned::flush(bins, &mut sc.templates, &mut sc.bins, &mut sc.accs);
        }
    }

    counts.stencil.fetch_add(n_st, Ordering::Relaxed);
    counts.span.fetch_add(n_sp, Ordering::Relaxed);
    counts.bright.fetch_add(n_br, Ordering::Relaxed);
    counts.ops.fetch_add(ops, Ordering::Relaxed);
}

/// Resolves the stripe accumulators row by row, adds the coarse levels and combines:
/// `A` everywhere; in the band `q·A + (1-q)·B` plus the centre correction (official) or the
/// depth groups (physical, [`physical::split_row`]). Hands each row to `sink`.
// Out of line, like scan_sources: profiles show the combine apart.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
fn combine_rows(
    ctx: &Ctx,
    coarse: &[Vec<Coarse>],
    nodes: Option<(usize, usize)>,
    y0: usize,
    y1: usize,
    sc: &mut Scratch,
    sink: &mut Sink,
    counts: &Counts,
) {
    const RAW: usize = raw::CHANNELS;
    let w = ctx.w;
    let (row_a, row_b, row_h, row_u, tmp) = (&mut sc.row_a, &mut sc.row_b, &mut sc.row_h, &mut sc.row_u, &mut sc.tmp);
    let out = &mut sc.raw;
    let mut split = 0u64;
    for r in 0..y1 - y0 {
        let y = y0 + r;
        row_a.clear();
        row_a.resize(w * 4, 0.0);
        sc.accs[0].add_row_to(r, row_a);
        for c in &coarse[0] {
            c.grid.add_upsampled_row(y, c.factor, row_a, tmp);
        }
        let q = &sc.q[r * w..(r + 1) * w];
        out.clear();
        out.resize(w * RAW, 0.0);
        'row: {
            // A cat's eye's targets normalize the light that reaches them (every pass alike).
            if ctx.cat_gains.is_some() {
                for (x, v) in row_a.chunks_exact_mut(4).enumerate() {
                    let g = ctx.gain(x, y);
                    v.iter_mut().for_each(|c| *c *= g);
                }
            }
            for (x, o) in out.chunks_exact_mut(RAW).enumerate() {
                o[..4].copy_from_slice(&row_a[x * 4..x * 4 + 4]);
                o[raw::VISIBILITY] = sc.vis[r * w + x];
            }
            let Some(nodes) = nodes else { break 'row };
            // The row's band targets: the band sums are needed there only.
            sc.band_x.clear();
            sc.band_x.extend((0..w).filter(|&x| q[x] < 1.0));
            let Some(&last) = sc.band_x.last() else { break 'row };
            let rows = BandRow { ctx, coarse, accs: &sc.accs, nodes, r, y, targets: &sc.band_x, end: last + 1, a: row_a };
            // The front passes interpolated at each band target, in row_b.
            rows.side(Side::Front, row_b, row_u, tmp);
            if ctx.s.profile == Profile::Physical {
                rows.side(Side::Behind, row_h, row_u, tmp);
                if ctx.cat_gains.is_some() {
                    for &x in &sc.band_x {
                        let g = ctx.gain(x, y);
                        row_b[x * 4..x * 4 + 4].iter_mut().chain(&mut row_h[x * 4..x * 4 + 4]).for_each(|c| *c *= g);
                    }
                }
                split += physical::split_row(ctx, y, q, row_b, row_h, out);
                break 'row;
            }
            for (x, o) in out.chunks_exact_mut(RAW).enumerate() {
                let qi = q[x];
                if qi >= 1.0 {
                    continue;
                }
                let i = y * w + x;
                let di = ctx.d(i);
                // The centre tap has occlusion 1, not q + (1-q)·g(0) as in A and B.
                let corr = ctx.base(i).map(|v| {
                    let e = energy(ctx.sigma[i], 0.0, ctx.unit) * (1.0 - qi) * (1.0 - in_front(di, di));
                    v.map(|c| c * e)
                });
                for c in 0..4 {
                    o[c] = qi * row_a[x * 4 + c] + (1.0 - qi) * row_b[x * 4 + c] + corr.map_or(0.0, |v| v[c]);
                }
            }
        }
        sink.row(r, out);
    }
    if split > 0 {
        counts.groups.fetch_add(split, Ordering::Relaxed);
    }
}

/// One row of a stripe with band targets: what [`BandRow::side`] reads.
struct BandRow<'a> {
    ctx: &'a Ctx<'a>,
    coarse: &'a [Vec<Coarse>],
    accs: &'a [Stripe],
    /// The stripe's band nodes `ka..=kb`.
    nodes: (usize, usize),
    /// Row within the stripe, and in the image.
    r: usize,
    y: usize,
    /// Columns of the row's band targets (ascending), and one past the last.
    targets: &'a [usize],
    end: usize,
    /// The row of `A` (what a complemented side is taken from).
    a: &'a [f32],
}

impl BandRow<'_> {
    /// One side's band sum at each band target of the row, interpolated at its disparity:
    /// the side's full pass plus `Σ_k hat_k(d_x)·U_k`, or `A` minus that where the side's
    /// passes hold its complement (4 values per pixel for the columns up to the last band
    /// target, into `out`; valid at the band targets only).
    fn side(&self, side: Side, out: &mut Vec<f32>, row_u: &mut Vec<f32>, tmp: &mut Vec<f32>) {
        let (ctx, (ka, kb)) = (self.ctx, self.nodes);
        let Some(band) = ctx.band else { return };
        let (m, n) = (kb - ka + 1, band.n);
        let sp = ctx.sides[side.index()];
        // Rows are resolved from column 0 (the spans' prefix sums) up to the last target.
        out.clear();
        out.resize(self.end * 4, 0.0);
        if sp.has_full {
            self.accs[band::slot(side, None, m)].add_row_to(self.r, out);
            for c in &self.coarse[band::slot(side, None, n)] {
                c.grid.add_upsampled_row(self.y, c.factor, out, tmp);
            }
        }
        if sp.has_partial {
            for k in ka..=kb {
                self.add_partial(side, k, out, row_u, tmp);
            }
        }
        if band.complemented(side) {
            for &x in self.targets {
                for c in 0..4 {
                    out[x * 4 + c] = self.a[x * 4 + c] - out[x * 4 + c];
                }
            }
        }
    }

    /// Adds `hat_k(d_x)·U_k` of `side` to `out` at each band target of the row.
    fn add_partial(&self, side: Side, k: usize, out: &mut [f32], row_u: &mut Vec<f32>, tmp: &mut Vec<f32>) {
        let (ctx, w, (ka, kb)) = (self.ctx, self.ctx.w, self.nodes);
        let Some(band) = ctx.band else { return };
        let (m, n) = (kb - ka + 1, band.n);
        row_u.clear();
        row_u.resize(self.end * 4, 0.0);
        self.accs[band::slot(side, Some(k - ka), m)].add_row_to(self.r, row_u);
        for c in &self.coarse[band::slot(side, Some(k), n)] {
            c.grid.add_upsampled_row(self.y, c.factor, row_u, tmp);
        }
        for &x in self.targets {
            let wk = band.hat(k, ctx.d(self.y * w + x));
            if wk > 0.0 {
                for c in 0..4 {
                    out[x * 4 + c] += wk * row_u[x * 4 + c];
                }
            }
        }
    }
}
