//! The span render's VJP on the source side: each source's gathers of its bins' cotangents
//! over its footprint (row prefix sums at the span ends, the rim tap by tap).

use super::SourceGrad;
use super::bins::Walk;
use super::ctx::Ctx;
use crate::render::fast::footprint::rim_row;

/// The source gradients of source rows `[sy0, sy1)` (padded rows included; each gradient goes
/// to the pixel the source replicates). Sources are bucketed by the first of their two bins;
/// bins are visited in increasing order, each bin's cotangent `gB_b` built once as row prefix
/// sums over the box its sources reach (two buffers in turn: bins `b` and `b + 1`), and each
/// source gathers both of its bins in one walk over its footprint.
pub(super) fn backward_stripe(ctx: &Ctx, gg: &[[[f64; 4]; 3]], sy0: i64, sy1: i64) -> Vec<(usize, SourceGrad)> {
    let (w, h) = (ctx.w, ctx.h);
    let (r0, r1) = ((sy0 - ctx.pad).max(0) as usize, ((sy1 + ctx.pad).min(h as i64)).max(0) as usize);
    if r0 >= r1 {
        return Vec::new();
    }
    let cols = -ctx.pad..w as i64 + ctx.pad;
    // Per bin, the box of target pixels (rows, columns; inclusive) the stripe's sources of that
    // bin reach: its prefix rows are built there only (a bin holds a few blocks of depth).
    let mut boxes: Vec<Option<[i64; 4]>> = vec![None; ctx.bins.count];
    let mut by_bin: Vec<Vec<(i64, i64)>> = vec![Vec::new(); ctx.bins.count];
    for sy in sy0..sy1 {
        for sx in cols.clone() {
            let j = ctx.clamp_index(sx, sy);
            let (lo, hi, ..) = ctx.extent(j, sy);
            let reach = sy - lo;
            let bx = [lo.max(r0 as i64), hi.min(r1 as i64 - 1), (sx - reach).max(0), (sx + reach).min(w as i64 - 1)];
            if bx[0] > bx[1] || bx[2] > bx[3] {
                continue;
            }
            let entries = ctx.bins.locate(ctx.d[j]);
            by_bin[entries[0].0].push((sx, sy));
            for (b, ..) in entries.into_iter().take(if ctx.bins.grouped { 2 } else { 1 }) {
                let e = boxes[b].get_or_insert(bx);
                *e = [e[0].min(bx[0]), e[1].max(bx[1]), e[2].min(bx[2]), e[3].max(bx[3])];
            }
        }
    }
    let stride = (w + 1) * 4;
    let mut bufs = [vec![0f64; (r1 - r0) * stride], vec![0f64; (r1 - r0) * stride]];
    let mut built = [None, None];
    let mut walk = Walk::new(&ctx.bins);
    walk.targets(&ctx.d[r0 * w..r1 * w]);
    let mut out = Vec::new();
    for (b0, sources) in by_bin.iter().enumerate() {
        if sources.is_empty() {
            continue;
        }
        let pair = if ctx.bins.grouped { 2 } else { 1 };
        for b in b0..b0 + pair {
            if built[b % 2] != Some(b) {
                let bx = boxes[b].expect("a box for every bin a source reads");
                walk.goto(&ctx.bins, b);
                bin_prefix(ctx, gg, &walk, bx, r0, &mut bufs[b % 2]);
                built[b % 2] = Some(b);
            }
        }
        for &(sx, sy) in sources {
            let j = ctx.clamp_index(sx, sy);
            let entries = ctx.bins.locate(ctx.d[j]);
            let (n, dn) = (ctx.norm[j].0 as f64, ctx.norm[j].1 as f64);
            let v = ctx.value(j);
            let dot = |a: &[f64; 4]| (0..4).map(|c| a[c] * v[c] as f64).sum::<f64>();
            let mut g = SourceGrad::default();
            let mut add = |(s, t): ([f64; 4], [f64; 4]), (_, hat, dhat): (usize, f32, f32)| {
                let (hat, sv, tv) = (hat as f64, dot(&s) / n, dot(&t));
                let gr = hat * (tv / n - sv * dn / n);
                g.d += dhat as f64 * sv + gr * ctx.dr_dd[j] as f64;
                g.r += gr;
                for (o, sc) in g.c.iter_mut().zip(&s) {
                    *o += hat * sc / n;
                }
            };
            if ctx.bins.grouped {
                let [a, b] = gather(ctx, [&bufs[b0 % 2], &bufs[(b0 + 1) % 2]], r0, r1, j, (sx, sy));
                add(a, entries[0]);
                add(b, entries[1]);
            } else {
                let [a] = gather(ctx, [&bufs[0]], r0, r1, j, (sx, sy));
                add(a, entries[0]);
            }
            out.push((j, g));
        }
    }
    out
}

