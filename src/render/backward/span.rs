//! A fast differentiable render of one opaque layer, for depth from defocus: the function of
//! [`super::Tape`] (the exact kernel; physical: with [`Smoothing`]'s edges) for a single layer
//! of alpha 1, drawn as spans instead of taps, with the in-layer depth terms interpolated over
//! the sources' depth; its vector-Jacobian product with respect to the colour, the disparity,
//! the focus and K. Both profiles; they differ in the footprint ([`Model`]), in what the bins'
//! weights split a source into ([`Bins::shape`]) and in how a target combines them.
//!
//! Forward. Each source `y` spreads `u_y = cov(R_y, ρ)/N(R_y)` ([`lens::disk_coverage_smooth`],
//! [`lens::disk_norm_smooth`], `R = K·|d|`) of `v_y = [c_y, 1]`. The depth group a source
//! joins at target `x`, `γ(d_y, d_x)` ([`lens::depth_groups`]), depends on both depths; here
//! it is interpolated linearly in the source's depth between depth bins `δ_b` (spacing
//! [`BIN_STEP`], relative disparity): a source is drawn, with hat weights `hat_b(d_y)`, into
//! the two bins around its depth, each bin one 4-channel scatter `B_b(x) = Σ_y hat_b(d_y)·u_y(x)·v_y`
//! (a smooth disk per source, its plateau one span per row and its edge as taps:
//! `render::fast::footprint::smooth_coverage_disk` into [`Stripe`]s), and a target
//! takes `G_k(x) = Σ_b γ_k(δ_b, d_x)·B_b(x)` with its exact depth. The target's own source, which
//! the exact kernel puts whole into the "same surface" group, is moved there exactly. The
//! groups are filled by [`lens::over_groups_smooth`]; the pixel is composited as the tape does
//! (one backdrop layer of alpha 1). Without occlusion there is one bin and one group: the plain
//! normalized scatter.
//!
//! Official profile: the footprint is the soft step `E = step(σ, ρ)·(unit/σ)²`, `σ = K·|d| + 1`
//! (the norm `N = (σ/unit)²`), drawn as the fast kernel draws it
//! (`render::fast::footprint::soft_step_disk`: 1 within `σ - 4`, the step out to `σ + 2.5`,
//! within 6.2e-5 of the step). The on-focal occlusion `O = q(x) + (1 - q(x))·f(d_y, d_x)` needs
//! two sums per target: slot 0 weighs each bin by the in-front weight `f(δ_b, d_x)`, slot 1
//! takes every bin whole, and the target's `[ΣRGB, W] = q·slot 1 + (1 - q)·slot 0`, its own
//! source moved to `O = 1`; the pixel is `ΣRGB/W`. The same scatter, gathers and VJP serve
//! both profiles with the split `[f, 1, 0]` in place of the three groups.
//!
//! Backward (w.r.t. every pixel's colour and disparity, the focus and K; the layer is opaque,
//! so there is no alpha gradient). The targets' group cotangents come from
//! [`lens::over_groups_smooth_vjp`]; a target's own depth moves its `γ(δ_b, d_x)` (whose
//! derivative in `d_x` the forward keeps per pixel, 96 bytes) and its own-source correction. A
//! source's depth moves its hats and its radius: with `gB_b(x) = Σ_k γ_k(δ_b, d_x)·ḡ_k(x)` the
//! cotangent of bin `b`, `∂L/∂d_y = Σ_b hat_b'·S_b + hat_b·(T_b/N - S_b·N'/N)·∂R/∂d` where
//! `S_b = Σ_x u_y(x)·gB_b(x)·v_y` is read from row prefix sums of `gB_b` at the span ends (the
//! adjoint of "difference-array spans + row prefix sums") and the edge taps, and
//! `T_b = Σ_x cov'(R_y, ρ)·gB_b(x)·v_y` needs only the edge taps. The same gathers before the
//! dot with `v_y` give the colour, `∂L/∂c_y = Σ_b hat_b·S_b/N` per channel (plus the own-source
//! correction); `d = D - focus` makes `∂L/∂focus = -Σ_y ∂L/∂D_y`, and `R = K·|d|` makes
//! `∂L/∂K = Σ_y ∂L/∂R_y·|d_y|`.
//!
//! Accuracy: the only approximation is the interpolation of `γ` in the source's depth
//! (error ≤ `BIN_STEP²/8·max|γ''|` ≈ 5e-4 of a source's weight at `BIN_STEP` = 0.01), and in
//! the official profile the truncated soft step; without occlusion the physical render is the
//! tape's up to rounding. `tests/span_tape.rs` measures both
//! against [`super::Tape`] and central differences.
//!
//! Cost: O(pixels·(R + bins)) per render and per VJP instead of the tape's O(pixels·lens²):
//! each source writes O(R) values into two bins, each target row is prefix-summed once per bin
//! its stripe uses, and each target evaluates `γ` once per non-empty bin. Parallel in stripes
//! of rows; memory: the stripe scratch (per worker, ~0.4 MB per bin at 512 px wide), 192 bytes
//! per pixel kept for the VJP, and one bin's prefix rows per backward stripe.

