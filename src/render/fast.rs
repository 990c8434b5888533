//! The fast per-layer kernel: the same model as [`super::exact`], at a near-constant cost
//! per pixel.
//!
//! The on-focal occlusion splits as `O(y,x) = q(x) + (1 - q(x))·g(d_y - d_x)` (see
//! [`super::lens`]). So each layer's sums are
//! `N(x) = q(x)·A(x) + (1 - q(x))·B(x, d_x) + centre correction`, where
//! `A = Σ_y v(y)·E(σ_y, |y-x|)` is a plain variable-radius scatter and `B` the same scatter
//! with sources weighted by `g(d_y - d_x)`. `B` only matters where `q(x) < 1`, a narrow band
//! of disparities around the focal plane; there it is interpolated in `d_x` between a few
//! nodes `δ_k`: `B = F + Σ_k hat_k(d_x)·U_k`, where `F` scatters the sources in front of
//! every node (g = 1) once and `U_k` the partly occluding ones weighted by `g(d_y - δ_k)`;
//! sources behind every node (g = 0) are skipped.
//!
//! Every plain scatter sorts its sources by scatter radius σ:
//! - σ below `stencil_max`: the exact taps `E(σ, r)` (the model's footprint is a few pixels),
//! - up to `2·r0`: an antialiased disk of the soft step's equivalent radius, one span per row
//!   into a difference array (cost O(σ), not O(σ²)),
//! - beyond: sources are aggregated per cell and radius bin on a grid 2^ℓ times coarser,
//!   where their radius is again below `2·r0`, scattered there and upsampled bilinearly
//!   (cost per source O(1)).
//!
//! Work is done one stripe of rows at a time: each worker scatters the stripe's sources into
//! reusable stripe accumulators for every pass at once (the tap weight is computed once and
//! shared by `A`, `F` and the `U_k`), adds the coarse levels, combines and hands each finished
//! raw pixel to the caller (who stores or composites it). Only the coarse grids and the
//! scatter radii are stored for the whole layer, so memory stays a few bytes per pixel.
//!
//! The quality knob moves the thresholds; at high quality every source is an exact stencil
//! and the interpolation nodes are dense, so the kernel converges to the exact one.

use super::aperture::{Tap, disk_tap_count, disk_taps_within};
use super::layer::{A, D, Layer};
use super::lens::{
    FACTORED_STEP_MAX, density, energy, focal_defocus, in_front, scatter_radius, soft_step, step_source_factor, step_tap_factor,
    visibility_half_size, weight_unit,
};
use super::splat::{Grid4, STRIPE_ROWS, Stripe, Window, accumulate};
use super::{RawLayer, RenderSettings};
use rayon::prelude::*;
use std::f32::consts::FRAC_PI_3;
use std::sync::atomic::{AtomicU64, Ordering};

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
    /// Visible sources drawn as exact stencils, as full-resolution disks, and aggregated on
    /// coarse grids (per pass: a source in several passes counts in each).
    pub stencil_sources: usize,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub span_sources: usize,
    /// Bright sources (a colour above 1.25, at most ~1% of the visible ones) drawn with their exact
    /// footprint at any radius; counted once per stripe row they own.
    pub bright_sources: usize,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub coarse_sources: usize,
    /// Target pixels in the on-focal band (where the occlusion term is computed).
    pub band_pixels: usize,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub nodes: usize,
    /// Plain scatter passes (1 when no pixel is near the focal plane: the occlusion part is
    /// skipped; in the band, `F` and one `U_k` per node).
    pub passes: usize,
    /// Sources skipped in the band passes because they are hidden behind every node.
    pub band_sources_skipped: usize,
    /// Stripes of rows where the occlusion part was computed, out of all stripes.
    pub band_stripes: usize,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub stripes: usize,
    /// Fully transparent pixels (never scattered).
    pub transparent_pixels: usize,
    /// Weighted taps the exact kernel evaluates for this layer (`W·H·taps(lens)`) and the
    /// elementary writes the fast kernel made (stencil taps, disk spans, coarse spans and
    /// upsampled pixels); `work_saved = 1 - fast_ops / exact_taps`.
    pub exact_taps: f64,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub fast_ops: f64,
    #[allow(missing_docs)] // TEMP: documented by the fast.rs/splat.rs split
    pub work_saved: f64,
}

/// The soft step's edge as a mixture of hard disks: radius offsets and weights of a 3-point
/// quadrature of the logistic distribution (scale 1/3 px, standard deviation π/(3√3) px).
/// The nodes are ±√3 standard deviations = ±π/3 px (3-point Gauss–Hermite).
const SOFT_EDGE: [(f32, f32); 3] = [(-FRAC_PI_3, 1.0 / 6.0), (0.0, 2.0 / 3.0), (FRAC_PI_3, 1.0 / 6.0)];
const HARD_EDGE: [(f32, f32); 1] = [(0.0, 1.0)];

/// Stencil taps reach `σ + STENCIL_TAIL` px: beyond, the soft step is below 5.5e-5 of its
/// plateau (a ring that holds < 0.1% of a source's energy).
const STENCIL_TAIL: f32 = 2.5;

/// `1 - q` below which a target counts as defocused (occlusion ≡ 1).
const BAND_EPS: f32 = 1e-6;
/// `g` this close to 0 or 1 counts as saturated.
const G_EPS: f64 = 1e-5;