/// Bin cotangent `gB_b(x) = Σ_k γ_k(δ_b, d_x)·ḡ_k(x)` (the walk at bin `b`) as row prefix sums
/// over the box `[ya, yb] × [xa, xb]` of `buf` (rows from `r0`): `buf[row][x + 1] =
/// Σ_{xa ≤ x' ≤ x} gB_b(x')`, `buf[row][xa] = 0`; the gathers read nothing outside the box.
fn bin_prefix(ctx: &Ctx, gg: &[[[f64; 4]; 3]], walk: &Walk, [ya, yb, xa, xb]: [i64; 4], r0: usize, buf: &mut [f64]) {
    let (w, stride) = (ctx.w, (ctx.w + 1) * 4);
    for y in ya as usize..=yb as usize {
        let ri = y - r0;
        let row = &mut buf[ri * stride..(ri + 1) * stride];
        row[xa as usize * 4..xa as usize * 4 + 4].fill(0.0);
        let mut acc = [0f64; 4];
        for x in xa as usize..=xb as usize {
            let i = y * w + x;
            let g = &gg[i];
            if g.iter().any(|k| k.iter().any(|&v| v != 0.0)) {
                let (split, _) = walk.split(&ctx.bins, ri * w + x, ctx.d[i]);
                for (a, c) in acc.iter_mut().zip(0..4) {
                    *a += (0..3).map(|k| split[k] as f64 * g[k][c]).sum::<f64>();
                }
            }
            row[(x + 1) * 4..(x + 2) * 4].copy_from_slice(&acc);
        }
    }
}

/// One source's gather of `N` bin cotangents (row prefix sums `pres[k]` of target rows
/// `[r0, r1)`): per bin `(Σ_x cov·gB, Σ_x cov'·gB)` per channel over the pixels its disk covers,
/// the plateau from the prefix sums at the span ends (cov = 1, cov' = 0 there), the edge tap by
/// tap (its coverage computed once for the `N` bins). The same pixels as the scatter
/// ([`rim_row`]).
#[inline]
fn gather<const N: usize>(ctx: &Ctx, pres: [&[f64]; N], r0: usize, r1: usize, j: usize, (sx, sy): (i64, i64)) -> [([f64; 4], [f64; 4]); N] {
    let (w, stride) = (ctx.w as i64, (ctx.w + 1) * 4);
    let (lo, hi, reach, inner) = ctx.extent(j, sy);
    let r = ctx.radius[j];
    let mut acc = [([0f64; 4], [0f64; 4]); N];
    for row in lo.max(r0 as i64)..=hi.min(r1 as i64 - 1) {
        let dy = row - sy;
        let Some((xi, xo)) = rim_row(reach, inner, ctx.p, dy) else { continue };
        let at = (row as usize - r0) * stride;
        if xi >= 0 {
            let (a, b) = ((sx - xi).max(0), (sx + xi).min(w - 1));
            if a <= b {
                let (a, b) = (a as usize, b as usize);
                for ((s, _), pre) in acc.iter_mut().zip(&pres) {
                    for c in 0..4 {
                        s[c] += pre[at + (b + 1) * 4 + c] - pre[at + a * 4 + c];
                    }
                }
            }
        }
        let dyf = (dy * dy) as f32;
        for dx in (xi + 1).max(0)..=xo {
            let rho = ((dx * dx) as f32 + dyf).sqrt();
            let (cov, dcov) = ctx.rim(r, rho);
            let (cov, dcov) = (cov as f64, dcov as f64);
            if cov == 0.0 && dcov == 0.0 {
                continue;
            }
            let sides: &[i64] = if dx == 0 { &[0] } else { &[dx, -dx] };
            for &o in sides {
                let x = sx + o;
                if x < 0 || x >= w {
                    continue;
                }
                let x = at + x as usize * 4;
                for ((s, t), pre) in acc.iter_mut().zip(&pres) {
                    for c in 0..4 {
                        let g = pre[x + 4 + c] - pre[x + c];
                        s[c] += cov * g;
                        t[c] += dcov * g;
                    }
                }
            }
        }
    }
    acc
}
