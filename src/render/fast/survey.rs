//! The layer-wide passes before any scattering: the survey (scatter radii, what is visible,
//! the on-focal band) and the presence of source classes per coarse level.

use super::band::{Band, Class, Side, band_coc, complement_pays, in_band};
use super::bright::{BRIGHT_MIN, is_bright};
use super::coarse::level_of;
use super::footprint::{drawn, source_radius};
use super::{Ctx, FastParams};
use crate::ImageRef;
use crate::render::RenderSettings;
use crate::render::layer::{A, CHANNELS, D, max_rgb};
use rayon::prelude::*;

/// What one parallel pre-pass learns about a layer.
#[derive(Clone, Copy)]
pub(super) struct Survey {
    /// Visible sources (alpha > 0).
    pub(super) visible: usize,
    /// Smallest footprint radius of a visible source (∞ if none).
    pub(super) sigma_min: f32,
    /// Largest drawn radius (see [`drawn_radius`]) of a visible source, at least 1.
    pub(super) sigma_max: f32,
    /// Largest drawn radius of a visible source drawn at full resolution (below `2·r0`);
    /// 0 if none.
    pub(super) full_max: f32,
    /// Visible sources drawn at full resolution (a physical source in focus has radius 0, so
    /// `full_max` alone does not tell).
    pub(super) full: usize,
    /// Largest drawn radius of a visible bright source (a colour above
    /// [`BRIGHT_MIN`], see [`is_bright`]); 0 if none.
    pub(super) bright_max: f32,
    /// Targets in the on-focal band, and the range `[band_lo, band_hi]` of their relative
    /// disparities (empty: lo > hi).
    pub(super) band_pixels: usize,
    pub(super) band_lo: f32,
    pub(super) band_hi: f32,
    /// Range `[d_lo, d_hi]` of the visible sources' relative disparities (empty: lo > hi):
    /// a layer whose range is narrow has one depth group (see [`super::physical`]).
    pub(super) d_lo: f32,
    pub(super) d_hi: f32,
}

impl Survey {
    const EMPTY: Survey = Survey {
        visible: 0,
        sigma_min: f32::INFINITY,
        sigma_max: 1.0,
        full_max: 0.0,
        full: 0,
        bright_max: 0.0,
        band_pixels: 0,
        band_lo: f32::INFINITY,
        band_hi: f32::NEG_INFINITY,
        d_lo: f32::INFINITY,
        d_hi: f32::NEG_INFINITY,
    };

    fn merge(a: Survey, b: Survey) -> Survey {
        Survey {
            visible: a.visible + b.visible,
            sigma_min: a.sigma_min.min(b.sigma_min),
            sigma_max: a.sigma_max.max(b.sigma_max),
            full_max: a.full_max.max(b.full_max),
            full: a.full + b.full,
            bright_max: a.bright_max.max(b.bright_max),
            band_pixels: a.band_pixels + b.band_pixels,
            band_lo: a.band_lo.min(b.band_lo),
            band_hi: a.band_hi.max(b.band_hi),
            d_lo: a.d_lo.min(b.d_lo),
            d_hi: a.d_hi.max(b.d_hi),
        }
    }

    /// The interpolation nodes of the on-focal band; None when no target is in it.
    pub(super) fn band(&self, node_step: f32) -> Option<Band> {
        (self.band_pixels > 0).then(|| Band::new(self.band_lo, self.band_hi, node_step))
    }
}