use super::Smoothing;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::fast::footprint::{RIM, STENCIL_TAIL, rim_row, smooth_coverage_disk, soft_step_disk};
use crate::render::layer::{CHANNELS, D, Layer};
use crate::render::lens::{self, Profile};
use crate::render::splat::Stripe;
use crate::render::{RawLayer, RenderSettings, composite, raw, validate};
use rayon::prelude::*;

/// Spacing of the depth bins over which the depth groups are interpolated, in relative
/// (normalized) disparity. The soft depth test `0.5 + 0.5·tanh(10(d_y - d_x - 0.1))` changes
/// over ~0.1; linear interpolation at 0.01 moves a group weight by at most 5e-4. Measured
/// (`tests/span_tape.rs`, README): images within 4e-5 and disparity gradients within 0.3%
/// (relative L2) of the exact tape's.
pub const BIN_STEP: f32 = 0.01;

/// Target rows per forward stripe: the stripe keeps one 4-channel accumulator per depth bin its
/// sources use (~24 KB per row and bin at 512 px), so stripes are short.
const FWD_ROWS: usize = 16;
/// Source rows per backward stripe: each builds prefix rows of the bins' cotangents over its
/// rows plus the largest reach on both sides, so taller stripes repeat less of that work.
const BWD_ROWS: usize = 64;

/// The depth bins: centres `δ_b = (first + b)·step`, relative disparity, on one lattice
/// whatever the layer's range (so the interpolation, hence the function, does not depend on
/// which depths are present). One bin without occlusion.
#[derive(Clone, Copy, Debug)]
struct Bins {
    first: i64,
    count: usize,
    step: f32,
    grouped: bool,
    /// The official profile's split (see [`Bins::shape`]).
    official: bool,
}

impl Bins {
    fn new(d: &[f32], grouped: bool, official: bool) -> Self {
        if !grouped {
            return Bins { first: 0, count: 1, step: 1.0, grouped, official };
        }
        let (lo, hi) = d.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let first = (lo / BIN_STEP).floor() as i64;
        let last = ((hi / BIN_STEP).floor() as i64 + 1).max(first + 1);
        Bins { first, count: (last - first + 1) as usize, step: BIN_STEP, grouped, official }
    }

    /// The split of a unit of a source's weight seen from a target, from the two tanh of the
    /// soft depth test (`t_front` for "the source is in front", `t_behind` the reverse), and
    /// its derivative in the source's depth. Physical: the three depth groups
    /// ([`lens::depth_groups_from_tanh`]). Official: `[f, 1, 0]` with `f` the in-front weight
    /// ([`lens::in_front_from_tanh`]): slot 0 sums the light the on-focal occlusion weighs by
    /// `f`, slot 1 all of it (the target mixes them as `(1 - q)·slot 0 + q·slot 1`).
    #[inline(always)]
    fn shape(&self, t_front: f32, t_behind: f32) -> ([f32; 3], [f32; 3]) {
        if self.official {
            let (f, df) = lens::in_front_from_tanh(t_front);
            ([f, 1.0, 0.0], [df, 0.0, 0.0])
        } else {
            lens::depth_groups_from_tanh(t_front, t_behind)
        }
    }

    /// Where a target's own source belongs: the surface group (physical), or weight 1 in both
    /// slots (official: the centre tap is never occluded).
    fn centre_split(&self) -> [f64; 3] {
        if self.official { [1.0, 1.0, 0.0] } else { [0.0, 1.0, 0.0] }
    }