/// Radius of the hard disk with the same area as the soft step's footprint
/// (`∫ 2πr·S(σ, r) dr = π·((σ - ln10/3)² + π²/27)`, a Fermi–Dirac integral: the step is
/// at 1/2 where `r = σ - ln10/3`).
#[inline]
fn equivalent_radius(sigma: f32) -> f32 {
    let m = (sigma - super::lens::STEP_LN_OFFSET / super::lens::STEP_GAIN).max(0.0);
    (m * m + std::f32::consts::PI * std::f32::consts::PI / 27.0).sqrt()
}

/// `|d|·K` below which a target is in the on-focal band: there `1 - q = exp(-3(|d|·K)²)`
/// exceeds `BAND_EPS`. The band test uses this threshold, never `q` itself, so the survey
/// and the stripes agree without evaluating the exponential twice.
fn band_coc() -> f32 {
    ((1.0 / BAND_EPS as f64).ln() / super::lens::STEP_GAIN as f64).sqrt() as f32
}

/// Whether a target at relative disparity `d` is in the on-focal band.
#[inline]
fn in_band(d: f32, s: &RenderSettings, band_coc: f32) -> bool {
    s.occlusion && d.abs() * s.blur < band_coc
}

/// The radius a source is drawn with: its scatter radius σ, capped at `p + RIM` for a
/// window of half-size `p`. Beyond `p + RIM` the soft step is within 6e-5 of 1 at every tap
/// of the window, so the footprint is the window itself whatever σ is; only the energy
/// density `1/σ²` still depends on σ. Without the cap a circle far larger than the image went
/// to a coarse grid whose cells are larger than the window, and its light was lost.
#[inline]
fn drawn_radius(sigma: f32, p: usize) -> f32 {
    sigma.min(p as f32 + RIM)
}

/// Coarse level of a source: level ℓ ≥ 1 takes σ in `[r0·2^ℓ, r0·2^(ℓ+1))`; None below `2·r0`.
#[inline]
fn level_of(sigma: f32, r0: f32) -> Option<usize> {
    (sigma >= 2.0 * r0).then(|| ((sigma / r0).log2().floor() as usize).clamp(1, 63))
}

/// How a source relates to the on-focal band's nodes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Class {
    /// Behind every node: `g ≤ G_EPS`, adds nothing to `B`.
    Hidden,
    /// Partly occluding: weighted by `g(d - δ_k)` per node.
    Partial,
    /// In front of every node: `g ≥ 1 - G_EPS`, adds its full value to every node.
    Front,
}

/// The interpolation nodes over the band's target disparities `[lo, hi]`.
#[derive(Clone, Copy)]
struct Band {
    lo: f32,
    step: f32,
    n: usize,
    /// Sources with `d ≤ hidden` are [`Class::Hidden`], with `d ≥ front` [`Class::Front`].
    hidden: f32,
    front: f32,
}

impl Band {
    fn new(lo: f32, hi: f32, node_step: f32) -> Self {
        let n = (((hi - lo) / node_step).ceil() as usize) + 1;
        let step = if n > 1 { (hi - lo) / (n - 1) as f32 } else { 0.0 };
        // g(δ) = ½ + ½·tanh(10(δ - 0.1)) ≤ ε  ⇔  δ ≤ 0.1 - atanh(1 - 2ε)/10; symmetric above.
        let z = (0.5 * ((1.0 - G_EPS) / G_EPS).ln() / 10.0) as f32;
        Band { lo, step, n, hidden: lo + 0.1 - z, front: hi + 0.1 + z }
    }

    fn node(&self, k: usize) -> f32 {
        self.lo + self.step * k as f32
    }

    #[inline]
    fn class(&self, d: f32) -> Class {
        if d <= self.hidden {
            Class::Hidden
        } else if d >= self.front {
            Class::Front
        } else {
            Class::Partial
        }
    }

    /// Hat-function (linear interpolation) weight of node k at target disparity `d`.
    #[inline]
    fn hat(&self, k: usize, d: f32) -> f32 {
        if self.n == 1 { 1.0 } else { (1.0 - ((d - self.node(k)) / self.step).abs()).max(0.0) }
    }

    /// The nodes whose hats are non-zero somewhere in `[a, b]`.
    fn nodes_for(&self, a: f32, b: f32) -> (usize, usize) {
        if self.n == 1 {
            return (0, 0);
        }
        let ka = (((a - self.lo) / self.step).floor().max(0.0) as usize).min(self.n - 1);
        let kb = (((b - self.lo) / self.step).ceil().max(0.0) as usize).min(self.n - 1);
        (ka, kb)
    }
}

/// What one parallel pre-pass learns about a layer.
#[derive(Clone, Copy)]
struct Survey {
    visible: usize,
    sigma_min: f32,
    sigma_max: f32,
    /// Largest drawn radius (see [`drawn_radius`]) of a visible source drawn at full
    /// resolution (below `2·r0`); 0 if none. `sigma_max` and `bright_max` are drawn radii too.
    full_max: f32,
    /// Largest σ of a visible bright source (a colour above 1, see [`is_bright`]); 0 if none.
    bright_max: f32,
    band_pixels: usize,
    band_lo: f32,
    band_hi: f32,
}

impl Survey {
    const EMPTY: Survey = Survey {
        visible: 0,
        sigma_min: f32::INFINITY,
        sigma_max: 1.0,
        full_max: 0.0,
        bright_max: 0.0,
        band_pixels: 0,
        band_lo: f32::INFINITY,
        band_hi: f32::NEG_INFINITY,
    };

