//! The span render's forward: per stripe of target rows, the sources scattered into their
//! depth bins, then each target's groups (physical) or on-focal slots (official).

use super::Target;
use super::bins::{Bins, Walk};
use super::ctx::{Ctx, Model};
use crate::render::lens;
use crate::render::raw;
use crate::render::splat::Stripe;

/// A forward worker's scratch: one stripe accumulator per depth bin (sized on first use),
/// which bins the current stripe uses, a row of values and the edge taps.
pub(super) struct Scratch {
    pub(super) stripes: Vec<Stripe>,
    pub(super) walk: Walk,
    /// Per bin, the columns `[x0, x1)` the stripe's sources of that bin reach (None: unused).
    pub(super) used: Vec<Option<(usize, usize)>>,
    /// Per bin, the sources (padded positions) whose first bin it is and that reach the stripe.
    pub(super) by_bin: Vec<Vec<(i64, i64)>>,
    pub(super) row: Vec<f32>,
    pub(super) e: Vec<f32>,
}

impl Scratch {
    pub(super) fn new(w: usize, bins: &Bins) -> Self {
        Scratch {
            stripes: (0..bins.count).map(|_| Stripe::new(w)).collect(),
            walk: Walk::new(bins),
            used: vec![None; bins.count],
            by_bin: vec![Vec::new(); bins.count],
            row: vec![0.0; w * 4],
            e: Vec::new(),
        }
    }
}

/// Renders target rows `[y0, y1)`: scatters the sources that reach them into their bins,
/// then per target sums the bins into groups and writes the raw pixel, keeping the groups and
/// their depth derivative: physical, the groups filled, `[P, A, 1]`; official, the two slots
/// mixed by `q`, `[ΣRGB, W, 1]`.
pub(super) fn forward_stripe(ctx: &Ctx, fill_width: f64, y0: usize, y1: usize, sc: &mut Scratch, out: &mut [f32], tg: &mut [Target]) {
    let w = ctx.w;
    let rows = ctx.source_rows(y0, y1);
    // Survey: the bins this stripe's sources use, and the columns they reach (a bin holds a
    // few blocks of depth: its rows are summed and gathered there only).
    sc.used.iter_mut().for_each(|u| *u = None);
    sc.by_bin.iter_mut().for_each(Vec::clear);
    for sy in rows.clone() {
        for sx in -ctx.pad..w as i64 + ctx.pad {
            let j = ctx.clamp_index(sx, sy);
            let (lo, hi, ..) = ctx.extent(j, sy);
            let reach = sy - lo;
            let (xa, xb) = ((sx - reach).max(0), (sx + reach).min(w as i64 - 1));
            if hi < y0 as i64 || lo >= y1 as i64 || xa > xb {
                continue;
            }
            let entries = ctx.bins.locate(ctx.d[j]);
            for (b, hat, _) in entries {
                if hat != 0.0 {
                    let e = sc.used[b].get_or_insert((xa as usize, xb as usize + 1));
                    *e = (e.0.min(xa as usize), e.1.max(xb as usize + 1));
                }
            }
            sc.by_bin[entries[0].0].push((sx, sy));
        }
    }
    for (st, u) in sc.stripes.iter_mut().zip(&sc.used) {
        if u.is_some() {
            st.reset(y0, y1);
        }
    }
    // Scatter, bin after bin: a stripe's bins together are far larger than the cache, and
    // sources drawn in raster order wrote to a different pair of them each.
    for &(sx, sy) in sc.by_bin.iter().flatten() {
        let j = ctx.clamp_index(sx, sy);
        let v = ctx.value(j);
        match ctx.bins.locate(ctx.d[j]) {
            // Both bins at once: the footprint's geometry and rim computed once.
            [(b0, h0, _), (_, h1, _)] if h0 != 0.0 && h1 != 0.0 => {
                let (lo, hi) = sc.stripes.split_at_mut(b0 + 1);
                ctx.draw([&mut lo[b0], &mut hi[0]], (sx, sy), j, [v.map(|c| c * h0), v.map(|c| c * h1)], &mut sc.e);
            }
            [(b0, h0, _), (b1, h1, _)] => {
                let (b, hat) = if h0 != 0.0 { (b0, h0) } else { (b1, h1) };
                ctx.draw([&mut sc.stripes[b]], (sx, sy), j, [v.map(|c| c * hat)], &mut sc.e);
            }
        }
    }
    // Gather: bins → groups → fill (physical) or on-focal mix (official).
    let centre = ctx.bins.centre_split();
    for (r, y) in (y0..y1).enumerate() {
        let tg = &mut tg[r * w..(r + 1) * w];
        let drow = &ctx.d[y * w..(y + 1) * w];
        sc.walk.targets(drow);
        for b in 0..ctx.bins.count {
            let Some((x0, x1)) = sc.used[b] else { continue };
            sc.row[x0 * 4..x1 * 4].fill(0.0);
            sc.stripes[b].add_row_range_to(r, x0, x1, &mut sc.row);
            sc.walk.goto(&ctx.bins, b);
            for (x, t) in tg.iter_mut().enumerate().take(x1).skip(x0) {
                let v = &sc.row[x * 4..x * 4 + 4];
                if v.iter().all(|&c| c == 0.0) {
                    continue;
                }
                let (split, dsplit) = sc.walk.split(&ctx.bins, x, drow[x]);
                for k in 0..3 {
                    for (c, &vc) in v.iter().enumerate() {
                        t.groups[k][c] += (split[k] * vc) as f64;
                        t.dgroups[k][c] -= (dsplit[k] * vc) as f64;
                    }
                }
            }
        }
        for (x, t) in tg.iter_mut().enumerate() {
            let i = y * w + x;
            let (u, du_dr, eta, deta) = ctx.own(i);
            let du = du_dr * ctx.dr_dd[i] as f64;
            if u != 0.0 || du != 0.0 {
                let v = ctx.value(i);
                for k in 0..3 {
                    let keep = centre[k] - eta[k];
                    for (c, &vc) in v.iter().enumerate() {
                        t.groups[k][c] += u * vc as f64 * keep;
                        t.dgroups[k][c] += vc as f64 * (du * keep - u * deta[k]);
                    }
                }
            }
            let p = match ctx.model {
                Model::Physical { .. } => lens::over_groups_smooth(&t.groups, fill_width),
                // `[ΣRGB, W]` of the exact kernel: `O = q + (1 - q)·f` summed.
                Model::Official { .. } => {
                    let q = ctx.defocus(i).0 as f64;
                    std::array::from_fn(|c| q * t.groups[1][c] + (1.0 - q) * t.groups[0][c])
                }
            };
            // Physical: `[P, A]` and the backdrop's visibility max(A, α) with α = 1; official:
            // `[ΣRGB, W]` and the box visibility of alpha 1.
            out[(r * w + x) * raw::CHANNELS..(r * w + x + 1) * raw::CHANNELS].copy_from_slice(&[
                p[0] as f32,
                p[1] as f32,
                p[2] as f32,
                p[3] as f32,
                1.0,
            ]);
        }
    }
}