    /// The centre of bin `b`.
    #[inline]
    fn centre(&self, b: usize) -> f32 {
        (self.first + b as i64) as f32 * self.step
    }

    /// The two bins a source at relative disparity `d` is drawn into: `(bin, hat, ∂hat/∂d)`.
    #[inline]
    fn locate(&self, d: f32) -> [(usize, f32, f32); 2] {
        if !self.grouped {
            return [(0, 1.0, 0.0), (0, 0.0, 0.0)];
        }
        let u = d / self.step - self.first as f32;
        let b0 = (u.floor().max(0.0) as usize).min(self.count - 2);
        let t = (u - b0 as f32).clamp(0.0, 1.0);
        [(b0, 1.0 - t, -1.0 / self.step), (b0 + 1, t, 1.0 / self.step)]
    }

    /// The group split of a unit of weight in bin `b` seen from a target at `dx`, and its
    /// derivative in the bin's depth (`-∂/∂dx`).
    #[inline]
    fn split(&self, b: usize, dx: f32) -> ([f32; 3], [f32; 3]) {
        if self.grouped {
            let c = self.centre(b);
            self.shape(lens::in_front_tanh(c, dx), lens::in_front_tanh(dx, c))
        } else {
            ([0.0, 1.0, 0.0], [0.0; 3])
        }
    }
}

/// The depth-group split of a run of targets, bin after bin: the two tanh of
/// [`lens::depth_groups_from_tanh`] from the factored form ([`lens::in_front_tanh_pair`]): one
/// exp per target per run, one per bin, two divisions per target and bin (the tanh evaluated
/// per target and bin were 45% of a step at 512², K = 30). Where the bins span more than the
/// factored form allows, the tanh are evaluated directly. Only with occlusion (one bin
/// otherwise, split `[0, 1, 0]`).
struct Walk {
    tx: Vec<f64>,
    nb: f64,
    bin: usize,
    centre: f32,
    factored: bool,
}

impl Walk {
    fn new(bins: &Bins) -> Self {
        let half = 0.5 * bins.count as f32 * bins.step;
        let centre = bins.centre(0) + half;
        Walk { tx: Vec::new(), nb: 0.0, bin: 0, centre, factored: bins.grouped && half + bins.step < lens::IN_FRONT_FACTORED_MAX }
    }

    /// Starts a run of targets of relative disparities `d`.
    fn targets(&mut self, d: &[f32]) {
        if self.factored {
            self.tx.clear();
            self.tx.extend(d.iter().map(|&dx| lens::in_front_target_factor(dx, self.centre)));
        }
    }

    /// Moves to bin `b`.
    fn goto(&mut self, bins: &Bins, b: usize) {
        self.bin = b;
        if self.factored {
            self.nb = lens::in_front_neighbour_factor(bins.centre(b), self.centre);
        }
    }

    /// The split of target `x` of the run (relative disparity `dx`) at the current bin and its
    /// derivative in the bin's depth.
    #[inline]
    fn split(&self, bins: &Bins, x: usize, dx: f32) -> ([f32; 3], [f32; 3]) {
        if !bins.grouped {
            ([0.0, 1.0, 0.0], [0.0; 3])
        } else if self.factored {
            let (tf, tb) = lens::in_front_tanh_pair(self.nb * self.tx[x]);
            bins.shape(tf, tb)
        } else {
            bins.split(self.bin, dx)
        }
    }
}

/// The footprint a source spreads: what differs between the profiles on the source side.
#[derive(Clone, Copy, Debug)]
enum Model {
    /// The smooth-edged disk `cov(R, ρ)/N(R)` of radius `R = K·|d|`, edge `edge` px wide.
    Physical { edge: f32 },
    /// The official soft step `step(σ, ρ)·(unit/σ)²` of radius `σ = K·|d| + 1`, drawn as the
    /// fast kernel draws it: 1 within `σ - RIM`, the step out to `σ + STENCIL_TAIL`.
    Official { unit: f32 },
}

/// The per-pixel terms every pass reads: relative disparity, footprint radius (`R` or `σ`),
/// norm `N` (the footprint's value is `cov/N`) and its derivative, `∂R/∂d`.
struct Ctx<'a> {
    img: &'a Image,
    w: usize,
    h: usize,
    /// Lens window half-size (taps `|offset| < p`).
    p: i64,
    /// How far outside the image the (replicate-padded) sources that reach it lie.
    pad: i64,
    model: Model,
    d: Vec<f32>,
    radius: Vec<f32>,
    norm: Vec<(f32, f32)>,
    dr_dd: Vec<f32>,
    /// `∂R/∂K` (`|d|`, 0 where the radius is capped).
    dr_dk: Vec<f32>,
    blur: f32,
    bins: Bins,
}