    fn merge(a: Survey, b: Survey) -> Survey {
        Survey {
            visible: a.visible + b.visible,
            sigma_min: a.sigma_min.min(b.sigma_min),
            sigma_max: a.sigma_max.max(b.sigma_max),
            full_max: a.full_max.max(b.full_max),
            bright_max: a.bright_max.max(b.bright_max),
            band_pixels: a.band_pixels + b.band_pixels,
            band_lo: a.band_lo.min(b.band_lo),
            band_hi: a.band_hi.max(b.band_hi),
        }
    }
}

/// A pass's coarse levels: grids `factor` times coarser than the image.
struct Coarse {
    factor: f32,
    grid: Grid4,
}

/// Per-layer state shared by every stripe.
struct Ctx<'a> {
    img: &'a crate::Image,
    s: &'a RenderSettings,
    w: usize,
    h: usize,
    p: usize,
    sigma: Vec<f32>,
    sigma_max: f32,
    /// See `Survey::full_max`; `bright_max` is `Survey::bright_max` for sources above
    /// `bright_level` (see [`bright_level`]).
    full_max: f32,
    bright_max: f32,
    bright_level: f32,
    /// Weight unit of the layer (see `lens::weight_unit`).
    unit: f32,
    params: FastParams,
    /// The on-focal band (None when no target is near the focal plane).
    band: Option<Band>,
    /// Whether the band passes have front / partial sources at all.
    has_front: bool,
    has_partial: bool,
    /// Distances of the stencil taps (sorted by row offset), their soft-step tap factors
    /// (infinite beyond the factored form's range), and where each row offset
    /// `-stencil_p..=stencil_p` starts in them.
    stencil_r: Vec<f32>,
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

    #[inline]
    fn d(&self, j: usize) -> f32 {
        self.img.data[j * 5 + D] - self.s.focus
    }

    /// A source's premultiplied value `[r·a, g·a, b·a, a]`; None when transparent.
    #[inline]
    fn base(&self, j: usize) -> Option<[f32; 4]> {
        let px = &self.img.data[j * 5..j * 5 + 5];
        let a = px[A];
        (a > 0.0).then(|| [px[0] * a, px[1] * a, px[2] * a, a])
    }

    /// Which sources pass `slot` scatters and with what value: slot 0 is `A`, 1 is `F`,
    /// `2 + k` is `U_k`.
    fn value(&self, slot: usize, j: usize) -> Option<[f32; 4]> {
        let v = self.base(j)?;
        match (slot, self.band) {
            (0, _) => Some(v),
            (1, Some(b)) => (b.class(self.d(j)) == Class::Front).then_some(v),
            (k, Some(b)) => {
                let dj = self.d(j);
                (b.class(dj) == Class::Partial).then(|| v.map(|c| c * in_front(dj, b.node(k - 2))))
            }
            _ => None,
        }
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

/// The coarse levels of pass `slot`, for the levels in `mask` (bit ℓ = level ℓ present).
fn coarse_levels(ctx: &Ctx, slot: usize, mask: u64, ops: &AtomicU64, coarse_sources: &AtomicU64) -> Vec<Coarse> {
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
        coarse_sources.fetch_add(n as u64, Ordering::Relaxed);
        if n == 0 {
            continue;
        }
        let (cw, ch) = ((w as f32 / f).ceil() as usize, (h as f32 / f).ceil() as usize);
        let mut grid = Grid4::new(cw, ch);
        let window = Window::Disk(ctx.p as f32 / f);
        let reach = 2.0 * r0 + 2.0;
        let pad = ctx.pad(ctx.sigma_max + 3.0) as f32;
        let rows = AtomicU64::new(0);
        accumulate(&mut grid, |st| {
            let (y0, y1) = st.rows();
            let mut spans = 0f32;
            for (i, row) in aggs.iter().enumerate() {
                // Centres of cell row i lie within ±1 of this coarse coordinate.
                let cy = (i as f32 * f - pad + 0.5 * f) / f - 0.5;
                if cy + 1.0 + reach < y0 as f32 || cy - 1.0 - reach > y1 as f32 {
                    continue;
                }
                for a in row {
                    spans += st.disk(a.cx, a.cy, a.rho, window, a.v).min(1.0).ceil();
                }
            }
            rows.fetch_add(spans as u64, Ordering::Relaxed);
        });
        ops.fetch_add(rows.into_inner() + (w * h) as u64, Ordering::Relaxed);
        out.push(Coarse { factor: f, grid });
    }
    out
}

