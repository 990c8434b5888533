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
//!   into a difference array (cost O(σ), not O(σ²)), drawn per radius bin ([`binned`]),
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
//!
//! The pieces, one idea per module: [`band`] (the on-focal band and its interpolation
//! nodes), [`footprint`] (how one source is drawn at full resolution: stencils, equivalent
//! disks, exact rims), [`binned`] (the medium disks and the coarse grids' disks drawn per
//! radius bin, a row's run of sources at once), [`bright`] (which sources get the exact
//! footprint at any radius),
//! [`coarse`] (the coarse grids), [`visibility`] (eq. 4 from a summed-area table), [`survey`]
//! (the layer-wide passes) and [`stripe`] (scatter and combine, one stripe of rows at a time).
//! [`scatter_layer_into`] reads as their sequence.
//!
//! The physical profile ([`super::lens::Profile::Physical`]) runs the same stripes and coarse
//! grids with its own footprint ([`physical`]: uniform disks of unit flux, drawn exactly up to
//! `2·r0`); its band holds the sharp targets that sources of other depths reach, where the
//! band passes collect the sources in front of and behind the target and [`physical`] re-splits
//! the sums into the in-layer depth groups wherever the coverage reaching a target exceeds 1.
//! Each finished pixel's sums are turned into `[P, A, V]` there.

mod band;
mod binned;
mod bright;
mod coarse;
pub(in crate::render) mod footprint;
mod physical;
mod scratch;
mod stripe;
mod survey;
mod visibility;

use super::aperture::shape::CatGains;
use super::aperture::{disk_tap_count, disk_taps_within};
use super::layer::{A, CHANNELS, D, Layer};
use super::lens::{Profile, density, disk_norm, weight_unit};
use super::splat::STRIPE_ROWS;
use super::{RawLayer, RenderSettings, Role, raw};
use band::{Band, Class, Side};
use footprint::{STENCIL_TAIL, Stencil};
use std::sync::atomic::AtomicU64;
use survey::{Presence, SidePresence, Survey};

/// The fast kernel's accuracy/speed trade-off, derived from the quality level.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FastParams {
    /// Sources with σ below this (pixels) use the exact taps.
    pub stencil_max: f32,
    /// Disks up to radius `2·r0` (grid pixels) are drawn directly; larger ones go to a
    /// coarser grid.
    pub r0: f32,
    /// Spacing of the interpolation nodes of the on-focal band, in disparity.
    pub node_step: f32,
    /// Draw full-resolution disks with the soft step's edge profile (3 nested disks) instead
    /// of one antialiased disk: 3× the span cost, closer to exact at small radii.
    pub soft_edge: bool,
    /// Width of the radius bins of the disks between `stencil_max` and `2·r0` (pixels; a
    /// disk's edge moves by at most half of it, see [`binned`]).
    pub radius_bin: f32,
}

impl FastParams {
    /// Quality 1 (fastest) … 8; 2 is the default. Higher is slower and closer to exact; 8
    /// uses the exact taps for every source (only the band interpolation remains).
    pub fn from_quality(q: u32) -> Self {
        let q = q.clamp(1, 8);
        let stencil_max = if q == 8 { f32::INFINITY } else { 2.0 + q as f32 };
        FastParams { stencil_max, r0: (2u32 << q) as f32, node_step: 0.04 / q as f32, soft_edge: q >= 3, radius_bin: 0.25 / q as f32 }
    }
}

