//! A fast differentiable render of one opaque layer, for depth from defocus: the function of
//! [`super::Tape`] (the exact kernel; physical: with [`Smoothing`]'s edges) for a single layer
//! of alpha 1, drawn as spans instead of taps, with the in-layer depth terms interpolated over
//! the sources' depth; its vector-Jacobian product with respect to the colour, the disparity,
//! the focus and K. Both profiles; they differ in the footprint ([`Model`]), in what the bins'
//! weights split a source into ([`bins::Bins::shape`]) and in how a target combines them.
//!
//! Forward. Each source `y` spreads `u_y = cov(R_y, ρ)/N(R_y)` ([`lens::disk_coverage_smooth`],
//! [`lens::disk_norm_smooth`], `R = K·|d|`) of `v_y = [c_y, 1]`. The depth group a source
//! joins at target `x`, `γ(d_y, d_x)` ([`lens::depth_groups`]), depends on both depths; here
//! it is interpolated linearly in the source's depth between depth bins `δ_b` (spacing
//! [`BIN_STEP`], relative disparity): a source is drawn, with hat weights `hat_b(d_y)`, into
//! the two bins around its depth, each bin one 4-channel scatter `B_b(x) = Σ_y hat_b(d_y)·u_y(x)·v_y`
//! (a smooth disk per source, its plateau one span per row and its edge as taps:
//! `render::fast::footprint::smooth_coverage_disk` into `Stripe`s), and a target
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
use crate::render::layer::Layer;
use crate::render::lens;
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

mod backward;
mod bins;
mod ctx;
mod forward;

use backward::backward_stripe;
use ctx::{Ctx, Model};
use forward::{Scratch, forward_stripe};

/// What the forward keeps per target for the VJP: the depth groups `[P_r, P_g, P_b, a]` before
#[derive(Clone, Copy, Default)]
struct Target {
    groups: [[f64; 4]; 3],
    dgroups: [[f64; 4]; 3],
}

/// A recorded span render of one opaque layer (either profile): its image and what
/// [`SpanTape::vjp`] needs. The function is that of [`super::Tape`] for the same
/// layer, settings and smoothing, except that the in-layer depth terms are interpolated
/// between depth bins [`BIN_STEP`] apart and, in the official profile, the soft step is
/// truncated (see the module notes); without occlusion in the physical profile, the same up to
/// rounding.
///
/// ```
/// use drbokeh::Image;
/// use drbokeh::render::{Layer, Profile, RenderSettings, Smoothing, SpanTape};
///
/// // An 8×6 opaque layer: grey, its left half on the focal plane, its right half behind.
/// let px: Vec<f32> = (0..48).flat_map(|i| [0.5, 0.5, 0.5, 1.0, if i % 8 < 4 { 1.0 } else { 0.4 }]).collect();
/// let layer = Layer::new(Image::from_vec(8, 6, 5, px).expect("8·6·5 values"), "example")?;
/// let s = RenderSettings { blur: 6.0, focus: 1.0, lens: 11, occlusion: true, profile: Profile::Physical, aperture: drbokeh::render::Aperture::DISC };
/// let tape = SpanTape::record(&layer, &s, Smoothing::default())?;
/// // L = ½‖image − target‖² with a black target: ∂L/∂image = image.
/// let g = tape.vjp(&tape.image().clone())?;
/// assert_eq!((g.colour.channels, g.disparity.channels), (3, 1));
/// assert!(g.disparity.all_finite() && g.focus.is_finite() && g.blur.is_finite());
/// # Ok::<(), drbokeh::Error>(())
/// ```
pub struct SpanTape<'a> {
    ctx: Ctx<'a>,
    fill_width: f64,
    targets: Vec<Target>,
    raw: RawLayer,
    image: Image,
}

impl<'a> SpanTape<'a> {
    /// Renders `layer` (every alpha 1) with `s.profile` (physical: `smoothing`'s edges) and
    /// the lens window `s.lens`, and keeps the per-pixel sums (192 bytes per pixel). Errors
    /// (usage): the checks of [`crate::render::render`], a layer that is not opaque. Cost: see
    /// the module notes.
    pub fn record(layer: &'a Layer, s: &RenderSettings, smoothing: Smoothing) -> Result<Self> {
        validate(std::slice::from_ref(layer), s)?;
        crate::render::backward::check_span_aperture(s)?;
        if s.aperture.channel_scales().is_some() {
            return Err(crate::error::Error::usage(format!(
                "aperture {}: the span kernel's differentiable render is achromatic; use the exact kernel (Tape) for chromatic aberration",
                s.aperture.label()
            )));
        }
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
        // Targets: the composite's and the fill's (physical) or q's (official) adjoints, the
        // target's own depth and its own source's correction (the centre tap put back where
        // the exact kernel has it).
        let official = matches!(ctx.model, Model::Official { .. });
        let centre = ctx.bins.centre_split();
        let mut grads = vec![SourceGrad::default(); w * h];
        let gg: Vec<[[f64; 4]; 3]> = self
            .targets
            .par_iter()
            .zip(grads.par_iter_mut())
            .enumerate()
            .map(|(i, (t, og))| {
                let g: [f64; 3] = std::array::from_fn(|c| cotangent.data[i * 3 + c] as f64);
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