impl<'a> Ctx<'a> {
    fn new(layer: &'a Layer, s: &RenderSettings, sm: &Smoothing) -> Self {
        let img = layer.image();
        let (w, h) = (img.width, img.height);
        let d: Vec<f32> = img.data.chunks_exact(CHANNELS).map(|px| px[D] - s.focus).collect();
        let (model, radius, norm): (_, Vec<f32>, Vec<(f32, f32)>) = match s.profile {
            Profile::Physical => {
                let radius: Vec<f32> = d.iter().map(|&d| lens::coc_radius(d, s.blur).min(lens::MAX_RADIUS)).collect();
                let norm = radius.par_iter().map(|&r| lens::disk_norm_smooth(r, sm.edge_width)).collect();
                (Model::Physical { edge: sm.edge_width }, radius, norm)
            }
            Profile::Official => {
                let sigma: Vec<f32> = d.iter().map(|&d| lens::scatter_radius(d, s.blur)).collect();
                let unit = lens::weight_unit(crate::render::min_visible_radius(img, &sigma));
                // `(unit/σ)²` is the density: N = (σ/unit)², ∂N/∂σ = 2σ/unit².
                let norm = sigma.iter().map(|&g| ((g / unit) * (g / unit), 2.0 * g / (unit * unit))).collect();
                (Model::Official { unit }, sigma, norm)
            }
        };
        let (dr_dd, dr_dk) = d.iter().map(|&d| lens::coc_radius_grad(d, s.blur)).unzip();
        let p = (s.lens / 2) as i64;
        let mut ctx = Ctx { img, w, h, p, pad: 0, model, d, radius, norm, dr_dd, dr_dk, blur: s.blur, bins: Bins::new(&[], false, false) };
        let reach = ctx.radius.iter().fold(0f32, |m, &r| m.max(ctx.edges(r).0));
        ctx.pad = (reach.min(1e9).ceil() as i64).min(p);
        ctx.bins = Bins::new(&ctx.d, s.occlusion, s.profile == Profile::Official);
        ctx
    }

    /// The official on-focal factor `q` of target `i` and `(∂q/∂d, ∂q/∂K)`
    /// ([`lens::focal_defocus`]); 1 (no occlusion) without occlusion terms or in the physical
    /// profile.
    #[inline]
    fn defocus(&self, i: usize) -> (f32, f32, f32) {
        if matches!(self.model, Model::Official { .. }) && self.bins.grouped {
            let (dq_dd, dq_dk) = lens::focal_defocus_grad(self.d[i], self.blur);
            (lens::focal_defocus(self.d[i], self.blur), dq_dd, dq_dk)
        } else {
            (1.0, 0.0, 0.0)
        }
    }

    /// A footprint of radius `r`'s `(reach, inner)`: nothing beyond `reach`, the plateau
    /// (value `1/N`) within `inner`, the rim taps between.
    #[inline]
    fn edges(&self, r: f32) -> (f32, f32) {
        match self.model {
            Model::Physical { edge } => (r + 0.5 * edge, r - 0.5 * edge),
            Model::Official { .. } => (r + STENCIL_TAIL, r - RIM),
        }
    }

    /// A rim tap of a footprint of radius `r` at distance `rho`: its value times `N` and the
    /// derivative of that in `r`.
    #[inline]
    fn rim(&self, r: f32, rho: f32) -> (f32, f32) {
        match self.model {
            Model::Physical { edge } => (lens::disk_coverage_smooth(r, rho, edge), lens::disk_coverage_smooth_grad(r, rho, edge)),
            Model::Official { .. } => (lens::soft_step(r, rho), lens::soft_step_grad(r, rho)),
        }
    }

    /// Draws source `j` at `(sx, sy)` into `N` stripes with values `vs` (its footprint over
    /// its norm).
    #[inline]
    fn draw<const N: usize>(&self, sts: [&mut Stripe; N], (sx, sy): (i64, i64), j: usize, vs: [[f32; 4]; N], e: &mut Vec<f32>) {
        let (r, norm) = (self.radius[j], self.norm[j].0);
        match self.model {
            Model::Physical { edge } => smooth_coverage_disk(sts, (sx, sy), r, edge, norm, self.p, vs, e),
            Model::Official { unit } => soft_step_disk(sts, (sx, sy), r, lens::density(r, unit), self.p, vs, e),
        };
    }