/// What the fast kernel did for one layer (for `--json`).
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct FastStats {
    /// Visible sources drawn as exact stencils (per pass: a source in several passes counts
    /// in each).
    pub stencil_sources: usize,
    /// Visible sources drawn as full-resolution disks (per pass).
    pub span_sources: usize,
    /// Bright sources (a colour above 1.25, at most ~1% of the visible ones) drawn with their exact
    /// footprint at any radius; counted once per stripe row they own.
    pub bright_sources: usize,
    /// Visible sources aggregated on coarse grids (per pass).
    pub coarse_sources: usize,
    /// Target pixels in the on-focal band (where the occlusion term is computed; physical
    /// profile: the sharp targets of a layer that can need depth groups, before the test of
    /// which of them sources of other depths reach).
    pub band_pixels: usize,
    /// Interpolation nodes of the on-focal band (0 when no target is in it).
    pub nodes: usize,
    /// Plain scatter passes (1 when no pixel is near the focal plane: the occlusion part is
    /// skipped; in the band, `F` and one `U_k` per node, and in the physical profile the same
    /// for the sources behind the targets).
    pub passes: usize,
    /// Sources skipped in the front band passes because they are hidden behind every node.
    pub band_sources_skipped: usize,
    /// Stripes of rows where the occlusion part was computed.
    pub band_stripes: usize,
    /// All stripes of rows.
    pub stripes: usize,
    /// Physical profile: targets re-split into in-layer depth groups (sharp, reached by sources
    /// of other depths, and with coverage above 1; see `fast::physical`).
    pub group_pixels: usize,
    /// Fully transparent pixels (never scattered).
    pub transparent_pixels: usize,
    /// Weighted taps the exact kernel evaluates for this layer (`W·H·taps(lens)`).
    pub exact_taps: f64,
    /// Elementary writes the fast kernel made (stencil taps, disk spans, coarse spans and
    /// upsampled pixels).
    pub fast_ops: f64,
    /// `1 - fast_ops / exact_taps`, at least 0.
    pub work_saved: f64,
}

/// Per-layer state shared by every stripe: the settings, the scatter radii and the
/// thresholds the survey decided.
struct Ctx<'a> {
    img: crate::ImageRef<'a>,
    s: &'a RenderSettings,
    /// Where the layer sits in the stack (the physical profile's visibility).
    role: Role,
    w: usize,
    h: usize,
    /// Window half-size `lens/2`.
    p: usize,
    /// Footprint radius of every pixel (see [`footprint::source_radius`]): the scatter radius σ
    /// (official) or the CoC r (physical).
    sigma: Vec<f32>,
    /// See `Survey::sigma_max`.
    sigma_max: f32,
    /// See `Survey::full_max`; `bright_max` is `Survey::bright_max` for sources above
    /// `bright_level` (see [`bright::bright_level`]).
    full_max: f32,
    /// Whether any visible source is drawn at full resolution (see `Survey::full`).
    has_full: bool,
    bright_max: f32,
    bright_level: f32,
    /// Weight unit of the layer (see `lens::weight_unit`).
    unit: f32,
    params: FastParams,
    /// The on-focal band (None when no target is near the focal plane, and in the physical
    /// profile when the layer needs no depth groups).
    band: Option<Band>,
    /// Which band passes have sources, per [`Side`] (the official profile uses the front only).
    sides: [SidePresence; 2],
    /// Physical profile with a band: which targets can need depth groups at all.
    reach: Option<physical::DepthReach>,
    /// The exact taps out to the stencil reach.
    stencil: Stencil,
    /// The radius bins of the medium disks (`stencil_max ≤ r < 2·r0`; None at quality 8).
    bins: Option<binned::Bins>,
    /// Their templates, built once for every worker.
    templates: std::sync::Arc<binned::SharedTemplates>,
    /// A cat's eye (physical profile): what each target multiplies the light reaching it by
    /// ([`crate::render::aperture::sources::ShapedSources::gain`]).
    cat_gains: Option<CatGains>,
}