/// Aggregates the sources of pass `slot` at coarse level `level` per cell and radius bin
/// (value-weighted centroid and radius, so a cell's light stays where it was); one Vec per
/// cell row.
fn aggregate(ctx: &Ctx, level: u32, slot: usize) -> Vec<Vec<Agg>> {
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
                let mut any = false;
                for sy in (y0 + ci * f)..(y0 + (ci + 1) * f).min(y1) {
                    for sx in (x0 + cj * f)..(x0 + (cj + 1) * f).min(x1) {
                        let j = ctx.clamp_index(sx, sy);
                        let sig = ctx.sigma[j];
                        let drawn = drawn_radius(sig, ctx.p);
                        if drawn < lo || drawn >= hi {
                            continue;
                        }
                        let Some(v) = ctx.value(slot, j) else { continue };
                        if is_bright(v[0].max(v[1]).max(v[2]), v[3], ctx.bright_level) {
                            // Drawn exactly at full resolution (scan_sources).
                            continue;
                        }
                        let dens = density(sig, ctx.unit);
                        let wgt = (v[3] * dens) as f64;
                        if wgt <= 0.0 {
                            continue;
                        }
                        let b = (((drawn - lo) / ff) as usize).min(bins - 1);
                        let a = &mut acc[b];
                        for c in 0..4 {
                            a[c] += (v[c] * dens) as f64;
                        }
                        a[4] += wgt * ((sx as f32 + 0.5) / ff - 0.5) as f64;
                        a[5] += wgt * ((sy as f32 + 0.5) / ff - 0.5) as f64;
                        a[6] += wgt * (equivalent_radius(drawn) / ff) as f64;
                        any = true;
                    }
                }
                if !any {
                    continue;
                }
                for a in acc.iter_mut() {
                    if a[3] > 0.0 {
                        out.push(Agg {
                            cx: (a[4] / a[3]) as f32,
                            cy: (a[5] / a[3]) as f32,
                            rho: (a[6] / a[3]) as f32,
                            v: [a[0] as f32, a[1] as f32, a[2] as f32, a[3] as f32],
                        });
                    }
                    *a = [0.0; 7];
                }
            }
            out
        })
        .collect()
}

/// A worker's reusable buffers (sized on first use, then recycled from stripe to stripe).
#[derive(Default)]
struct Scratch {
    /// Accumulators: `[A, F, U_ka, …, U_kb]` for the stripe's nodes.
    accs: Vec<Stripe>,
    /// `q` of the stripe's targets.
    q: Vec<f32>,
    /// The stripe's finished raw pixels, 5 channels.
    raw: Vec<f32>,
    row_a: Vec<f32>,
    row_b: Vec<f32>,
    row_u: Vec<f32>,
    tmp: Vec<f32>,
    /// Tap weights per stencil row `-stencil_p..=stencil_p` (first column offset, weights)
    /// of a source with scatter radius `stencil_sigma` (reused while σ repeats: in-focus
    /// regions and planes of constant depth).
    stencil_w: Vec<(i64, Vec<f32>)>,
    stencil_sigma: f32,
    /// One rim row of a bright source.
    rim: Vec<f32>,
    /// (accumulator, factor) pairs a source scatters into.
    dests: Vec<(usize, f32)>,
    sat: Vec<f64>,
    vis: Vec<f32>,
}

/// The exact taps `E(σ, r)` of a source with scatter radius `sigma` (energy density `dens`),
/// per stencil row, out to `σ + STENCIL_TAIL`.
fn stencil_weights(ctx: &Ctx, sigma: f32, dens: f32, out: &mut Vec<(i64, Vec<f32>)>) {
    let rows = (2 * ctx.stencil_p + 1) as usize;
    out.resize_with(rows, Default::default);
    let reach = sigma + STENCIL_TAIL;
    let fs = step_source_factor(sigma);
    for (k, (jm_out, e)) in out.iter_mut().enumerate() {
        let di = k as i64 - ctx.stencil_p;
        e.clear();
        // Row di holds dj = -m..=m; keep |dj| < sqrt(reach² - di²).
        let (start, end) = (ctx.stencil_rows[k], ctx.stencil_rows[k + 1]);
        let rem = reach * reach - (di * di) as f32;
        if rem <= 0.0 || end == start {
            continue;
        }
        let m = (end - start) / 2;
        let jm = (rem.sqrt().ceil() as usize).saturating_sub(1).min(m);
        let (a, b) = (start + m - jm, start + m + jm + 1);
        if sigma <= FACTORED_STEP_MAX {
            e.extend(ctx.stencil_factor[a..b].iter().map(|&fr| dens / (1.0 + fs * fr)));
        } else {
            // Beyond the factored form's range (quality 8 draws every radius as a stencil):
            // the plain stable step, one exponential per tap.
            e.extend(ctx.stencil_r[a..b].iter().map(|&r| dens * soft_step(sigma, r)));
        }
        *jm_out = jm as i64;
    }
}

/// Whether a source whose largest premultiplied channel is `c` at alpha `a` is brighter than
/// `level` (≥ [`BRIGHT_MIN`], see [`bright_level`]): such sources are drawn exactly, see [`rim_disk`].
#[inline]
fn is_bright(c: f32, a: f32, level: f32) -> bool {
    c > a * level
}

/// The lowest colour that counts as bright. Disk edges err by up to ~0.015 for colours up to
/// white (the stress tests), so 1.25 keeps that under 0.02; it also leaves alone the slight
/// overshoots above 1 that inpainting produces in an 8-bit photo's background (treating those
/// as bright cost a 12 MP render 40%).
const BRIGHT_MIN: f32 = 1.25;

/// Most visible sources (fraction) drawn exactly as bright: their cost grows with σ.
const BRIGHT_FRACTION: usize = 100;

/// The colour above which a source counts as bright: [`BRIGHT_MIN`], raised when more than 1%
/// of the visible sources are above it (a bright sky, an HDR photo exposed low) to the level
/// that keeps the brightest 1%. Edge errors grow with a source's value relative to its
/// surroundings, so the brightest sources are the ones that need the exact footprint, and the
/// cap keeps the cost near-constant per pixel.
fn bright_level(img: &crate::Image, visible: usize) -> f32 {
    let mut above: Vec<f32> =
        img.data.par_chunks_exact(5).filter(|px| px[A] > 0.0).map(|px| px[0].max(px[1]).max(px[2])).filter(|&c| c > BRIGHT_MIN).collect();
    let budget = (visible / BRIGHT_FRACTION).max(1);
    if above.len() <= budget {
        return BRIGHT_MIN;
    }
    let k = above.len() - budget - 1;
    let (_, &mut kth, _) = above.select_nth_unstable_by(k, f32::total_cmp);
    kth
}