    /// The pixel a (possibly padded) source position reads, replicate padding.
    #[inline]
    fn clamp_index(&self, sx: i64, sy: i64) -> usize {
        sy.clamp(0, self.h as i64 - 1) as usize * self.w + sx.clamp(0, self.w as i64 - 1) as usize
    }

    /// `[c_r, c_g, c_b, 1]` of pixel `j`.
    #[inline]
    fn value(&self, j: usize) -> [f32; 4] {
        let px = &self.img.data[j * CHANNELS..j * CHANNELS + 3];
        [px[0], px[1], px[2], 1.0]
    }

    /// The source rows that can reach target rows `[y0, y1)`, padding included.
    fn source_rows(&self, y0: usize, y1: usize) -> std::ops::Range<i64> {
        (y0 as i64 - self.pad).max(-self.pad)..(y1 as i64 + self.pad).min(self.h as i64 + self.pad)
    }

    /// The rows `[lo, hi]` a source at row `sy` reaches, and its edge `(reach, inner)`.
    #[inline]
    fn extent(&self, j: usize, sy: i64) -> (i64, i64, f32, f32) {
        let (reach, inner) = self.edges(self.radius[j]);
        let rr = (reach.min(1e9).ceil() as i64).min(self.p);
        (sy - rr, sy + rr, reach, inner)
    }

    /// The own-source terms of target `i`: its weight at its own pixel `u`, `∂u/∂R`, and per
    /// group `η_k` (the share of it the bins gave group k) and `∂η_k/∂d`. The exact kernel
    /// never occludes the centre tap: `centre_split - η_k` moves it where it belongs.
    fn own(&self, i: usize) -> (f64, f64, [f64; 3], [f64; 3]) {
        if !self.bins.grouped || self.p < 1 {
            return (0.0, 0.0, [0.0; 3], [0.0; 3]);
        }
        let (r, (n, dn)) = (self.radius[i], self.norm[i]);
        // The centre is a plateau pixel where the plateau reaches it (as `rim_row` decides).
        let (cov, dcov) = if self.edges(r).1 > 0.0 { (1.0, 0.0) } else { self.rim(r, 0.0) };
        let u = cov as f64 / n as f64;
        let du = dcov as f64 / n as f64 - u * dn as f64 / n as f64;
        let dx = self.d[i];
        let (mut eta, mut deta) = ([0f64; 3], [0f64; 3]);
        for (b, hat, dhat) in self.bins.locate(dx) {
            let (g, dg) = self.bins.split(b, dx);
            for k in 0..3 {
                eta[k] += (hat * g[k]) as f64;
                deta[k] += (dhat * g[k] - hat * dg[k]) as f64;
            }
        }
        (u, du, eta, deta)
    }
}

/// What the forward keeps per target for the VJP: the depth groups `[P_r, P_g, P_b, a]` before
/// the fill and their derivative in the target's own relative disparity.
#[derive(Clone, Copy, Default)]
struct Target {
    groups: [[f64; 4]; 3],
    dgroups: [[f64; 4]; 3],
}

/// A recorded span render of one opaque layer (physical profile): its image and what
/// [`SpanTape::vjp`] needs. The function is that of [`super::Tape`] for the same
/// layer, settings and smoothing, except that the depth groups' split is interpolated between
/// depth bins [`BIN_STEP`] apart (see the module notes); without occlusion, the same up to
/// rounding.
pub struct SpanTape<'a> {
    ctx: Ctx<'a>,
    fill_width: f64,
    targets: Vec<Target>,
    raw: RawLayer,
    image: Image,
}