impl<'a> Ctx<'a> {
    /// The thresholds of one layer from its survey: weight unit, band nodes, stencil table
    /// and bright level. Reads the image again only when bright sources are many.
    fn new(img: crate::ImageRef<'a>, s: &'a RenderSettings, role: Role, params: FastParams, sigma: Vec<f32>, survey: &Survey) -> Self {
        let p = s.lens / 2;
        let stencil_reach = params.stencil_max.min(survey.sigma_max) + STENCIL_TAIL;
        let (bright_level, bright_max) =
            bright::bright_sources(img, survey.visible, survey.bright_max, |i| footprint::drawn(s, sigma[i], p));
        let band = match s.profile {
            Profile::Official => survey.band(params.node_step),
            Profile::Physical => physical::groups_wanted(s, p, survey).then(|| survey.band(params.node_step)).flatten(),
        };
        // Taps lie strictly inside the window (r < p); a physical source reaches r < radius + ½.
        let reach = (s.profile == Profile::Physical && band.is_some()).then(|| {
            physical::DepthReach::new(
                img,
                s.focus,
                (survey.sigma_max + if s.aperture.is_disc() { footprint::EDGE } else { 1.0 }).min(p as f32 - 1.0),
            )
        });
        Ctx {
            img,
            s,
            role,
            w: img.width,
            h: img.height,
            p,
            stencil: Stencil::new(&disk_taps_within(s.lens, stencil_reach)),
            unit: weight_unit(if survey.sigma_min.is_finite() { survey.sigma_min } else { 1.0 }),
            sigma,
            sigma_max: survey.sigma_max,
            full_max: survey.full_max,
            has_full: survey.full > 0,
            bright_max,
            bright_level,
            params,
            band,
            sides: [SidePresence::default(); 2],
            reach,
            // A non-disc aperture draws every full-resolution source through its templates.
            bins: (params.stencil_max < 2.0 * params.r0 || !s.aperture.is_disc()).then(|| {
                let shape = match (s.profile, s.aperture.geometry()) {
                    (Profile::Physical, Some(g)) => binned::Shape::Aperture(g),
                    (Profile::Physical, None) => binned::Shape::Physical,
                    (Profile::Official, _) if params.soft_edge => binned::Shape::Official { soft_below: f32::INFINITY },
                    (Profile::Official, _) => binned::Shape::Official { soft_below: 2.0 * params.stencil_max },
                };
                // A shape's edge is a sharp outline: bins 8 times finer than the disc's ramp
                // needs, a cat's eye's too. Its bins were twice the disc's (16 times fewer
                // templates per bin and cut), and a light of CoC 1-2 px drawn at its bin's
                // radius had its peak tens of percent off, with the rounding's sign (bench
                // scene s003 of seed 1: fast 23.1 dB against the exact kernel's 28.9; with
                // these bins 29.6, the 12.2 MP cat's-eye render at focus 1 +5%).
                let cat = s.aperture.cat_eye(img.width, img.height);
                let width = if s.aperture.is_disc() && cat.is_none() { params.radius_bin } else { params.radius_bin / 8.0 };
                binned::Bins::new(shape, width, p).with_cat_eye(cat, 1.0)
            }),
            templates: Default::default(),
            cat_gains: match (s.profile, s.aperture.geometry(), s.aperture.cat_eye(img.width, img.height)) {
                (Profile::Physical, Some(g), Some(cat)) => Some(cat.gains(g)),
                _ => None,
            },
        }
    }

    /// Target `(x, y)`'s cat's-eye gain (1 without a cat's eye).
    #[inline]
    fn gain(&self, x: usize, y: usize) -> f32 {
        self.cat_gains.as_ref().map_or(1.0, |g| g.at(x, y))
    }

    /// The radius a source of footprint radius `radius` is drawn with (see [`footprint::drawn`]).
    #[inline]
    fn drawn(&self, radius: f32) -> f32 {
        footprint::drawn(self.s, radius, self.p)
    }

    /// A source's flux per unit of footprint, from its true footprint radius: the energy
    /// density `1/σ²` in weight units (official) or `1/disk_norm(r)` (physical; the shape's
    /// `1/norm(r)` for a non-disc aperture).
    #[inline]
    fn density(&self, radius: f32) -> f32 {
        match (self.s.profile, self.s.aperture.geometry()) {
            (Profile::Official, _) => density(radius, self.unit),
            (Profile::Physical, None) => 1.0 / disk_norm(radius),
            (Profile::Physical, Some(g)) => 1.0 / g.norm(radius),
        }
    }

