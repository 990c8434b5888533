//! The fast per-layer kernel: the same model as [`super::exact`], at a near-constant cost
//! per pixel.
//!
//! The on-focal occlusion splits as `O(y,x) = q(x) + (1 - q(x))·g(d_y - d_x)` (see
//! [`super::lens`]). So each layer's sums are
//! `N(x) = q(x)·A(x) + (1 - q(x))·B(x, d_x) + centre correction`, where
//! `A = Σ_y v(y)·E(σ_y, |y-x|)` is a plain variable-radius scatter and `B` the same scatter
//! with sources weighted by `g(d_y - d_x)`. `B` only matters where `q(x) < 1`, a narrow band
//! of disparities around the focal plane; there it is interpolated in `d_x` between a few
//! nodes `δ_k`, each a plain scatter again. Sources far in front of every node (g = 1) are
//! scattered once and shared by all nodes; sources far behind (g = 0) are skipped.
//!
//! Every plain scatter sorts its sources by scatter radius σ:
//! - σ below `stencil_max`: the exact taps `E(σ, r)` (the model's footprint is a few pixels),
//! - up to `2·r0`: an antialiased disk of the soft step's equivalent radius, one span per row
//!   into a difference array (cost O(σ), not O(σ²)),
//! - beyond: sources are aggregated per cell and radius bin on a grid 2^ℓ times coarser,
//!   where their radius is again below `2·r0`, scattered there and upsampled bilinearly
//!   (cost per source O(1)).
//!
//! The quality knob moves these thresholds; at high quality every source is an exact stencil
//! and the interpolation nodes are dense, so the kernel converges to the exact one.

use super::aperture::{disk_taps, Tap};
use super::layer::{Layer, A, D};
use super::lens::{density, energy, focal_defocus, in_front, scatter_radius, step_source_factor, step_tap_factor, visibility_half_size, weight_unit};
use super::splat::{accumulate, Grid4, Window};
use super::{RawLayer, RenderSettings};
use rayon::prelude::*;

/// The fast kernel's accuracy/speed trade-off, derived from the quality level.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FastParams {
    /// Sources with σ below this use the exact taps.
    pub stencil_max: f32,
    /// Disks up to radius `2·r0` (grid pixels) are drawn directly; larger ones go to a
    /// coarser grid.
    pub r0: f32,
    /// Spacing of the interpolation nodes of the on-focal band, in disparity.
    pub node_step: f32,
    /// Draw full-resolution disks with the soft step's edge profile (3 nested disks) instead
    /// of one antialiased disk: 3× the span cost, closer to exact at small radii.
    pub soft_edge: bool,
}

impl FastParams {
    /// Quality 1 (fastest) … 8; 2 is the default. Higher is slower and closer to exact; 8
    /// uses the exact taps for every source (only the band interpolation remains).
    pub fn from_quality(q: u32) -> Self {
        let q = q.clamp(1, 8);
        let stencil_max = if q == 8 { f32::INFINITY } else { 2.0 + q as f32 };
        FastParams { stencil_max, r0: (2u32 << q) as f32, node_step: 0.04 / q as f32, soft_edge: q >= 3 }
    }
}

/// What the fast kernel did for one layer (for `--json`).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FastStats {
    pub stencil_sources: usize,
    pub span_sources: usize,
    pub coarse_sources: usize,
    /// Target pixels in the on-focal band (where the occlusion term is computed).
    pub band_pixels: usize,
    pub nodes: usize,
    /// Plain scatter passes run (1 when no pixel is near the focal plane).
    pub passes: usize,
    /// Sources skipped in the band passes because they are hidden behind every node.
    pub band_sources_skipped: usize,
}

/// The soft step's edge as a mixture of hard disks: radius offsets and weights of a 3-point
/// quadrature of the logistic distribution (scale 1/3 px, standard deviation π/(3√3) px).
const SOFT_EDGE: [(f32, f32); 3] = [(-1.047_2, 1.0 / 6.0), (0.0, 2.0 / 3.0), (1.047_2, 1.0 / 6.0)];
const HARD_EDGE: [(f32, f32); 1] = [(0.0, 1.0)];

/// Stencil taps reach `σ + STENCIL_TAIL` px: beyond, the soft step is below 5.5e-5 of its
/// plateau (a ring that holds < 0.1% of a source's energy).
const STENCIL_TAIL: f32 = 2.5;

/// `1 - q` below which a target counts as defocused (occlusion ≡ 1).
const BAND_EPS: f32 = 1e-6;
/// `g` this close to 0 or 1 counts as saturated.
const G_EPS: f32 = 1e-5;

