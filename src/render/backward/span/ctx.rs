//! What a source spreads and what every pass reads per pixel: the footprint of each profile
//! ([`Model`]) and the per-pixel terms ([`Ctx`]).

use super::bins::Bins;
use crate::image::ImageRef;
use crate::render::fast::footprint::{RIM, STENCIL_TAIL, smooth_coverage_disk, soft_step_disk};
use crate::render::layer::{CHANNELS, D, Layer};
use crate::render::lens::{self, Profile};
use crate::render::splat::Stripe;
use crate::render::{RenderSettings, Smoothing};
use rayon::prelude::*;

/// The footprint a source spreads: what differs between the profiles on the source side.
#[derive(Clone, Copy, Debug)]
pub(super) enum Model {
    /// The smooth-edged disk `cov(R, ρ)/N(R)` of radius `R = K·|d|`, edge `edge` px wide.
    Physical { edge: f32 },
    /// The official soft step `step(σ, ρ)·(unit/σ)²` of radius `σ = K·|d| + 1`, drawn as the
    /// fast kernel draws it: 1 within `σ - RIM`, the step out to `σ + STENCIL_TAIL`.
    Official { unit: f32 },
}

impl Model {
    /// A footprint of radius `r`'s `(reach, inner)`: nothing beyond `reach`, the plateau
    /// (value `1/N`) within `inner`, the rim taps between.
    #[inline]
    pub(super) fn edges(self, r: f32) -> (f32, f32) {
        match self {
            Model::Physical { edge } => (r + 0.5 * edge, r - 0.5 * edge),
            Model::Official { .. } => (r + STENCIL_TAIL, r - RIM),
        }
    }
}

/// The per-pixel terms every pass reads: relative disparity, footprint radius (`R` or `σ`),
/// norm `N` (the footprint's value is `cov/N`) and its derivative, `∂R/∂d`.
pub(super) struct Ctx<'a> {
    pub(super) img: ImageRef<'a>,
    pub(super) w: usize,
    pub(super) h: usize,
    /// Lens window half-size (taps `|offset| < p`).
    pub(super) p: i64,
    /// How far outside the image the (replicate-padded) sources that reach it lie.
    pub(super) pad: i64,
    pub(super) model: Model,
    pub(super) d: Vec<f32>,
    pub(super) radius: Vec<f32>,
    pub(super) norm: Vec<(f32, f32)>,
    pub(super) dr_dd: Vec<f32>,
    /// `∂R/∂K` (`|d|`, 0 where the radius is capped).
    pub(super) dr_dk: Vec<f32>,
    pub(super) blur: f32,
    pub(super) bins: Bins,
}

impl<'a> Ctx<'a> {
    pub(super) fn new(layer: &'a Layer, s: &RenderSettings, sm: &Smoothing) -> Self {
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
        let reach = radius.iter().fold(0f32, |m, &r| m.max(model.edges(r).0));
        let pad = (reach.min(1e9).ceil() as i64).min(p);
        let bins = Bins::new(&d, s.occlusion, s.profile == Profile::Official);
        Ctx { img, w, h, p, pad, model, d, radius, norm, dr_dd, dr_dk, blur: s.blur, bins }
    }

    /// The official on-focal factor `q` of target `i` and `(∂q/∂d, ∂q/∂K)`
    /// ([`lens::focal_defocus`]); 1 (no occlusion) without occlusion terms or in the physical
    /// profile.
    #[inline]
    pub(super) fn defocus(&self, i: usize) -> (f32, f32, f32) {
        if matches!(self.model, Model::Official { .. }) && self.bins.grouped {
            let (dq_dd, dq_dk) = lens::focal_defocus_grad(self.d[i], self.blur);
            (lens::focal_defocus(self.d[i], self.blur), dq_dd, dq_dk)
        } else {
            (1.0, 0.0, 0.0)
        }
    }

    /// A rim tap of a footprint of radius `r` at distance `rho`: its value times `N` and the
    /// derivative of that in `r`.
    #[inline]
    pub(super) fn rim(&self, r: f32, rho: f32) -> (f32, f32) {
        match self.model {
            Model::Physical { edge } => (lens::disk_coverage_smooth(r, rho, edge), lens::disk_coverage_smooth_grad(r, rho, edge)),
            Model::Official { .. } => lens::soft_step_with_grad(r, rho),
        }
    }

    /// Draws source `j` at `(sx, sy)` into `N` stripes with values `vs` (its footprint over
    /// its norm).
    #[inline]
    pub(super) fn draw<const N: usize>(&self, sts: [&mut Stripe; N], (sx, sy): (i64, i64), j: usize, vs: [[f32; 4]; N], e: &mut Vec<f32>) {
        let (r, norm) = (self.radius[j], self.norm[j].0);
        match self.model {
            Model::Physical { edge } => smooth_coverage_disk(sts, (sx, sy), r, edge, norm, self.p, vs, e),
            Model::Official { unit } => soft_step_disk(sts, (sx, sy), r, lens::density(r, unit), self.p, vs, e),
        };
    }

    /// The pixel a (possibly padded) source position reads, replicate padding.
    #[inline]
    pub(super) fn clamp_index(&self, sx: i64, sy: i64) -> usize {
        sy.clamp(0, self.h as i64 - 1) as usize * self.w + sx.clamp(0, self.w as i64 - 1) as usize
    }

    /// `[c_r, c_g, c_b, 1]` of pixel `j`.
    #[inline]
    pub(super) fn value(&self, j: usize) -> [f32; 4] {
        let px = &self.img.data[j * CHANNELS..j * CHANNELS + 3];
        [px[0], px[1], px[2], 1.0]
    }

    /// The source rows that can reach target rows `[y0, y1)`, padding included.
    pub(super) fn source_rows(&self, y0: usize, y1: usize) -> std::ops::Range<i64> {
        (y0 as i64 - self.pad).max(-self.pad)..(y1 as i64 + self.pad).min(self.h as i64 + self.pad)
    }

    /// The rows `[lo, hi]` a source at row `sy` reaches, and its edge `(reach, inner)`.
    #[inline]
    pub(super) fn extent(&self, j: usize, sy: i64) -> (i64, i64, f32, f32) {
        let (reach, inner) = self.model.edges(self.radius[j]);
        let rr = (reach.min(1e9).ceil() as i64).min(self.p);
        (sy - rr, sy + rr, reach, inner)
    }

    /// The own-source terms of target `i`: its weight at its own pixel `u`, `∂u/∂R`, and per
    /// group `η_k` (the share of it the bins gave group k) and `∂η_k/∂d`. The exact kernel
    /// never occludes the centre tap: `centre_split - η_k` moves it where it belongs.
    pub(super) fn own(&self, i: usize) -> (f64, f64, [f64; 3], [f64; 3]) {
        if !self.bins.grouped || self.p < 1 {
            return (0.0, 0.0, [0.0; 3], [0.0; 3]);
        }
        let (r, (n, dn)) = (self.radius[i], self.norm[i]);
        // The centre is a plateau pixel where the plateau reaches it (as `rim_row` decides).
        let (cov, dcov) = if self.model.edges(r).1 > 0.0 { (1.0, 0.0) } else { self.rim(r, 0.0) };
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