/// Inside this distance from the edge (`r ≤ σ - RIM`) the soft step is within 6e-5 of 1.
const RIM: f32 = 4.0;

/// The exact footprint `E(σ, r)` of one source at integer position (sx, sy), clipped to the
/// lens window `|offset| < p` and to the stripe, in O(σ) writes: per row, one span of the
/// plateau (`r ≤ σ - RIM`, soft step taken as 1) and explicit taps on the rim out to
/// `σ + STENCIL_TAIL`. Returns the number of writes.
fn rim_disk(st: &mut Stripe, (sx, sy): (i64, i64), sigma: f32, dens: f32, p: i64, v: [f32; 4], e: &mut Vec<f32>) -> u64 {
    let (y0, y1) = st.rows();
    let (reach, inner) = (sigma + STENCIL_TAIL, sigma - RIM);
    let rr = (reach.min(1e9).ceil() as i64).min(p);
    let mut ops = 0;
    for row in (sy - rr).max(y0)..=(sy + rr).min(y1 - 1) {
        let dy = row - sy;
        let rem = p * p - dy * dy;
        if rem <= 0 {
            continue;
        }
        // Largest |dx| inside the window (strict disk, as the official mask).
        let m = ((rem as f64).sqrt().ceil() as i64 - 1).max(0);
        let dyf = (dy * dy) as f32;
        let xo = if reach * reach > dyf { ((reach * reach - dyf).sqrt() as i64).min(m) } else { continue };
        let xi = if inner > 0.0 && inner * inner >= dyf { ((inner * inner - dyf).sqrt() as i64).min(xo) } else { -1 };
        if xi >= 0 {
            st.pixels(row, sx - xi, sx + xi, v.map(|c| c * dens));
            ops += 4;
        }
        if xo > xi {
            e.clear();
            e.extend((xi + 1..=xo).map(|dx| dens * soft_step(sigma, ((dx * dx) as f32 + dyf).sqrt())));
            st.tap_row(sx + xi + 1, row, e, v);
            if xi >= 0 || xo > 0 {
                // The left rim mirrors the right one (without the centre column when xi < 0).
                let skip = usize::from(xi < 0);
                e.reverse();
                let left = &e[..e.len() - skip];
                st.tap_row(sx - xo, row, left, v);
            }
            ops += 2 * e.len() as u64;
        }
    }
    ops
}

/// Counters the stripes add to.
#[derive(Default)]
struct Counts {
    bright: AtomicU64,
    stencil: AtomicU64,
    span: AtomicU64,
    band_stripes: AtomicU64,
    ops: AtomicU64,
    coarse: AtomicU64,
}

/// Renders one layer into its raw sums `[ΣR, ΣG, ΣB, W, o]`, like [`super::exact::scatter_layer`].
/// Allocates the 5-channel output.
pub fn scatter_layer(layer: &Layer, s: &RenderSettings, params: FastParams) -> (RawLayer, FastStats) {
    let (w, h) = (layer.width(), layer.height());
    let mut out = vec![0f32; w * h * 5];
    let stats = scatter_layer_into(layer, s, params, &mut out, 5, &|raw, px| px.copy_from_slice(raw));
    (RawLayer::new(w, h, out, layer), stats)
}