/// Radius of the hard disk with the same area as the soft step's footprint
/// (`∫ 2πr·S(σ, r) dr = π·((σ - ln10/3)² + π²/27)`, a Fermi–Dirac integral: the step is
/// at 1/2 where `r = σ - ln10/3`).
#[inline]
fn equivalent_radius(sigma: f32) -> f32 {
    let m = (sigma - super::lens::STEP_LN_OFFSET / super::lens::STEP_GAIN).max(0.0);
    (m * m + std::f32::consts::PI * std::f32::consts::PI / 27.0).sqrt()
}

struct Ctx<'a> {
    img: &'a crate::Image,
    w: usize,
    h: usize,
    p: usize,
    sigma: Vec<f32>,
    sigma_max: f32,
    /// Weight unit of the layer (see `lens::weight_unit`).
    unit: f32,
    /// Whether any visible source falls in coarse level ℓ (index ℓ).
    levels_present: Vec<bool>,
    params: FastParams,
    /// Stencil taps sorted by row offset, their soft-step tap factors, and where each row
    /// offset `-stencil_p..=stencil_p` starts in them.
    stencil: Vec<Tap>,
    stencil_factor: Vec<f32>,
    stencil_rows: Vec<usize>,
    stencil_p: i64,
}

impl Ctx<'_> {
    #[inline]
    fn clamp_index(&self, x: i64, y: i64) -> usize {
        y.clamp(0, self.h as i64 - 1) as usize * self.w + x.clamp(0, self.w as i64 - 1) as usize
    }

    /// How far outside the image a source can still reach a target.
    fn pad(&self, reach: f32) -> i64 {
        (reach.min(1e9).ceil() as i64 + 1).min(self.p as i64 - 1).max(0)
    }
}

/// One aggregated source on a coarse grid.
#[derive(Clone, Copy)]
struct Agg {
    cx: f32,
    cy: f32,
    rho: f32,
    v: [f32; 4],
}