/// One parallel pass over the layer: the scatter radius of every pixel (allocated, 4 bytes
/// per pixel) and the [`Survey`].
pub(super) fn survey(img: ImageRef<'_>, s: &RenderSettings, params: FastParams) -> (Vec<f32>, Survey) {
    let (w, h) = (img.width, img.height);
    let p = s.lens / 2;
    let mut sigma = vec![0f32; w * h];
    let bc = band_coc();
    let survey = sigma
        .par_chunks_mut(w)
        .zip(img.data.par_chunks(w * CHANNELS))
        .map(|(srow, prow)| {
            let mut sv = Survey::EMPTY;
            for (sg, px) in srow.iter_mut().zip(prow.chunks_exact(CHANNELS)) {
                let d = px[D] - s.focus;
                *sg = source_radius(s.profile, d, s.blur);
                if px[A] > 0.0 {
                    sv.visible += 1;
                    sv.sigma_min = sv.sigma_min.min(*sg);
                    sv.d_lo = sv.d_lo.min(d);
                    sv.d_hi = sv.d_hi.max(d);
                    let drawn = drawn(s, *sg, p);
                    sv.sigma_max = sv.sigma_max.max(drawn);
                    if drawn < 2.0 * params.r0 {
                        sv.full_max = sv.full_max.max(drawn);
                        sv.full += 1;
                    }
                    if is_bright(max_rgb(px), 1.0, BRIGHT_MIN) {
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
    (sigma, survey)
}

/// Which sources one side's band passes have, per coarse level.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct SidePresence {
    /// Coarse levels present (bit ℓ = level ℓ) among the side's full sources and its partial
    /// ones.
    pub(super) levels_full: u64,
    pub(super) levels_partial: u64,
    /// Whether the side has any full / partial source.
    pub(super) has_full: bool,
    pub(super) has_partial: bool,
}

/// Which source classes a layer has, per coarse level: what decides the passes and their
/// coarse grids.
pub(super) struct Presence {
    /// Coarse levels present (bit ℓ = level ℓ) among all visible sources (pass `A`).
    pub(super) levels_all: u64,
    /// Per [`Side`]: what its passes scatter (its full sources, or where the side is to be
    /// complemented its out ones, see [`Band::complement_if_cheaper`]); empty for a side the
    /// profile does not use.
    pub(super) sides: [SidePresence; 2],
    /// Per [`Side`]: how many sources are full in it and how many out of it.
    pub(super) counts: [[usize; 2]; 2],
    /// Visible sources out of every front pass (behind every band node; skipped).
    pub(super) hidden: usize,
}

/// One parallel pass over the visible sources: their coarse levels per class.
pub(super) fn presence(ctx: &Ctx) -> Presence {
    let (r0, band) = (ctx.params.r0, ctx.band);
    let sides = ctx.sides_used();
    // Levels of pass A (bit 0 tags a visible source at all), and per side the levels and
    // counts of its [full, partial, out] sources. Folded per worker: one pass, no per-pixel
    // allocation.
    #[derive(Clone, Copy, Default)]
    struct Tally {
        all: u64,
        levels: [[u64; 3]; 2],
        count: [[u64; 3]; 2],
    }
    let tally = (0..ctx.h)
        .into_par_iter()
        .fold(Tally::default, |mut t, y| {
            for j in y * ctx.w..(y + 1) * ctx.w {
                if ctx.img.data[j * CHANNELS + A] <= 0.0 {
                    continue;
                }
                let tag = level_of(ctx.drawn(ctx.sigma[j]), r0).map_or(0, |l| 1u64 << l) | 1;
                t.all |= tag;
                let Some(b) = band else { continue };
                let d = ctx.d(j);
                for &side in sides {
                    let c = match b.class(side, d) {
                        Class::Full => 0,
                        Class::Partial => 1,
                        Class::Out => 2,
                    };
                    t.levels[side.index()][c] |= tag;
                    t.count[side.index()][c] += 1;
                }
            }
            t
        })
        .reduce(Tally::default, |mut a, b| {
            a.all |= b.all;
            for k in 0..2 {
                for c in 0..3 {
                    a.levels[k][c] |= b.levels[k][c];
                    a.count[k][c] += b.count[k][c];
                }
            }
            a
        });
    let counts = [0, 1].map(|k| [tally.count[k][0] as usize, tally.count[k][2] as usize]);
    let side = |k: usize| {
        // What the passes scatter: the full sources, or the out ones of a complemented side
        // (decided from the same counts in `Band::complement_if_cheaper`).
        let [full, out] = counts[k];
        let levels = tally.levels[k];
        let scattered = if complement_pays(full, out) { levels[2] } else { levels[0] };
        SidePresence {
            levels_full: scattered & !1,
            levels_partial: levels[1] & !1,
            has_full: scattered & 1 != 0,
            has_partial: levels[1] & 1 != 0,
        }
    };
    Presence { levels_all: tally.all & !1, sides: [side(0), side(1)], counts, hidden: tally.count[Side::Front.index()][2] as usize }
}