/// Renders one layer and hands each pixel's raw sums `[ΣR, ΣG, ΣB, W, o]` to `finish`, with
/// that pixel's `stride` values of `out` (row-major, `width·height·stride` f32): storing them
/// ([`scatter_layer`]) or compositing them on the fly (`render::render`). Besides `out`,
/// allocates the scatter radii (4 bytes per pixel), the coarse grids of the passes that have
/// large-blur sources (≤ 16/4^ℓ bytes per pixel at level ℓ each) and per-worker stripe
/// scratch.
pub fn scatter_layer_into(
    layer: &Layer,
    s: &RenderSettings,
    params: FastParams,
    out: &mut [f32],
    stride: usize,
    finish: &(dyn Fn(&[f32; 5], &mut [f32]) + Sync),
) -> FastStats {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    assert_eq!(out.len(), w * h * stride, "output buffer size");
    let p = s.lens / 2;
    let mut stats = FastStats::default();

    // One pass over the layer: scatter radii, what is visible, and the on-focal band.
    let mut sigma = vec![0f32; w * h];
    let bc = band_coc();
    let survey = sigma
        .par_chunks_mut(w)
        .zip(img.data.par_chunks(w * 5))
        .map(|(srow, prow)| {
            let mut sv = Survey::EMPTY;
            for (sg, px) in srow.iter_mut().zip(prow.chunks_exact(5)) {
                let d = px[D] - s.focus;
                *sg = scatter_radius(d, s.blur);
                if px[A] > 0.0 {
                    sv.visible += 1;
                    sv.sigma_min = sv.sigma_min.min(*sg);
                    let drawn = drawn_radius(*sg, p);
                    sv.sigma_max = sv.sigma_max.max(drawn);
                    if drawn < 2.0 * params.r0 {
                        sv.full_max = sv.full_max.max(drawn);
                    }
                    if is_bright(px[0].max(px[1]).max(px[2]), 1.0, BRIGHT_MIN) {
                        sv.bright_max = sv.bright_max.max(drawn);
                    }
                }
                if in_band(d, s, bc) {
                    sv.band_pixels += 1;
                    sv.band_lo = sv.band_lo.min(d);
                    sv.band_hi = sv.band_hi.max(d);
                }
            }
            sv
        })
        .reduce(|| Survey::EMPTY, Survey::merge);
    stats.transparent_pixels = w * h - survey.visible;
    stats.band_pixels = survey.band_pixels;
    stats.stripes = h.div_ceil(STRIPE_ROWS);
    stats.exact_taps = (w * h) as f64 * disk_tap_count(s.lens) as f64;
    let unit = weight_unit(if survey.sigma_min.is_finite() { survey.sigma_min } else { 1.0 });

    let band = (survey.band_pixels > 0).then(|| Band::new(survey.band_lo, survey.band_hi, params.node_step));
    let stencil_reach = params.stencil_max.min(survey.sigma_max) + STENCIL_TAIL;
    let stencil: Vec<Tap> = disk_taps_within(s.lens, stencil_reach);
    let stencil_p = stencil.iter().map(|t| t.di.abs() as i64).max().unwrap_or(0);
    let stencil_rows: Vec<usize> = (-stencil_p..=stencil_p + 1).map(|di| stencil.partition_point(|t| (t.di as i64) < di)).collect();
    let (bright_level, bright_max) = if survey.bright_max > 0.0 {
        let level = bright_level(img, survey.visible);
        let max = if level > BRIGHT_MIN {
            let sig = &sigma;
            img.data
                .par_chunks_exact(5)
                .enumerate()
                .filter(|(_, px)| px[A] > 0.0 && is_bright(px[0].max(px[1]).max(px[2]), 1.0, level))
                .map(|(i, _)| drawn_radius(sig[i], p))
                .reduce(|| 0.0, f32::max)
        } else {
            survey.bright_max
        };
        (level, max)
    } else {
        (BRIGHT_MIN, 0.0)
    };
    let mut ctx = Ctx {
        img,
        s,
        w,
        h,
        p,
        stencil_r: stencil.iter().map(|t| t.r).collect(),
        stencil_factor: stencil.iter().map(|t| step_tap_factor(t.r)).collect(),
        stencil_rows,
        stencil_p,
        unit,
        sigma,
        sigma_max: survey.sigma_max,
        full_max: survey.full_max,
        bright_max,
        bright_level,
        params,
        band,
        has_front: false,
        has_partial: false,
    };

    // Coarse levels present, per source class: [all, front, partial] as bit masks.
    let masks = (0..w * h)
        .into_par_iter()
        .with_min_len(4096)
        .filter(|&j| img.data[j * 5 + A] > 0.0)
        .map(|j| {
            let bit = level_of(drawn_radius(ctx.sigma[j], p), params.r0).map_or(0, |l| 1u64 << l);
            let class = band.map(|b| b.class(ctx.d(j)));
            // Bit 0 marks that the class has any visible source at all; [3] counts the
            // sources hidden behind every node.
            let tag = bit | 1;
            match class {
                Some(Class::Front) => [tag, tag, 0, 0],
                Some(Class::Partial) => [tag, 0, tag, 0],
                Some(Class::Hidden) => [tag, 0, 0, 1],
                None => [tag, 0, 0, 0],
            }
        })
        .reduce(|| [0u64; 4], |a, b| [a[0] | b[0], a[1] | b[1], a[2] | b[2], a[3] + b[3]]);
    ctx.has_front = masks[1] & 1 != 0;
    ctx.has_partial = masks[2] & 1 != 0;
    let ctx = ctx;
    let n_nodes = band.map_or(0, |b| b.n);
    stats.nodes = n_nodes;
    stats.passes = 1 + usize::from(ctx.has_front) + if ctx.has_partial { n_nodes } else { 0 };
    stats.band_sources_skipped = masks[3] as usize;

    let counts = Counts::default();
    // Coarse grids of every pass, indexed by slot (0 = A, 1 = F, 2 + k = U_k).
    let empty = survey.visible == 0 || p == 0;
    let mut coarse: Vec<Vec<Coarse>> = Vec::new();
    if !empty {
        coarse.push(coarse_levels(&ctx, 0, masks[0] & !1, &counts.ops, &counts.coarse));
        coarse.push(if ctx.has_front { coarse_levels(&ctx, 1, masks[1] & !1, &counts.ops, &counts.coarse) } else { Vec::new() });
        for k in 0..n_nodes {
            coarse.push(if ctx.has_partial { coarse_levels(&ctx, 2 + k, masks[2] & !1, &counts.ops, &counts.coarse) } else { Vec::new() });
        }
    }

    // Scratch is pooled, not made per rayon split: a worker's first stripe sizes its buffers
    // and later stripes reuse them without new pages.
    let pool = std::sync::Mutex::new(Vec::<Scratch>::new());
    out.par_chunks_mut(STRIPE_ROWS * w * stride).enumerate().for_each(|(si, chunk)| {
        let mut sc = pool.lock().map(|mut p| p.pop()).ok().flatten().unwrap_or_default();
        let y0 = si * STRIPE_ROWS;
        let y1 = (y0 + STRIPE_ROWS).min(h);
        render_stripe(&ctx, &coarse, empty, y0, y1, &mut sc, &counts);
        // Hand the finished pixels over.
        for (k, px) in chunk.chunks_exact_mut(stride).enumerate() {
            let raw: &[f32; 5] = sc.raw[k * 5..k * 5 + 5].try_into().expect("5 channels");
            finish(raw, px);
        }
        if let Ok(mut p) = pool.lock() {
            p.push(sc);
        }
    });
    stats.stencil_sources = counts.stencil.into_inner() as usize;
    stats.span_sources = counts.span.into_inner() as usize;
    stats.bright_sources = counts.bright.into_inner() as usize;
    stats.coarse_sources = counts.coarse.into_inner() as usize;
    stats.band_stripes = counts.band_stripes.into_inner() as usize;
    stats.fast_ops = counts.ops.into_inner() as f64;
    stats.work_saved = if stats.exact_taps > 0.0 { (1.0 - stats.fast_ops / stats.exact_taps).max(0.0) } else { 0.0 };
    stats
}