/// `Σ_y val(y)·E(σ_y, |y - x|)` for every target x (4 channels). `val` returns the source's
/// value (None = no contribution).
fn scatter_pass(ctx: &Ctx, val: &(dyn Fn(usize) -> Option<[f32; 4]> + Sync), stats: &mut FastStats) -> Grid4 {
    let (w, h) = (ctx.w, ctx.h);
    let pr = ctx.params;
    let mut out = Grid4::new(w, h);
    let lattice = Window::Lattice(ctx.p as i64);

    // Full resolution: exact stencils and directly drawn disks.
    let reach0 = equivalent_radius((2.0 * pr.r0).min(ctx.sigma_max)).max(pr.stencil_max.min(ctx.sigma_max) + STENCIL_TAIL);
    let pad0 = ctx.pad(reach0);
    let counts = std::sync::Mutex::new((0usize, 0usize));
    accumulate(&mut out, |st| {
        let (y0, y1) = st.rows();
        let (mut n_st, mut n_sp) = (0, 0);
        for sy in (y0 - pad0).max(-pad0)..(y1 + pad0).min(h as i64 + pad0) {
            for sx in -pad0..w as i64 + pad0 {
                let j = ctx.clamp_index(sx, sy);
                let sig = ctx.sigma[j];
                if sig >= 2.0 * pr.r0 {
                    continue;
                }
                let Some(v) = val(j) else { continue };
                let own_row = sy >= y0 && sy < y1;
                if sig < pr.stencil_max {
                    n_st += own_row as usize;
                    let reach = sig + STENCIL_TAIL;
                    let fs = step_source_factor(sig);
                    let dens = density(sig, ctx.unit);
                    // Taps are sorted by row; visit only this stripe's rows.
                    let (ra, rb) = ((y0 - sy).max(-ctx.stencil_p), (y1 - 1 - sy).min(ctx.stencil_p));
                    for di in ra..=rb {
                        // Row di holds dj = -m..=m; keep |dj| < sqrt(reach² - di²).
                        let (start, end) = (ctx.stencil_rows[(di + ctx.stencil_p) as usize], ctx.stencil_rows[(di + ctx.stencil_p + 1) as usize]);
                        let m = (end - start) / 2;
                        let rem = reach * reach - (di * di) as f32;
                        if rem <= 0.0 {
                            continue;
                        }
                        let jm = (rem.sqrt().ceil() as usize).saturating_sub(1).min(m);
                        let (a, b) = (start + m - jm, start + m + jm + 1);
                        for (t, &fr) in ctx.stencil[a..b].iter().zip(&ctx.stencil_factor[a..b]) {
                            let e = dens / (1.0 + fs * fr);
                            st.tap(sx + t.dj as i64, sy + di, v.map(|c| c * e));
                        }
                    }
                } else {
                    n_sp += own_row as usize;
                    let dens = density(sig, ctx.unit);
                    let rho = equivalent_radius(sig);
                    // Small disks show their soft edge most: draw its profile there.
                    let edge = if pr.soft_edge || sig < 2.0 * pr.stencil_max { &SOFT_EDGE[..] } else { &HARD_EDGE[..] };
                    for &(off, wt) in edge {
                        st.disk(sx as f32, sy as f32, rho + off, lattice, v.map(|c| c * dens * wt));
                    }
                }
            }
        }
        let mut c = counts.lock().expect("counter");
        c.0 += n_st;
        c.1 += n_sp;
    });
    let (n_st, n_sp) = counts.into_inner().expect("counter");
    stats.stencil_sources += n_st;
    stats.span_sources += n_sp;

    // Coarse levels: level ℓ takes σ in [r0·2^ℓ, r0·2^(ℓ+1)).
    let mut level = 1u32;
    while level < 63 && pr.r0 * (1u64 << level) as f32 <= ctx.sigma_max {
        let f = (1u64 << level) as f32;
        if !ctx.levels_present.get(level as usize).copied().unwrap_or(false) {
            level += 1;
            continue;
        }
        let aggs = aggregate(ctx, level, val);
        stats.coarse_sources += aggs.iter().map(|r| r.len()).sum::<usize>();
        if aggs.iter().any(|r| !r.is_empty()) {
            let (cw, ch) = ((w as f32 / f).ceil() as usize, (h as f32 / f).ceil() as usize);
            let mut coarse = Grid4::new(cw, ch);
            let window = Window::Disk(ctx.p as f32 / f);
            let reach = 2.0 * pr.r0 + 2.0;
            let pad = ctx.pad(ctx.sigma_max + 3.0) as f32;
            accumulate(&mut coarse, |st| {
                let (y0, y1) = st.rows();
                for (i, row) in aggs.iter().enumerate() {
                    // Centres of cell row i lie within ±1 of this coarse coordinate.
                    let cy = (i as f32 * f - pad + 0.5 * f) / f - 0.5;
                    if cy + 1.0 + reach < y0 as f32 || cy - 1.0 - reach > y1 as f32 {
                        continue;
                    }
                    for a in row {
                        st.disk(a.cx, a.cy, a.rho, window, a.v);
                    }
                }
            });
            out.data.par_chunks_mut(w * 4).enumerate().for_each(|(y, orow)| {
                let v = (y as f32 + 0.5) / f - 0.5;
                for x in 0..w {
                    let s = coarse.sample((x as f32 + 0.5) / f - 0.5, v);
                    for c in 0..4 {
                        orow[x * 4 + c] += s[c];
                    }
                }
            });
        }
        level += 1;
    }
    out
}

/// Aggregates the sources of coarse level `level` per cell and radius bin; one Vec per cell row.
fn aggregate(ctx: &Ctx, level: u32, val: &(dyn Fn(usize) -> Option<[f32; 4]> + Sync)) -> Vec<Vec<Agg>> {
    let f = 1i64 << level;
    let ff = f as f32;
    let (lo, hi) = (ctx.params.r0 * ff, ctx.params.r0 * 2.0 * ff);
    let bins = ctx.params.r0 as usize;
    let pad = ctx.pad(ctx.sigma_max + 3.0);
    let (x0, x1) = (-pad, ctx.w as i64 + pad);
    let (y0, y1) = (-pad, ctx.h as i64 + pad);
    let cols = ((x1 - x0) + f - 1) / f;
    let rows = ((y1 - y0) + f - 1) / f;
    (0..rows)
        .into_par_iter()
        .map(|ci| {
            let mut out = Vec::new();
            let mut acc = vec![[0f64; 7]; bins];
            for cj in 0..cols {
                acc.iter_mut().for_each(|a| *a = [0.0; 7]);
                let mut any = false;
                for sy in (y0 + ci * f)..(y0 + (ci + 1) * f).min(y1) {
                    for sx in (x0 + cj * f)..(x0 + (cj + 1) * f).min(x1) {
                        let j = ctx.clamp_index(sx, sy);
                        let sig = ctx.sigma[j];
                        if sig < lo || sig >= hi {
                            continue;
                        }
                        let Some(v) = val(j) else { continue };
                        let dens = density(sig, ctx.unit);
                        let wgt = (v[3] * dens) as f64;
                        if wgt <= 0.0 {
                            continue;
                        }
                        let b = (((sig - lo) / ff) as usize).min(bins - 1);
                        let a = &mut acc[b];
                        for c in 0..4 {
                            a[c] += (v[c] * dens) as f64;
                        }
                        a[4] += wgt * ((sx as f32 + 0.5) / ff - 0.5) as f64;
                        a[5] += wgt * ((sy as f32 + 0.5) / ff - 0.5) as f64;
                        a[6] += wgt * (equivalent_radius(sig) / ff) as f64;
                        any = true;
                    }
                }
                if !any {
                    continue;
                }
                for a in &acc {
                    if a[3] > 0.0 {
                        out.push(Agg {
                            cx: (a[4] / a[3]) as f32,
                            cy: (a[5] / a[3]) as f32,
                            rho: (a[6] / a[3]) as f32,
                            v: [a[0] as f32, a[1] as f32, a[2] as f32, a[3] as f32],
                        });
                    }
                }
            }
            out
        })
        .collect()
}