    /// Row-major index of (x, y), replicate-padded (clamped to the image).
    #[inline]
    fn clamp_index(&self, x: i64, y: i64) -> usize {
        y.clamp(0, self.h as i64 - 1) as usize * self.w + x.clamp(0, self.w as i64 - 1) as usize
    }

    /// How far outside the image a source can still reach a target.
    fn pad(&self, reach: f32) -> i64 {
        (reach.min(1e9).ceil() as i64 + 1).min(self.p as i64 - 1).max(0)
    }

    /// Relative disparity of pixel `j`.
    #[inline]
    fn d(&self, j: usize) -> f32 {
        self.img.data[j * CHANNELS + D] - self.s.focus
    }

    /// A source's premultiplied value `[r·a, g·a, b·a, a]`; None when transparent.
    #[inline]
    fn base(&self, j: usize) -> Option<[f32; 4]> {
        let px = &self.img.data[j * CHANNELS..(j + 1) * CHANNELS];
        let a = px[A];
        (a > 0.0).then(|| [px[0] * a, px[1] * a, px[2] * a, a])
    }

    /// The sides the band passes collect: the front (official `B`), and in the physical
    /// profile the back as well (its depth groups).
    fn sides_used(&self) -> &'static [Side] {
        match self.s.profile {
            Profile::Official => &Side::BOTH[..1],
            Profile::Physical => &Side::BOTH,
        }
    }

    /// Which sources pass `slot` scatters and with what value (see [`band::slot`]; the band
    /// has `n` nodes here).
    // Inline: called per source and coarse level from `coarse::aggregate`, another module
    // (codegen unit) since the split.
    #[inline]
    fn value(&self, slot: usize, j: usize) -> Option<[f32; 4]> {
        let v = self.base(j)?;
        if slot == 0 {
            return Some(v);
        }
        let b = self.band?;
        let (side, node) = band::pass_of(slot, b.n);
        let dj = self.d(j);
        match (b.pass_class(side, dj), node) {
            (Class::Full, None) => Some(v),
            (Class::Partial, Some(k)) => {
                let g = b.pass_weight(side, k, dj);
                Some(v.map(|c| c * g))
            }
            _ => None,
        }
    }

    /// The stripe accumulators source `j` adds to, with their factors, into `dests`: `A`
    /// (slot 0, factor 1), and with band nodes `ka..=kb` in the stripe each side's full pass
    /// or its partial passes (see [`band::slot`], with the stripe's `kb - ka + 1` nodes).
    #[inline]
    fn dests(&self, nodes: Option<(usize, usize)>, j: usize, dests: &mut Vec<(usize, f32)>) {
        dests.clear();
        dests.push((0, 1.0));
        let (Some((ka, kb)), Some(b)) = (nodes, self.band) else { return };
        let dj = self.d(j);
        let m = kb - ka + 1;
        for &side in self.sides_used() {
            match b.pass_class(side, dj) {
                Class::Full => dests.push((band::slot(side, None, m), 1.0)),
                Class::Partial => dests.extend((ka..=kb).map(|k| (band::slot(side, Some(k - ka), m), b.pass_weight(side, k, dj)))),
                Class::Out => {}
            }
        }
    }
}

/// Counters the stripes and coarse levels add to.
#[derive(Default)]
struct Counts {
    bright: AtomicU64,
    stencil: AtomicU64,
    span: AtomicU64,
    band_stripes: AtomicU64,
    groups: AtomicU64,
    ops: AtomicU64,
    coarse: AtomicU64,
}

impl Counts {
    /// Writes the counts into `stats` (and the work saved against the exact kernel).
    fn report(self, stats: &mut FastStats) {
        stats.stencil_sources = self.stencil.into_inner() as usize;
        stats.span_sources = self.span.into_inner() as usize;
        stats.bright_sources = self.bright.into_inner() as usize;
        stats.coarse_sources = self.coarse.into_inner() as usize;
        stats.band_stripes = self.band_stripes.into_inner() as usize;
        stats.group_pixels = self.groups.into_inner() as usize;
        stats.fast_ops = self.ops.into_inner() as f64;
        stats.work_saved = if stats.exact_taps > 0.0 { (1.0 - stats.fast_ops / stats.exact_taps).max(0.0) } else { 0.0 };
    }
}