impl<'a> SpanTape<'a> {
    /// Renders `layer` (every alpha 1) with the physical profile, `smoothing`'s edges and the
    /// lens window `s.lens`, and keeps the per-pixel groups (192 bytes per pixel). Errors
    /// (usage): the checks of [`crate::render::render`], a layer that is not opaque, the
    /// official profile (use [`super::Tape`]). Cost: see the module notes.
    pub fn record(layer: &'a Layer, s: &RenderSettings, smoothing: Smoothing) -> Result<Self> {
        validate(std::slice::from_ref(layer), s)?;
        smoothing.validate()?;
        if !layer.is_opaque() {
            return Err(Error::usage("the span render takes one opaque layer (alpha 1 everywhere)"));
        }
        let ctx = Ctx::new(layer, s, &smoothing);
        let fill_width = smoothing.fill_width as f64;
        let (w, h) = (ctx.w, ctx.h);
        let mut targets = vec![Target::default(); w * h];
        let mut out = vec![0f32; w * h * raw::CHANNELS];
        out.par_chunks_mut(FWD_ROWS * w * raw::CHANNELS).zip(targets.par_chunks_mut(FWD_ROWS * w)).enumerate().for_each_init(
            || Scratch::new(w, &ctx.bins),
            |sc, (k, (out, tg))| {
                let y0 = k * FWD_ROWS;
                forward_stripe(&ctx, fill_width, y0, (y0 + FWD_ROWS).min(h), sc, out, tg);
            },
        );
        let raw = RawLayer::new(w, h, out, layer);
        let image = composite::composite(std::slice::from_ref(&raw));
        if !image.all_finite() {
            return Err(Error::Internal(format!(
                "the span render produced non-finite pixels (blur {}, focus {}, lens {}); please report this",
                s.blur, s.focus, s.lens
            )));
        }
        Ok(SpanTape { ctx, fill_width, targets, raw, image })
    }

    /// The rendered linear RGB image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The gradients of a loss whose gradient with respect to [`SpanTape::image`] is
    /// `cotangent` (3 channels, the image's size, finite): with respect to every pixel's colour
    /// and normalized disparity, the focus and K (the layer is opaque: no alpha gradient). f64
    /// sums, saturated at ±`f32::MAX`. Allocates 96 bytes per pixel of group cotangents, 48 of
    /// sums and, per backward worker, two bins' prefix rows. Cost: see the module notes.
    pub fn vjp(&self, cotangent: &Image) -> Result<SpanGradients> {
        let (w, h) = (self.ctx.w, self.ctx.h);
        super::check_cotangent(cotangent, w, h)?;
        let ctx = &self.ctx;
        // Targets: the composite's and the fill's adjoints, the target's own depth and its own
        // source's correction (moved whole to the surface group).
        let mut grads = vec![SourceGrad::default(); w * h];
        let gg: Vec<[[f64; 4]; 3]> = self
            .targets
            .par_iter()
            .zip(grads.par_iter_mut())
            .enumerate()
            .map(|(i, (t, og))| {
                let g: [f64; 3] = std::array::from_fn(|c| cotangent.data[i * 3 + c] as f64);
                let official = matches!(ctx.model, Model::Official { .. });
                let cot = composite_adjoint(self.raw.pixel(i), g, official);
                if cot == [0.0; 4] {
                    return [[0.0; 4]; 3];
                }
                let gg = if official {
                    // S = q·slot 1 + (1 - q)·slot 0: q's own derivative, then the slots'.
                    let (q, dq_dd, dq_dk) = ctx.defocus(i);
                    let g_q = (0..4).map(|c| cot[c] * (t.groups[1][c] - t.groups[0][c])).sum::<f64>();
                    og.d = g_q * dq_dd as f64;
                    og.k = g_q * dq_dk as f64;
                    [cot.map(|c| (1.0 - q as f64) * c), cot.map(|c| q as f64 * c), [0.0; 4]]
                } else {
                    lens::over_groups_smooth_vjp(&t.groups, self.fill_width, &cot)
                };
                og.d += (0..3).map(|k| (0..4).map(|c| gg[k][c] * t.dgroups[k][c]).sum::<f64>()).sum::<f64>();
                let (u, du_dr, eta, _) = ctx.own(i);
                if u != 0.0 || du_dr != 0.0 {
                    let v = ctx.value(i);
                    let centre = ctx.bins.centre_split();
                    for k in 0..3 {
                        let keep = centre[k] - eta[k];
                        og.r += du_dr * keep * (0..4).map(|c| gg[k][c] * v[c] as f64).sum::<f64>();
                        for (o, g) in og.c.iter_mut().zip(&gg[k]) {
                            *o += u * keep * g;
                        }
                    }
                }
                gg
            })
            .collect();
        // Sources: gathers of the bins' cotangents over each source's disk.
        let rows: Vec<i64> = (-ctx.pad..h as i64 + ctx.pad).step_by(BWD_ROWS).collect();
        let parts: Vec<Vec<(usize, SourceGrad)>> =
            rows.par_iter().map(|&sy0| backward_stripe(ctx, &gg, sy0, (sy0 + BWD_ROWS as i64).min(h as i64 + ctx.pad))).collect();
        for part in parts {
            for (j, v) in part {
                grads[j].add(&v);
            }
        }
        // The focus moves every relative disparity (d = D - focus), K every radius (R = K·|d|).
        let focus = -grads.iter().map(|g| g.d).sum::<f64>();
        let blur = grads.iter().zip(&ctx.dr_dk).map(|(g, &k)| g.r * k as f64 + g.k).sum::<f64>();
        let sat = |v: f64| v.clamp(-(f32::MAX as f64), f32::MAX as f64) as f32;
        let colour = grads.iter().flat_map(|g| g.c.map(sat)).collect();
        let disparity = grads.iter().map(|g| sat(g.d)).collect();
        Ok(SpanGradients {
            colour: Image::from_vec(w, h, 3, colour).expect("three values per pixel"),
            disparity: Image::from_vec(w, h, 1, disparity).expect("one value per pixel"),
            focus: sat(focus),
            blur: sat(blur),
        })
    }