/// Renders one layer into its raw sums `[ΣR, ΣG, ΣB, W, o]`, like [`super::exact::scatter_layer`].
pub fn scatter_layer(layer: &Layer, s: &RenderSettings, params: FastParams) -> (RawLayer, FastStats) {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let p = s.lens / 2;
    let mut stats = FastStats::default();
    let d: Vec<f32> = img.data.par_chunks_exact(5).map(|px| px[D] - s.focus).collect();
    let sigma: Vec<f32> = d.par_iter().map(|&d| scatter_radius(d, s.blur)).collect();
    let q: Vec<f32> = d.par_iter().map(|&d| if s.occlusion { focal_defocus(d, s.blur) } else { 1.0 }).collect();
    let vis = visibility(img, &sigma, p);
    if layer.is_transparent() || p == 0 {
        let mut out = vec![0f32; w * h * 5];
        for (o, v) in out.chunks_exact_mut(5).zip(&vis) {
            o[4] = *v;
        }
        return (RawLayer::new(w, h, out, layer), stats);
    }
    let sigma_max = (0..w * h).filter(|&i| img.data[i * 5 + A] > 0.0).map(|i| sigma[i]).fold(1.0, f32::max);
    let stencil_reach = params.stencil_max.min(sigma_max) + STENCIL_TAIL;
    let stencil: Vec<Tap> = disk_taps(s.lens).into_iter().filter(|t| t.r < stencil_reach).collect();
    let stencil_p = stencil.iter().map(|t| t.di.abs() as i64).max().unwrap_or(0);
    let stencil_rows: Vec<usize> = (-stencil_p..=stencil_p + 1).map(|di| stencil.partition_point(|t| (t.di as i64) < di)).collect();
    let ctx = Ctx {
        img,
        w,
        h,
        p,
        stencil_factor: stencil.iter().map(|t| step_tap_factor(t.r)).collect(),
        stencil,
        stencil_rows,
        stencil_p,
        unit: weight_unit(super::min_visible_radius(img, &sigma)),
        levels_present: {
            let mut v = vec![false; 64];
            for (i, &sg) in sigma.iter().enumerate() {
                if img.data[i * 5 + A] > 0.0 && sg >= 2.0 * params.r0 {
                    v[((sg / params.r0).log2().floor() as usize).min(63)] = true;
                }
            }
            v
        },
        sigma,
        sigma_max,
        params,
    };
    let base = |j: usize| -> Option<[f32; 4]> {
        let px = &ctx.img.data[j * 5..j * 5 + 5];
        let a = px[A];
        (a > 0.0).then(|| [px[0] * a, px[1] * a, px[2] * a, a])
    };
    let a_grid = scatter_pass(&ctx, &base, &mut stats);
    stats.passes = 1;

    // The on-focal band: targets whose occlusion term is not saturated at 1.
    let band: Vec<bool> = q.iter().map(|&q| 1.0 - q > BAND_EPS).collect();
    stats.band_pixels = band.iter().filter(|&&b| b).count();
    let mut b_acc = vec![0f32; if stats.band_pixels > 0 { w * h * 4 } else { 0 }];
    if stats.band_pixels > 0 {
        let (dlo, dhi) = d.iter().zip(&band).filter(|(_, b)| **b).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), (&d, _)| (lo.min(d), hi.max(d)));
        let n = (((dhi - dlo) / params.node_step).ceil() as usize).max(0) + 1;
        let step = if n > 1 { (dhi - dlo) / (n - 1) as f32 } else { 0.0 };
        let nodes: Vec<f32> = (0..n).map(|k| dlo + step * k as f32).collect();
        stats.nodes = n;
        // Sources hidden behind every node add nothing; those in front of every node add
        // their full value to every node: scatter them once.
        let classes: Vec<u8> = d
            .par_iter()
            .map(|&dj| {
                let (g_min, g_max) = (in_front(dj, dhi), in_front(dj, dlo));
                if g_max <= G_EPS {
                    0
                } else if g_min >= 1.0 - G_EPS {
                    2
                } else {
                    1
                }
            })
            .collect();
        let class = |j: usize| classes[j];
        
        let alpha_at = |j: usize| img.data[j * 5 + A] > 0.0;
        let has = |c: u8| (0..w * h).any(|j| class(j) == c && alpha_at(j));
        let front = if has(2) {
            stats.passes += 1;
            scatter_pass(&ctx, &|j| if class(j) == 2 { base(j) } else { None }, &mut stats)
        } else {
            Grid4::new(w, h)
        };
        let any_unsaturated = has(1);
        stats.band_sources_skipped = (0..w * h).filter(|&j| class(j) == 0 && alpha_at(j)).count();
        for &node in &nodes {
            let u = if any_unsaturated {
                stats.passes += 1;
                scatter_pass(&ctx, &|j| if class(j) == 1 { base(j).map(|v| v.map(|c| c * in_front(d[j], node))) } else { None }, &mut stats)
            } else {
                Grid4::new(w, h)
            };
            // Hat-function (linear) interpolation weight of node k at disparity d_x.
            b_acc.par_chunks_mut(4).enumerate().for_each(|(i, acc)| {
                if !band[i] {
                    return;
                }
                let wk = if n == 1 { 1.0 } else { (1.0 - ((d[i] - node) / step).abs()).max(0.0) };
                if wk > 0.0 {
                    for c in 0..4 {
                        acc[c] += wk * (front.data[i * 4 + c] + u.data[i * 4 + c]);
                    }
                }
            });
        }
    }

    let mut out = vec![0f32; w * h * 5];
    out.par_chunks_mut(5).enumerate().for_each(|(i, o)| {
        let a = a_grid.at(i);
        if !band.is_empty() && band[i] {
            let (qi, b) = (q[i], &b_acc[i * 4..i * 4 + 4]);
            // The centre tap has occlusion 1, not q + (1-q)·g(0) as in A and B.
            let corr = base(i).map(|v| {
                let e = energy(ctx.sigma[i], 0.0, ctx.unit) * (1.0 - qi) * (1.0 - in_front(d[i], d[i]));
                v.map(|c| c * e)
            });
            for c in 0..4 {
                o[c] = qi * a[c] + (1.0 - qi) * b[c] + corr.map_or(0.0, |v| v[c]);
            }
        } else {
            o[..4].copy_from_slice(a);
        }
        o[4] = vis[i];
    });
    (RawLayer::new(w, h, out, layer), stats)
}