/// Renders rows `[y0, y1)` into `sc.raw` as raw 5-channel pixels.
fn render_stripe(ctx: &Ctx, coarse: &[Vec<Coarse>], empty: bool, y0: usize, y1: usize, sc: &mut Scratch, counts: &Counts) {
    let w = ctx.w;
    let rows = y1 - y0;
    visibility_rows(ctx.img, &ctx.sigma, ctx.p, y0, y1, &mut sc.sat, &mut sc.vis);
    let mut raw = std::mem::take(&mut sc.raw);
    raw.clear();
    raw.resize(rows * w * 5, 0.0);
    if empty {
        for (o, &v) in raw.chunks_exact_mut(5).zip(&sc.vis) {
            o[4] = v;
        }
        sc.raw = raw;
        return;
    }

    // Targets of this stripe: q, and the band's nodes they need.
    sc.q.clear();
    let bc = band_coc();
    let (mut blo, mut bhi) = (f32::INFINITY, f32::NEG_INFINITY);
    for i in y0 * w..y1 * w {
        // q < 1 marks a band target; the others count as q = 1 (occlusion ≡ 1).
        let d = ctx.d(i);
        let q = if in_band(d, ctx.s, bc) {
            blo = blo.min(d);
            bhi = bhi.max(d);
            focal_defocus(d, ctx.s.blur)
        } else {
            1.0
        };
        sc.q.push(q);
    }
    let nodes = match ctx.band {
        Some(b) if blo <= bhi && (ctx.has_front || ctx.has_partial) => Some(b.nodes_for(blo, bhi)),
        _ => None,
    };
    let n_acc = match nodes {
        Some((ka, kb)) if ctx.has_partial => 2 + kb - ka + 1,
        Some(_) => 2,
        None => 1,
    };
    if nodes.is_some() {
        counts.band_stripes.fetch_add(1, Ordering::Relaxed);
    }
    while sc.accs.len() < n_acc {
        sc.accs.push(Stripe::new(w));
    }
    for a in &mut sc.accs[..n_acc] {
        a.reset(y0, y1);
    }

    scan_sources(ctx, nodes, y0, y1, sc, counts);
    combine_rows(ctx, coarse, nodes, y0, y1, sc, &mut raw);
    counts.ops.fetch_add((rows * w * n_acc) as u64, Ordering::Relaxed);
    sc.raw = raw;
}

/// Scatters the full-resolution sources that reach rows `[y0, y1)` (exact stencils and
/// directly drawn disks) into the stripe accumulators `sc.accs`: `A`, and for a stripe with
/// band targets `F` and the `U_k` of `nodes`.
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
            let bright = is_bright(v[0].max(v[1]).max(v[2]), v[3], ctx.bright_level);
            if sig >= 2.0 * pr.r0 && !bright {
                continue;
            }
            sc.dests.clear();
            sc.dests.push((0, 1.0));
            if let (Some((ka, kb)), Some(b)) = (nodes, ctx.band) {
                let dj = ctx.d(j);
                match b.class(dj) {
                    Class::Front => sc.dests.push((1, 1.0)),
                    Class::Partial => sc.dests.extend((ka..=kb).map(|k| (2 + k - ka, in_front(dj, b.node(k))))),
                    Class::Hidden => {}
                }
            }
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
                    stencil_weights(ctx, sig, dens, &mut sc.stencil_w);
                    sc.stencil_sigma = true_sig;
                }
                // Visit only this stripe's rows.
                let (ra, rb) = ((y0i - sy).max(-ctx.stencil_p), (y1i - 1 - sy).min(ctx.stencil_p));
                for di in ra..=rb {
                    let (jm, ref e) = sc.stencil_w[(di + ctx.stencil_p) as usize];
                    if e.is_empty() {
                        continue;
                    }
                    for &(slot, f) in &sc.dests {
                        sc.accs[slot].tap_row(sx - jm, sy + di, e, v.map(|c| c * f));
                    }
                    ops += (e.len() * sc.dests.len()) as u64;
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
    }

    counts.stencil.fetch_add(n_st, Ordering::Relaxed);
    counts.span.fetch_add(n_sp, Ordering::Relaxed);
    counts.bright.fetch_add(n_br, Ordering::Relaxed);
    counts.ops.fetch_add(ops, Ordering::Relaxed);
}