    /// `∂L/∂D` alone (one channel, the layer's size; D the normalized disparity): the
    /// `disparity` of [`SpanTape::vjp`].
    pub fn disparity_vjp(&self, cotangent: &Image) -> Result<Image> {
        Ok(self.vjp(cotangent)?.disparity)
    }
}

/// The gradients of [`SpanTape::vjp`].
#[derive(Clone, Debug, PartialEq)]
pub struct SpanGradients {
    /// `∂L/∂` R, G, B of every pixel (linear, straight colour): 3 channels, the layer's size.
    pub colour: Image,
    /// `∂L/∂D` of every pixel (D the normalized disparity): 1 channel.
    pub disparity: Image,
    /// `∂L/∂focus`.
    pub focus: f32,
    /// `∂L/∂K` (`RenderSettings::blur`).
    pub blur: f32,
}

/// One pixel's share of the gradients, summed over the sources it replicates and its target:
/// `∂L/∂d` (everything), `∂L/∂R` (the radius' part of it, for K), `∂L/∂K` through the
/// official on-focal factor `q`, `∂L/∂c`.
#[derive(Clone, Copy, Default)]
struct SourceGrad {
    d: f64,
    r: f64,
    k: f64,
    c: [f64; 3],
}

impl SourceGrad {
    fn add(&mut self, o: &SourceGrad) {
        self.d += o.d;
        self.r += o.r;
        self.k += o.k;
        for c in 0..3 {
            self.c[c] += o.c[c];
        }
    }
}

/// The compositor's adjoint for one backdrop layer of alpha 1 (as [`super::Tape`] takes it):
/// physical, the pixel is `clamp(P/A)` where `A < 1` (the backdrop's visibility is its alpha
/// of 1) and `P` where `A = 1`; official, `clamp(ΣRGB/W)` (visibility 1). The clamp, which
/// only removes rounding, is the identity. Returns the cotangent of `[P_r, P_g, P_b, A]` or
/// `[ΣR, ΣG, ΣB, W]`.
#[inline]
fn composite_adjoint(px: &[f32], g: [f64; 3], official: bool) -> [f64; 4] {
    let a = px[raw::WEIGHT] as f64;
    if official || 1.0 > a {
        if a <= 0.0 {
            return [0.0; 4];
        }
        let gx: [f64; 3] = std::array::from_fn(|c| g[c] / a);
        [gx[0], gx[1], gx[2], -(0..3).map(|c| gx[c] * px[c] as f64 / a).sum::<f64>()]
    } else {
        [g[0], g[1], g[2], 0.0]
    }
}

/// A forward worker's scratch: one stripe accumulator per depth bin (sized on first use),
/// which bins the current stripe uses, a row of values and the edge taps.
struct Scratch {
    stripes: Vec<Stripe>,
    walk: Walk,
    /// Per bin, the columns `[x0, x1)` the stripe's sources of that bin reach (None: unused).
    used: Vec<Option<(usize, usize)>>,
    row: Vec<f32>,
    e: Vec<f32>,
}