/// Non-focal visibility (eq. 4) for every pixel from a summed-area table of the
/// replicate-padded alpha (f64: sums of millions of values). O(1) per pixel.
fn visibility(img: &crate::Image, sigma: &[f32], p: usize) -> Vec<f32> {
    let (w, h) = (img.width, img.height);
    let nmax = sigma.iter().map(|&s| visibility_half_size(s, p)).max().unwrap_or(0);
    let (pw, ph) = (w + 2 * nmax, h + 2 * nmax);
    let mut sat = vec![0f64; (pw + 1) * (ph + 1)];
    for y in 0..ph {
        let sy = (y as i64 - nmax as i64).clamp(0, h as i64 - 1) as usize;
        let mut row = 0f64;
        for x in 0..pw {
            let sx = (x as i64 - nmax as i64).clamp(0, w as i64 - 1) as usize;
            row += img.data[(sy * w + sx) * 5 + A] as f64;
            sat[(y + 1) * (pw + 1) + x + 1] = sat[y * (pw + 1) + x + 1] + row;
        }
    }
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w + nmax, i / w + nmax);
            let n = visibility_half_size(sigma[i], p);
            let (x0, y0, x1, y1) = (x - n, y - n, x + n + 1, y + n + 1);
            let s = sat[y1 * (pw + 1) + x1] - sat[y0 * (pw + 1) + x1] - sat[y1 * (pw + 1) + x0] + sat[y0 * (pw + 1) + x0];
            (s / ((2 * n + 1) * (2 * n + 1)) as f64) as f32
        })
        .collect()
}