/// Resolves the stripe accumulators row by row, adds the coarse levels and combines:
/// `A` everywhere; `q·A + (1-q)·B` plus the centre correction in the band. Writes `raw`.
#[inline(never)]
fn combine_rows(ctx: &Ctx, coarse: &[Vec<Coarse>], nodes: Option<(usize, usize)>, y0: usize, y1: usize, sc: &mut Scratch, raw: &mut [f32]) {
    let w = ctx.w;
    let (row_a, row_b, row_u, tmp) = (&mut sc.row_a, &mut sc.row_b, &mut sc.row_u, &mut sc.tmp);
    for r in 0..y1 - y0 {
        let y = y0 + r;
        row_a.clear();
        row_a.resize(w * 4, 0.0);
        sc.accs[0].add_row_to(r, row_a);
        for c in &coarse[0] {
            c.grid.add_upsampled_row(y, c.factor, row_a, tmp);
        }
        let q = &sc.q[r * w..(r + 1) * w];
        let out = &mut raw[r * w * 5..(r + 1) * w * 5];
        for (x, o) in out.chunks_exact_mut(5).enumerate() {
            o[..4].copy_from_slice(&row_a[x * 4..x * 4 + 4]);
            o[4] = sc.vis[r * w + x];
        }
        let (Some((ka, kb)), Some(band)) = (nodes, ctx.band) else { continue };
        // B = F + Σ_k hat_k(d_x)·U_k (the hats sum to 1 over the band), held in row_b.
        row_b.clear();
        row_b.resize(w * 4, 0.0);
        if ctx.has_front {
            sc.accs[1].add_row_to(r, row_b);
            for c in &coarse[1] {
                c.grid.add_upsampled_row(y, c.factor, row_b, tmp);
            }
        }
        if ctx.has_partial {
            for k in ka..=kb {
                row_u.clear();
                row_u.resize(w * 4, 0.0);
                sc.accs[2 + k - ka].add_row_to(r, row_u);
                for c in &coarse[2 + k] {
                    c.grid.add_upsampled_row(y, c.factor, row_u, tmp);
                }
                for x in 0..w {
                    if q[x] < 1.0 {
                        let wk = band.hat(k, ctx.d(y * w + x));
                        if wk > 0.0 {
                            for c in 0..4 {
                                row_b[x * 4 + c] += wk * row_u[x * 4 + c];
                            }
                        }
                    }
                }
            }
        }
        for (x, o) in out.chunks_exact_mut(5).enumerate() {
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
}

/// Non-focal visibility (eq. 4) of rows `[y0, y1)` into `out`: box means of the
/// replicate-padded alpha from a summed-area table of just the rows the boxes reach (f64).
/// O(1) per pixel plus the table, `(rows + 2n)·(w + 2n)` for the stripe's largest box half-size n.
#[inline(never)]
fn visibility_rows(img: &crate::Image, sigma: &[f32], p: usize, y0: usize, y1: usize, sat: &mut Vec<f64>, out: &mut Vec<f32>) {
    let (w, h) = (img.width, img.height);
    let nmax = sigma[y0 * w..y1 * w].iter().map(|&s| visibility_half_size(s, p)).max().unwrap_or(0);
    out.clear();
    // Every box lies in these rows; if their alpha is one constant (an opaque background, an
    // empty part of a foreground layer), every mean is that constant, exactly.
    let (ra, rb) = (y0.saturating_sub(nmax), (y1 + nmax).min(h));
    if nmax == 0 {
        // Every box is the pixel itself.
        out.extend(img.data[y0 * w * 5..y1 * w * 5].chunks_exact(5).map(|px| px[A]));
        return;
    }
    let a0 = img.data[ra * w * 5 + A];
    if img.data[ra * w * 5..rb * w * 5].chunks_exact(5).all(|px| px[A] == a0) {
        out.resize((y1 - y0) * w, a0);
        return;
    }
    let (pw, ph) = (w + 2 * nmax, (y1 - y0) + 2 * nmax);
    sat.clear();
    sat.resize((pw + 1) * (ph + 1), 0.0);
    for yy in 0..ph {
        let sy = (y0 as i64 + yy as i64 - nmax as i64).clamp(0, h as i64 - 1) as usize;
        let src = &img.data[sy * w * 5..(sy + 1) * w * 5];
        let (above, this) = sat[yy * (pw + 1)..(yy + 2) * (pw + 1)].split_at_mut(pw + 1);
        let mut row = 0f64;
        // Replicate padding: the left and right margins repeat the edge pixels.
        let alpha = std::iter::repeat_n(src[A], nmax)
            .chain(src.chunks_exact(5).map(|px| px[A]))
            .chain(std::iter::repeat_n(src[(w - 1) * 5 + A], nmax));
        for ((t, &u), a) in this[1..].iter_mut().zip(&above[1..]).zip(alpha) {
            row += a as f64;
            *t = u + row;
        }
    }
    let inv_area: Vec<f64> = (0..=nmax).map(|n| 1.0 / ((2 * n + 1) * (2 * n + 1)) as f64).collect();
    for y in y0..y1 {
        for x in 0..w {
            let n = visibility_half_size(sigma[y * w + x], p);
            let (cx, cy) = (x + nmax, y - y0 + nmax);
            let (xa, ya, xb, yb) = (cx - n, cy - n, cx + n + 1, cy + n + 1);
            let s = sat[yb * (pw + 1) + xb] - sat[ya * (pw + 1) + xb] - sat[yb * (pw + 1) + xa] + sat[ya * (pw + 1) + xa];
            out.push((s * inv_area[n]) as f32);
        }
    }
}