impl Scratch {
    fn new(w: usize, bins: &Bins) -> Self {
        Scratch {
            stripes: (0..bins.count).map(|_| Stripe::new(w)).collect(),
            walk: Walk::new(bins),
            used: vec![None; bins.count],
            row: vec![0.0; w * 4],
            e: Vec::new(),
        }
    }
}

/// Renders target rows `[y0, y1)`: scatters the sources that reach them into their bins,
/// then per target sums the bins into groups, fills them and writes the raw pixel
/// `[P, A, 1]`, keeping the groups and their depth derivative.
fn forward_stripe(ctx: &Ctx, fill_width: f64, y0: usize, y1: usize, sc: &mut Scratch, out: &mut [f32], tg: &mut [Target]) {
    let w = ctx.w;
    let rows = ctx.source_rows(y0, y1);
    // Survey: the bins this stripe's sources use, and the columns they reach (a bin holds a
    // few blocks of depth: its rows are summed and gathered there only).
    sc.used.iter_mut().for_each(|u| *u = None);
    for sy in rows.clone() {
        for sx in -ctx.pad..w as i64 + ctx.pad {
            let j = ctx.clamp_index(sx, sy);
            let (lo, hi, ..) = ctx.extent(j, sy);
            let reach = sy - lo;
            let (xa, xb) = ((sx - reach).max(0), (sx + reach).min(w as i64 - 1));
            if hi < y0 as i64 || lo >= y1 as i64 || xa > xb {
                continue;
            }
            for (b, hat, _) in ctx.bins.locate(ctx.d[j]) {
                if hat != 0.0 {
                    let e = sc.used[b].get_or_insert((xa as usize, xb as usize + 1));
                    *e = (e.0.min(xa as usize), e.1.max(xb as usize + 1));
                }
            }
        }
    }
    for (st, u) in sc.stripes.iter_mut().zip(&sc.used) {
        if u.is_some() {
            st.reset(y0, y1);
        }
    }
    // Scatter.
    for sy in rows {
        for sx in -ctx.pad..w as i64 + ctx.pad {
            let j = ctx.clamp_index(sx, sy);
            let (lo, hi, ..) = ctx.extent(j, sy);
            if hi < y0 as i64 || lo >= y1 as i64 {
                continue;
            }
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
    }
    // Gather: bins → groups → fill (physical) or on-focal mix (official).
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
                let centre = ctx.bins.centre_split();
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

/// The source gradients of source rows `[sy0, sy1)` (padded rows included; each gradient goes
/// to the pixel the source replicates). Sources are bucketed by the first of their two bins;
/// bins are visited in increasing order, each bin's cotangent `gB_b` built once as row prefix
/// sums over the box its sources reach (two buffers in turn: bins `b` and `b + 1`), and each
/// source gathers both of its bins in one walk over its disk.
fn backward_stripe(ctx: &Ctx, gg: &[[[f64; 4]; 3]], sy0: i64, sy1: i64) -> Vec<(usize, SourceGrad)> {
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The factored split against the tanh evaluated at every bin, over 101 bins (relative
    /// disparities -1 … 0) and targets across the range: the group weights agree to 1e-6,
    /// their slopes (up to 5) to 5e-6.
    #[test]
    fn walk_is_the_split_evaluated_directly() {
        let d: Vec<f32> = (0..300).map(|i| -1.0 + i as f32 / 299.0 + 0.003 * (i % 7) as f32).collect();
        for official in [false, true] {
            let bins = Bins::new(&d, true, official);
            let mut walk = Walk::new(&bins);
            assert!(walk.factored);
            walk.targets(&d);
            for b in 0..bins.count {
                walk.goto(&bins, b);
                for (x, &dx) in d.iter().enumerate() {
                    let (g, dg) = walk.split(&bins, x, dx);
                    let (want, dwant) = bins.split(b, dx);
                    for k in 0..3 {
                        assert!((g[k] - want[k]).abs() < 1e-6, "bin {b} d {dx}: {g:?} vs {want:?}");
                        assert!((dg[k] - dwant[k]).abs() < 5e-6, "bin {b} d {dx}: {dg:?} vs {dwant:?}");
                    }
                }
            }
        }
        // A range too wide for the factored form falls back to the tanh.
        assert!(!Walk::new(&Bins::new(&[-20.0, 20.0], true, false)).factored);
    }
}