/// Renders one layer (at `role` in the stack) into its raw sums, like
/// [`super::exact::scatter_layer`]: `[ΣR, ΣG, ΣB, W, o]` (official) or `[P_r, P_g, P_b, A, V]`
/// (physical). Allocates the raw output (`width·height·raw::CHANNELS` f32).
pub fn scatter_layer(layer: &Layer, s: &RenderSettings, params: FastParams, role: Role) -> (RawLayer, FastStats) {
    let (w, h) = (layer.width(), layer.height());
    let mut out = vec![0f32; w * h * raw::CHANNELS];
    let stats = scatter_layer_into(layer, s, params, role, &mut out, raw::CHANNELS, &|raw, px| px.copy_from_slice(raw));
    (RawLayer::new(w, h, out, layer), stats)
}

/// Renders one layer at `role` in the stack and hands each pixel's raw sums (see
/// [`scatter_layer`]) to `finish`, with
/// that pixel's `stride` values of `out` (row-major, `width·height·stride` f32): storing them
/// ([`scatter_layer`]) or compositing them on the fly (`render::render`). Besides `out`,
/// allocates the scatter radii (4 bytes per pixel), the coarse grids of the passes that have
/// large-blur sources (≤ 16/4^ℓ bytes per pixel at level ℓ each) and per-worker stripe
/// scratch.
pub fn scatter_layer_into(
    layer: &Layer,
    s: &RenderSettings,
    params: FastParams,
    role: Role,
    out: &mut [f32],
    stride: usize,
    finish: &(dyn Fn(&raw::Pixel, &mut [f32]) + Sync),
) -> FastStats {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    assert_eq!(out.len(), w * h * stride, "output buffer size");
    // Survey: scatter radii, what is visible, the on-focal band.
    let (sigma, survey) = survey::survey(img, s, params);
    // Thresholds: weight unit, band nodes, stencil table, bright level.
    let mut ctx = Ctx::new(img, s, role, params, sigma, &survey);
    // Masks: which passes have sources, and on which coarse levels.
    let presence = survey::presence(&ctx);
    ctx.sides = presence.sides;
    if let Some(b) = &mut ctx.band {
        for side in Side::BOTH {
            let [full, out] = presence.counts[side.index()];
            b.complement_if_cheaper(side, full, out);
        }
    }
    let ctx = ctx;
    let mut stats = plan_stats(&ctx, &survey, &presence);
    // Passes: the coarse grids of every pass, then the stripes.
    let counts = Counts::default();
    let empty = survey.visible == 0 || ctx.p == 0;
    let coarse = if empty { Vec::new() } else { coarse::passes(&ctx, &presence, &counts) };
    stripe::render_stripes(&ctx, &coarse, empty, out, stride, finish, &counts);
    // Counts.
    counts.report(&mut stats);
    stats
}

/// The statistics known before any scattering.
fn plan_stats(ctx: &Ctx, survey: &Survey, presence: &Presence) -> FastStats {
    let n_nodes = ctx.band.map_or(0, |b| b.n);
    FastStats {
        transparent_pixels: ctx.w * ctx.h - survey.visible,
        band_pixels: if ctx.band.is_some() { survey.band_pixels } else { 0 },
        stripes: ctx.h.div_ceil(STRIPE_ROWS),
        exact_taps: (ctx.w * ctx.h) as f64 * disk_tap_count(ctx.s.lens) as f64,
        nodes: n_nodes,
        passes: 1 + ctx.sides.iter().map(|sp| usize::from(sp.has_full) + if sp.has_partial { n_nodes } else { 0 }).sum::<usize>(),
        band_sources_skipped: presence.hidden,
        ..FastStats::default()
    }
}
