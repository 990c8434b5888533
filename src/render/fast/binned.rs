//! Medium disks by radius bin: sources whose footprint radius lies between the stencils and
//! the coarse grids (`stencil_max ≤ r < 2·r0`, 4 to 16 px at quality 2) are drawn per row of
//! sources and per radius bin, as shifted copies of the row.
//!
//! Drawn one by one, each such source costs O(r) scattered writes (and in the physical profile a
//! square root and a coverage per rim tap), and at CoCs of 8–16 px that was the slowest range
//! of the kernel (12.2 MP at focus 0.2 of the end-to-end scene, physical: 1.9 G writes, 6.3 s,
//! where CoC 64 took 1.1 s). Here a source's radius is rounded to a bin
//! ([`super::FastParams::radius_bin`] px wide: 1/8 at quality 2); a bin's footprint (row
//! differences for its spans, taps for its rim) is a [`Template`] built once per layer; and
//! the sources of one row that share a bin and lie within `GAP` px of each other form a run,
//! drawn by adding the run, shifted by each entry's offset, into the stripe's accumulators:
//! contiguous adds instead of one scattered write per tap and source.
//!
//! The rounding moves a disk's edge by at most half a bin, so an edge pixel's weight by at
//! most half a bin times the source's density. The flux is kept: the physical template is
//! normalized by its own [`disk_norm`] (unit flux, exactly), an official source's density is
//! scaled by the ratio of its disk's area to the bin's.

use super::footprint::{EDGE, HARD_EDGE, SOFT_EDGE, equivalent_radius, rim_row_taps};
use crate::render::aperture::shape::{CatEye, CutCircle, Geometry};
use crate::render::lens::{disk_coverage, disk_norm};
use crate::render::splat::{Stripe, Window, disk_chord, flux_scale, lattice_row_reach, span_edges};
use std::collections::HashMap;
use std::f32::consts::PI;
use std::sync::{Arc, Mutex};

/// Sources of one bin at most this many pixels apart share a run (the zeros between them are
/// added too). A run costs a loop per template row and entry; a zero element, one add per
/// entry.
pub(super) const GAP: i64 = 8;

/// The footprint a layer's bins draw.
#[derive(Clone, Copy, Debug)]
pub(super) enum Shape {
    /// The physical ramped disk of CoC `r` ([`super::footprint::coverage_disk`]).
    Physical,
    /// The official footprint's disk of scatter radius `σ`: a hard disk of the soft step's
    /// equivalent radius, or its soft edge as 3 nested disks below `soft_below` (as
    /// `stripe::scan_sources` draws a source).
    Official { soft_below: f32 },
    /// A coarse grid's aggregated source ([`super::coarse`]): an antialiased hard disk of
    /// radius `ρ` (grid pixels) at a centre off the grid's lattice, rounded to `1/PHASES` of a
    /// grid pixel, clipped to a disk window of radius `window` (as `Stripe::disk` draws it).
    Coarse { window: f32 },
    /// The physical footprint of a non-disc aperture ([`Geometry::coverage`] over
    /// [`Geometry::norm`]) of CoC `r`, its plateau as spans and its outline as taps, clipped
    /// to the lens window; keys carry whether the shape is point-reflected (a source in front
    /// of the focal plane).
    Aperture(&'static Geometry),
    /// A coarse grid's aggregate of a non-disc aperture: its coverage at circumradius `ρ`
    /// (grid pixels) at a centre rounded to `1/SHAPE_PHASES` of a grid pixel, clipped to a
    /// disk window of radius `window`; the aggregate's value is a density (see
    /// `coarse::aggregate`), so the template is not normalized.
    CoarseAperture { shape: &'static Geometry, window: f32 },
}

/// Coarse shape: centre positions per grid pixel along each axis (a centre moves by at most
/// 1/32 of a grid pixel; a uniform cell's centroid lies on a position exactly). See
/// `coarse::COARSE_BIN` for the measurement that chose it.
pub(super) const PHASES: usize = 16;

/// Centre positions per grid pixel of a coarse aperture's template: a shape's template costs
/// O(ρ²) coverages to build, not a disk's O(ρ) chords, so fewer positions (a centre moves by
/// at most 1/8 of a grid pixel, before the bilinear upsampling blurs it).
pub(super) const SHAPE_PHASES: usize = 4;

impl Shape {
    /// The hard disks (radius offset, weight) a source of radius `r` is drawn as, around its
    /// equivalent radius.
    fn edge(self, r: f32) -> &'static [(f32, f32)] {
        match self {
            Shape::Official { soft_below } if r < soft_below => &SOFT_EDGE,
            _ => &HARD_EDGE,
        }
    }

    /// The radius of the hard disk drawn for radius `r`: the official footprint's equivalent
    /// radius, else `r` itself.
    fn disk_radius(self, r: f32) -> f32 {
        match self {
            Shape::Official { .. } => equivalent_radius(r),
            _ => r,
        }
    }

    /// Template positions per pixel along each axis.
    fn phases(self) -> usize {
        match self {
            Shape::Coarse { .. } => PHASES,
            Shape::CoarseAperture { .. } => SHAPE_PHASES,
            _ => 1,
        }
    }

    /// Whether keys carry the point reflection (an aperture that is not point-symmetric).
    fn flips(self) -> bool {
        match self {
            Shape::Aperture(g) | Shape::CoarseAperture { shape: g, .. } => !g.symmetric(),
            _ => false,
        }
    }

    /// The area of the nested disks `edge` around disk radius `rho`: an official or coarse
    /// source's value is scaled by its area over its bin's, so the bin keeps its flux (exact
    /// for the disks' continuous areas).
    fn area(edge: &[(f32, f32)], rho: f32) -> f32 {
        edge.iter().map(|&(off, wt)| wt * PI * (rho + off) * (rho + off)).sum()
    }
}

/// One bin's footprint, for a source of value 1 before its factor (see [`Bins::bin`]).
struct Template {
    /// A cat's eye: the relative change of the cut's flux per unit move of the class's circle
    /// centre `v` (x, y; [`Bins::cut_flux`]); zero without one.
    flux_grad: [f32; 2],
    /// What the footprint's weights were multiplied by: `1 / disk_norm` of the bin's radius
    /// (physical), the disk's area over the area its rows draw (coarse), 1 otherwise.
    scale: f32,
    /// Largest row offset from the centre's lattice row; row `j` is `rows[j + rr]`.
    rr: i64,
    /// Per row offset: its row differences `diffs[..]` and taps `taps[..]` (column offset,
    /// weight).
    rows: Vec<TemplateRow>,
    diffs: Vec<(i64, f64)>,
    taps: Vec<(i64, f32)>,
}

#[derive(Clone, Copy, Default)]
struct TemplateRow {
    diffs: (u32, u32),
    taps: (u32, u32),
}

impl Template {
    /// The footprint of radius `r` (CoC, scatter radius or disk radius, per `shape`) in a
    /// window of half-size `p`, centred `phase` (x, y; in `[0, 1)`, coarse shape only) past a
    /// lattice point: the rows, spans and taps the one-by-one draw of such a source makes.
    /// An aperture's shape is point-reflected when `flip`, and cut by a cat's eye's circle
    /// `cut` (the one its sources' light crosses, [`CatEye::cut`]; see
    /// [`Geometry::coverage_cut`]).
    fn new(shape: Shape, r: f32, phase: (f32, f32), flip: bool, cut: Option<CutCircle>, p: i64) -> Self {
        let mut t = Template { flux_grad: [0.0; 2], scale: 1.0, rr: 0, rows: Vec::new(), diffs: Vec::new(), taps: Vec::new() };
        match shape {
            Shape::Physical => {
                let (reach, inner) = (r + EDGE, r - EDGE);
                t.rr = (reach.ceil() as i64).min(p);
                let mut e = Vec::new();
                for dy in -t.rr..=t.rr {
                    let Some((xi, _)) = rim_row_taps(reach, inner, p, dy, |rho| disk_coverage(r, rho), &mut e) else {
                        t.push_row(&[], &[]);
                        continue;
                    };
                    // The plateau |dx| ≤ xi as one span, the taper's taps mirrored on the left
                    // (without the centre column).
                    let plateau: &[(i64, f64)] = if xi >= 0 { &[(-xi, 1.0), (xi + 1, -1.0)] } else { &[] };
                    let right = e.iter().enumerate().map(|(k, &c)| (xi + 1 + k as i64, c));
                    let taps: Vec<(i64, f32)> = right.clone().chain(right.filter(|&(dx, _)| dx > 0).map(|(dx, c)| (-dx, c))).collect();
                    t.push_row(plateau, &taps);
                }
            }
            Shape::Official { .. } | Shape::Coarse { .. } => {
                let (fx, fy) = phase;
                let (edge, rho) = (shape.edge(r), shape.disk_radius(r));
                let window = match shape {
                    Shape::Coarse { window } => Window::Disk(window),
                    _ => Window::Lattice(p),
                };
                // Rows j (from the centre's lattice row) with |j - fy| within a disk.
                let outer = rho + edge[edge.len() - 1].0;
                t.rr = (outer + fy).floor().max((fy - outer).ceil().abs()) as i64;
                for j in -t.rr..=t.rr {
                    let dy = j as f32 - fy;
                    let mut diffs = Vec::new();
                    for &(off, wt) in edge {
                        let Some(hw) = disk_chord(rho + off, window, dy).filter(|_| dy.abs() <= rho + off) else {
                            continue;
                        };
                        let (l, r) = (fx - hw + 0.5, fx + hw + 0.5);
                        if r > l {
                            let edges = span_edges(l, r, l.floor() as i64, r.floor() as i64);
                            diffs.extend(edges.iter().map(|&(dx, f)| (dx, f * wt as f64)));
                        }
                    }
                    t.push_row(&diffs, &[]);
                }
            }
            // The lens window's taps (|offset| < p, as the exact kernel's), or the coarse
            // window's disk around the off-lattice centre.
            Shape::Aperture(g) => t.shape_rows(g, r, (0.0, 0.0), flip, cut, |j| lattice_row_reach(p, j).map(|m| (-m as f32, m as f32))),
            Shape::CoarseAperture { shape: g, window } => t.shape_rows(g, r, phase, flip, cut, |j| {
                Window::Disk(window).half_width(j as f32 - phase.1).map(|hw| (phase.0 - hw, phase.0 + hw))
            }),
        }
        // The physical disk's unit flux folded into the weights: a source's own factor is
        // then 1, with no norm per source (`disk_norm` per source was 7% of a CoC-16 render).
        // Folding the official disks' area the same way moved the golden `bg_focus` case's max
        // abs error against the exact kernel from 0.0031 to 0.0087 (cause not found: the
        // products agree to 1e-7), so those keep a per-source ratio of areas.
        // A coarse disk's rows are chords at their centres: its area is divided out the same
        // way, so the aggregate's value keeps the flux of a disk of area π·r² (the factor of
        // `Bins::place` scales that to the source's own radius).
        t.scale = Template::scale_of(shape, r, phase.1);
        if t.scale != 1.0 {
            t.diffs.iter_mut().for_each(|d| d.1 *= t.scale as f64);
            t.taps.iter_mut().for_each(|c| c.1 *= t.scale);
        }
        t
    }

    /// The factor a template's weights are multiplied by (see [`Template::scale`]).
    fn scale_of(shape: Shape, r: f32, phase_y: f32) -> f32 {
        match shape {
            Shape::Physical => 1.0 / disk_norm(r),
            // A cat's eye's cut too: its targets normalize what passes (`fast::Ctx::cat_gains`).
            Shape::Aperture(g) => 1.0 / g.norm(r),
            // The aggregate's density is of the whole shape's area already.
            Shape::CoarseAperture { .. } => 1.0,
            Shape::Coarse { .. } => flux_scale(r, phase_y),
            Shape::Official { .. } => 1.0,
        }
    }

    /// This aperture template mirrored by `m` ([`Mirror`]) and its weights scaled to `scale`:
    /// the template of the key `m` was found for. Only an aperture's rows qualify (each
    /// row's differences close their spans, so they sum to 0). O(size).
    fn mirrored(&self, m: &Mirror, scale: f32) -> Template {
        let ratio = scale / self.scale;
        let [sx, sy] = m.shift;
        let rr = self.rr + sy;
        // The cut's centre mirrors with the weights.
        let [gx, gy] = self.flux_grad;
        let flux_grad = [if m.flip[0] { -gx } else { gx }, if m.flip[1] { -gy } else { gy }];
        let mut t = Template { flux_grad, scale, rr, rows: Vec::with_capacity(self.rows.len()), diffs: Vec::new(), taps: Vec::new() };
        let (mut diffs, mut taps) = (Vec::new(), Vec::new());
        for j in -rr..=rr {
            diffs.clear();
            taps.clear();
            let jc = if m.flip[1] { sy - j } else { j };
            if jc.abs() <= self.rr {
                let tr = self.rows[(jc + self.rr) as usize];
                let (d, c) = (&self.diffs[tr.diffs.0 as usize..tr.diffs.1 as usize], &self.taps[tr.taps.0 as usize..tr.taps.1 as usize]);
                if m.flip[0] {
                    // Column c ↦ s − c. A run [a, b) (+1 at a, −1 at b) becomes [s − b + 1,
                    // s − a + 1): each step −f at s − dx + 1.
                    diffs.extend(d.iter().rev().map(|&(dx, f)| (sx - dx + 1, -f * ratio as f64)));
                    taps.extend(c.iter().rev().map(|&(dx, w)| (sx - dx, w * ratio)));
                } else {
                    diffs.extend(d.iter().map(|&(dx, f)| (dx, f * ratio as f64)));
                    taps.extend(c.iter().map(|&(dx, w)| (dx, w * ratio)));
                }
            }
            t.push_row(&diffs, &taps);
        }
        t
    }

    /// The rows of an aperture's footprint of circumradius `r` centred `(fx, fy)` past the
    /// lattice point: per row `j`, the pixels wholly inside as spans (runs of coverage 1) and
    /// the others with some coverage as taps, where `window(j)` bounds `|dx|` (pixels whose
    /// centre column lies in it). O(r²) coverages.
    fn shape_rows(
        &mut self,
        g: &Geometry,
        r: f32,
        (fx, fy): (f32, f32),
        flip: bool,
        cut: Option<CutCircle>,
        window: impl Fn(i64) -> Option<(f32, f32)>,
    ) {
        // A pixel's tent (its square and the source's) reaches a pixel past the outline.
        let reach = r + 1.0;
        self.rr = (reach + fy).ceil() as i64;
        let (mut diffs, mut taps) = (Vec::new(), Vec::new());
        for j in -self.rr..=self.rr {
            diffs.clear();
            taps.clear();
            let dy = j as f32 - fy;
            if let Some((a, b)) = window(j).filter(|_| dy.abs() < reach) {
                let (lo, hi) = (((fx - reach).floor() as i64).max(a.ceil() as i64), ((fx + reach).ceil() as i64).min(b.floor() as i64));
                let mut run: Option<i64> = None;
                for dx in lo..=hi + 1 {
                    // Output coordinates, y up.
                    let c = if dx <= hi { g.coverage_cut(r, dx as f32 - fx, -dy, flip, cut) } else { 0.0 };
                    match (c == 1.0, run) {
                        (true, None) => run = Some(dx),
                        (false, Some(a)) => {
                            diffs.extend([(a, 1.0), (dx, -1.0)]);
                            run = None;
                        }
                        _ => {}
                    }
                    // (A bubble's weights may pass 1.)
                    if c > 0.0 && c != 1.0 {
                        taps.push((dx, c));
                    }
                }
            }
            self.push_row(&diffs, &taps);
        }
    }

    fn push_row(&mut self, diffs: &[(i64, f64)], taps: &[(i64, f32)]) {
        let (d0, t0) = (self.diffs.len() as u32, self.taps.len() as u32);
        self.diffs.extend_from_slice(diffs);
        self.taps.extend_from_slice(taps);
        self.rows.push(TemplateRow { diffs: (d0, self.diffs.len() as u32), taps: (t0, self.taps.len() as u32) });
    }

    /// Draws a run of sources centred at row `sy`, columns `x0 ..` (`run[i]` at `x0 + i`, values
    /// already scaled for this bin) into `st`, clipped to its rows. Returns the writes.
    fn draw(&self, st: &mut Stripe, sy: i64, x0: i64, run: &[[f32; 4]]) -> u64 {
        let (y0, y1) = st.rows();
        let mut ops = 0;
        for row in (sy - self.rr).max(y0)..=(sy + self.rr).min(y1 - 1) {
            let tr = self.rows[(row - sy + self.rr) as usize];
            let (diffs, taps) = (&self.diffs[tr.diffs.0 as usize..tr.diffs.1 as usize], &self.taps[tr.taps.0 as usize..tr.taps.1 as usize]);
            for &(dx, f) in diffs {
                st.diff_run(row, x0 + dx, run, f);
            }
            for &(dx, c) in taps {
                st.tap_run(row, x0 + dx, run, c);
            }
            ops += (diffs.len() + taps.len()) as u64;
        }
        ops * run.len() as u64
    }
}

/// How one layer's (or coarse level's) sources map to templates: radius bins `width` px wide
/// (and centre positions, for the coarse shape). Key `(k·P + py)·P + px` is bin `k` (radius
/// `k·width`) at centre position `(px, py)/P` past a lattice point (`P` = `shape.phases()`);
/// with a cat's eye, its second circle's centre, quantized ([`Bins::cut_class`]), sits in
/// the key's bits from [`CUT_SHIFT`] on.
#[derive(Clone, Copy, Debug)]
pub(super) struct Bins {
    shape: Shape,
    /// Window half-size.
    p: i64,
    /// Width of a bin, pixels (at radius 0, with `growth`).
    width: f32,
    /// Bins widening with the radius, `max(width, growth·r)` (0: uniform): a cat's eye's
    /// full-resolution templates ([`CAT_BIN_GROWTH`]).
    growth: f32,
    /// An aperture's cat's eye (its sources' templates are per cut as well).
    cat: Option<CatEye>,
    /// Full-resolution pixels per unit of the bins' radii (a coarse grid's `2^ℓ`).
    px_per_unit: f32,
}

/// How a cat's-eye template is the mirror image of another key's ([`Bins::mirror_of`]): its
/// weight at column `dx`, row `j` is the other's at `(flip[0] ? shift[0] − dx : dx,
/// flip[1] ? shift[1] − j : j)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Mirror {
    key: u64,
    flip: [bool; 2],
    shift: [i64; 2],
}

/// How a cat's eye's full-resolution radius bins widen with the radius: `CAT_BIN_GROWTH·r`
/// px wide at radius `r` where that passes the base width (from 2 px on at quality 2: 1/64
/// px below, r/128 above; see [`Bins::growth`]).
/// Its templates are per bin and cut class, and with uniform bins of 1/64 px a 12 MP render
/// focused at 0.2 (circles of 8-16 px on a slanted ground) built most of its time in them;
/// the outline's quantization by the cut classes (up to [`CUT_PX`] / 2) dwarfs a bin's
/// width / 2 at these radii, while small circles keep bins as fine as before (a light of
/// CoC 1-2 px drawn at a coarse bin's radius had its peak tens of percent off).
const CAT_BIN_GROWTH: f32 = 1.0 / 128.0;

/// Where a cat's eye's cut class starts in a key; 12 bits per axis above it.
const CUT_SHIFT: u32 = 40;
/// The cut's centre per axis in steps of `CUT_PX / r` (unit frame; at least 1/2048, at most
/// [`CUT_STEP_MAX`]): the outline of a template then lies within `CUT_PX / √2` px of the
/// source's own. A coarse grid (upsampled bilinearly, `2^ℓ` px per cell) quantizes to
/// [`CUT_PX_COARSE`] grid px: its templates were 78% of a 12 MP cat's-eye render at focus 1
/// with 0.5.
const CUT_PX: f32 = 0.25;
/// [`CUT_PX`] of the coarse grids, grid pixels.
const CUT_PX_COARSE: f32 = 1.0;
/// The coarsest cut step (unit frame), whatever the radius. Where neighbouring sources fall
/// in different classes the templates do not tile: an opaque surface's coverage falls short
/// by about the outline's move over the radius. `CUT_PX / r` alone made small circles' steps
/// an eighth of the radius (10% see-through at CoC 2 px, `tests/aperture.rs`); 1/32 keeps it
/// near 1% (1/64: within 1%, but 3.2x the 12 MP render at focus 1 in template builds; 1/32:
/// 1.5x, measured 2026-11-27).
const CUT_STEP_MAX: f32 = 1.0 / 32.0;

impl Bins {
    /// Bins `width` px wide of footprint `shape` in a window of half-size `p`.
    pub(super) fn new(shape: Shape, width: f32, p: usize) -> Self {
        Bins { shape, p: p as i64, width, growth: 0.0, cat: None, px_per_unit: 1.0 }
    }

    /// These bins with templates per cat's eye cut (an aperture shape only), their radii in
    /// units of `px_per_unit` full-resolution pixels.
    pub(super) fn with_cat_eye(self, cat: Option<CatEye>, px_per_unit: f32) -> Self {
        let cat = cat.filter(|_| matches!(self.shape, Shape::Aperture(_) | Shape::CoarseAperture { .. }));
        let growth = if cat.is_some() && matches!(self.shape, Shape::Aperture(_)) { CAT_BIN_GROWTH } else { 0.0 };
        Bins { cat, growth, px_per_unit, ..self }
    }

    /// Whether keys carry the point reflection: a shape that is not point-symmetric, or cut.
    fn flips(&self) -> bool {
        self.shape.flips() || self.cat.is_some()
    }

    /// The quantization step of a cut's centre in bin `k`.
    fn cut_step(&self, k: u64) -> f32 {
        let px = if matches!(self.shape, Shape::CoarseAperture { .. }) { CUT_PX_COARSE } else { CUT_PX };
        (px / self.radius(k).max(1e-3)).clamp(1.0 / 2048.0, CUT_STEP_MAX)
    }

    /// The cut class of a source at full-resolution pixel `at` in bin `k` (as [`Bins::key_of`]
    /// takes it; 0 without a cat's eye).
    #[inline]
    fn cut_class(&self, k: u64, at: (f32, f32)) -> u64 {
        let Some(cat) = self.cat else { return 0 };
        let [vx, vy] = cat.offset(at.0, at.1);
        let step = self.cut_step(k);
        let q = |v: f32| ((v / step).round().clamp(-2047.0, 2047.0) as i64 + 2048) as u64;
        (q(vy) << 12) | q(vx)
    }

    /// The cut of a key's class in bin `k`, reflected when `flip` (None without a cat's eye).
    fn cut_of(&self, k: u64, key: u64, flip: bool) -> Option<CutCircle> {
        let cat = self.cat?;
        let v = self.class_centre(k, key);
        Some(cat.cut(v, self.radius(k) * self.px_per_unit, flip))
    }

    /// The bin of radius `r` (a source centred on a lattice point) and the factor that scales
    /// a source's value for it (see [`Bins::factor`]; with the template's own scale, a physical
    /// source gets `1 / disk_norm` of its bin, unit flux, and an official one the ratio of its
    /// area to the bin's, its density applied besides). O(1).
    #[inline]
    pub(super) fn bin(&self, r: f32) -> (u64, f32) {
        let k = self.bin_index(r);
        (k, self.factor(k, r))
    }

    /// [`Bins::bin`] for an aperture's shape, point-reflected when `flip` (a source in front
    /// of the focal plane), of a source at full-resolution pixel `at` (its cat's eye's cut).
    #[inline]
    pub(super) fn bin_flipped(&self, r: f32, flip: bool, at: (f32, f32)) -> (u64, f32) {
        let k = self.bin_index(r);
        (self.key_of(k, flip && self.flips(), (0, 0), self.cut_class(k, at)), self.factor(k, r))
    }

    /// Coarse shape: the template of a disk of radius `rho` centred at `(cx, cy)` (grid
    /// pixels), the lattice point `(x, y)` it is placed at, and its value's factor. O(1).
    #[inline]
    /// With a cat's eye, `at` is the aggregate's full-resolution position (its cut).
    pub(super) fn place(&self, cx: f32, cy: f32, rho: f32, flip: bool, at: (f32, f32)) -> (u64, i64, i64, f32) {
        let n = self.shape.phases() as i64;
        let (qx, qy) = ((cx * n as f32).round() as i64, (cy * n as f32).round() as i64);
        let k = self.bin_index(rho);
        let phase = (qx.rem_euclid(n) as u64, qy.rem_euclid(n) as u64);
        let key = self.key_of(k, flip && self.flips(), phase, self.cut_class(k, at));
        (key, qx.div_euclid(n), qy.div_euclid(n), self.factor(k, rho))
    }

    #[inline]
    fn bin_index(&self, r: f32) -> u64 {
        let u = r.max(0.0) / self.width;
        // Uniform up to the radius where `growth·r` passes `width`, geometric beyond.
        let g = self.growth;
        if g > 0.0 && u * g > 1.0 { (1.0 / g + (u * g).ln() / g).round() as u64 } else { u.round() as u64 }
    }

    /// The factor of a source of radius `r` drawn by bin `k` (see [`Bins::bin`]): 1 for the
    /// physical disk (its template has unit flux), the ratio of the bin's disks' area at the
    /// source's own radius to theirs otherwise (so the source keeps its flux).
    #[inline]
    fn factor(&self, k: u64, r: f32) -> f32 {
        match self.shape {
            Shape::Physical | Shape::Aperture(_) => 1.0,
            // Coverage areas scale as ρ².
            Shape::CoarseAperture { .. } => {
                let rk = self.radius(k);
                if rk > 0.0 { (r / rk) * (r / rk) } else { 1.0 }
            }
            shape => {
                let (rk, edge) = (self.radius(k), shape.edge(self.radius(k)));
                Shape::area(edge, shape.disk_radius(r)) / Shape::area(edge, shape.disk_radius(rk))
            }
        }
    }

    /// The radius of bin `k`, pixels.
    fn radius(&self, k: u64) -> f32 {
        let g = self.growth;
        if g > 0.0 && k as f32 * g > 1.0 {
            return (k as f32 * g - 1.0).exp() / g * self.width;
        }
        k as f32 * self.width
    }

    /// A key's bin, point reflection and centre position `(px, py)` (in `1/P` of a pixel).
    fn parts(&self, key: u64) -> (u64, bool, u64, u64) {
        let n = self.shape.phases() as u64;
        let base = if self.cat.is_some() { key & ((1 << CUT_SHIFT) - 1) } else { key };
        let (k, py, px) = (base / (n * n), base / n % n, base % n);
        let (k, flip) = if self.flips() || matches!(self.shape, Shape::Aperture(_)) { (k / 2, k % 2 == 1) } else { (k, false) };
        (k, flip, px, py)
    }

    /// The key of bin `k`, reflection `flip`, centre position `(px, py)` and cut class
    /// `class` (as stored: 12 bits per axis, offset by 2048): the one encoding that
    /// [`Bins::place`], [`Bins::bin_flipped`] and [`Bins::mirror_of`] write and
    /// [`Bins::parts`] reads.
    #[inline]
    fn key_of(&self, k: u64, flip: bool, (px, py): (u64, u64), class: u64) -> u64 {
        let n = self.shape.phases() as u64;
        let kf = if self.flips() || matches!(self.shape, Shape::Aperture(_)) { k * 2 + u64::from(flip) } else { k };
        ((kf * n + py) * n + px) | (class << CUT_SHIFT)
    }

    /// The scale of `key`'s template ([`Template::scale`]), without building it.
    fn scale_of(&self, key: u64) -> f32 {
        let n = self.shape.phases() as f32;
        let (k, _, _, py) = self.parts(key);
        Template::scale_of(self.shape, self.radius(k), py as f32 / n)
    }

    /// With a cat's eye on a shape that is its own mirror image in x or y
    /// ([`Geometry::mirrors`]), the key whose template `key`'s mirrors, when it is another:
    /// the cut's circle centred `v` and the shape mirrored together leave the coverage
    /// mirrored, so only cuts with `v` on one side of each such axis are built; across the
    /// frame a cat's eye's `v` points to the centre from every quadrant (a 12 MP render at
    /// focus 0.2 built ~5,000 templates of ~0.3 ms each). The point reflection of a source
    /// in front of the focal plane does not fold into a source behind it (their product with
    /// both mirrors), as it did until 2026-11-29: a source in front meets another cut
    /// ([`CatEye::cut`]). A coarse template's centre position mirrors with it (`p ↦ (P − p) mod P`, a column or
    /// row's shift of one when `p ≠ 0`). Same weights up to rounding: the mirrored outline is
    /// the same polygon, its vertices computed in another order.
    fn mirror_of(&self, key: u64) -> Option<Mirror> {
        let (Some(_), Shape::Aperture(g) | Shape::CoarseAperture { shape: g, .. }) = (self.cat, self.shape) else { return None };
        let [mx, my] = g.mirrors();
        if !(mx || my) {
            return None;
        }
        let (k, flip, px, py) = self.parts(key);
        let class = key >> CUT_SHIFT;
        let (qx, qy) = (class & 0xFFF, class >> 12);
        // Mirrors taking the cut's centre to x ≥ 0 and y ≥ 0 (stored class 2048 is 0).
        let (cx, cy) = (mx && qx < 2048, my && qy < 2048);
        let canonical_class = (if cy { 4096 - qy } else { qy }) << 12 | if cx { 4096 - qx } else { qx };
        // The weight at output offset p of a source reflected by F (−1 when `flip`) is the
        // coverage A(F·p; v) = A(M·F·p; M·v) for the mirrors M. With both mirrors the
        // canonical template is unreflected and this one is it at M·F·p; otherwise it keeps
        // its reflection (F commutes with M) and this one is it at M·p.
        // Not across the focal plane: a source in front meets another cut (`CatEye::cut`).
        let (flip_c, gx, gy) = (flip, cx, cy);
        if !gx && !gy && flip_c == flip {
            return None;
        }
        let n = self.shape.phases() as u64;
        let mirror_phase = |p: u64, g: bool| if g { ((n - p) % n, i64::from(p != 0)) } else { (p, 0) };
        let ((px_c, sx), (py_c, sy)) = (mirror_phase(px, gx), mirror_phase(py, gy));
        let canonical = self.key_of(k, flip_c, (px_c, py_c), canonical_class);
        (canonical != key).then_some(Mirror { key: canonical, flip: [gx, gy], shift: [sx, sy] })
    }

    /// The template of `key`, built (O(r)).
    fn template(&self, key: u64) -> Template {
        let n = self.shape.phases() as u64;
        let (k, flip, px, py) = self.parts(key);
        let cut = self.cut_of(k, key, flip);
        let mut t = Template::new(self.shape, self.radius(k), (px as f32 / n as f32, py as f32 / n as f32), flip, cut, self.p);
        t.flux_grad = self.flux_grad(k, key, flip);
        t
    }

    /// The circle centre `v` (unit frame) of a key's cut class in bin `k`.
    fn class_centre(&self, k: u64, key: u64) -> [f32; 2] {
        let class = key >> CUT_SHIFT;
        let step = self.cut_step(k);
        let at = |q: u64| (q as i64 - 2048) as f32 * step;
        [at(class & 0xFFF), at(class >> 12)]
    }

    /// With a cat's eye, [`Template::flux_grad`] of a key: the cut's flux differenced over
    /// half a class step from the class's centre (3 areas of the outline, O(vertices) each).
    fn flux_grad(&self, k: u64, key: u64, flip: bool) -> [f32; 2] {
        let (Some(cat), Shape::Aperture(g) | Shape::CoarseAperture { shape: g, .. }) = (self.cat, self.shape) else { return [0.0; 2] };
        let [vx, vy] = self.class_centre(k, key);
        let r = self.radius(k) * self.px_per_unit;
        let h = 0.5 * self.cut_step(k);
        let flux = |v: [f32; 2]| g.cut_area(cat.cut(v, r, flip));
        let f0 = flux([vx, vy]);
        if f0 <= 0.0 {
            return [0.0; 2];
        }
        // Forward differences over half a step: the sources of the class lie within it.
        let d = |a: [f32; 2]| ((flux(a) - f0) / (h as f64 * f0)) as f32;
        [d([vx + h, vy]), d([vx, vy + h])]
    }

    /// A cat's eye: the factor of a source of `key` whose template is `t`, at lattice position
    /// `(x, y)`, for its own cut's flux over its class's (to first order in the move between
    /// the two circles, under half a class step per axis). A class's template keeps its
    /// class's flux, and the targets' gains count on each source's own: without this a light
    /// came out up to 2-3% dim or bright where its class rounded its circle (bench scene
    /// s007 of seed 1: fast 41.1 dB against the exact kernel's 47.8).
    #[inline]
    fn cut_flux(&self, t: &Template, key: u64, (x, y): (i64, i64)) -> f32 {
        let Some(cat) = self.cat else { return 1.0 };
        let (k, _, px, py) = self.parts(key);
        // The source's full-resolution position (a coarse key's centre past its lattice point),
        // clamped to the frame as a replicated source's cut is.
        let n = self.shape.phases() as f32;
        let f = self.px_per_unit;
        let pos = |l: i64, p: u64, size: usize| ((l as f32 + p as f32 / n + 0.5) * f - 0.5).clamp(0.0, size as f32 - 1.0);
        let [vx, vy] = cat.offset(pos(x, px, cat.width()), pos(y, py, cat.height()));
        let [qx, qy] = self.class_centre(k, key);
        1.0 + t.flux_grad[0] * (vx - qx) + t.flux_grad[1] * (vy - qy)
    }
}

/// The templates the workers of one layer (or coarse level, as its [`Bins`]) have built, by
/// key: each is built once, whichever worker needs it first, not once per worker (a 12.2 MP
/// cat's-eye render builds thousands, at up to a millisecond each).
#[derive(Default)]
pub(super) struct SharedTemplates(Mutex<HashMap<u64, Arc<Template>>>);

/// The templates one worker has drawn, by key (built on first use, or taken from the
/// [`SharedTemplates`] it shares; per layer, or per coarse level, as its [`Bins`]). Looked up
/// without a lock once a worker has met a key.
#[derive(Default)]
pub(super) struct Templates {
    local: HashMap<u64, Arc<Template>>,
    shared: Option<Arc<SharedTemplates>>,
}

impl Templates {
    /// A worker's templates that share `shared`'s.
    pub(super) fn sharing(shared: &Arc<SharedTemplates>) -> Self {
        Templates { local: HashMap::new(), shared: Some(Arc::clone(shared)) }
    }

    /// Whether these share a pool (a pooled scratch's may come from another layer).
    pub(super) fn shares(&self, shared: &Arc<SharedTemplates>) -> bool {
        self.shared.as_ref().is_some_and(|s| Arc::ptr_eq(s, shared))
    }

    fn get(&mut self, bins: &Bins, key: u64) -> &Template {
        if !self.local.contains_key(&key) {
            let found = self.shared.as_ref().and_then(|s| s.0.lock().unwrap_or_else(|e| e.into_inner()).get(&key).cloned());
            let t = found.unwrap_or_else(|| {
                // Built outside the lock; a worker that built it meanwhile wins.
                let t = Arc::new(match bins.mirror_of(key) {
                    Some(m) => self.get(bins, m.key).mirrored(&m, bins.scale_of(key)),
                    None => bins.template(key),
                });
                match &self.shared {
                    Some(shared) => Arc::clone(shared.0.lock().unwrap_or_else(|e| e.into_inner()).entry(key).or_insert(t)),
                    None => t,
                }
            });
            self.local.insert(key, t);
        }
        &self.local[&key]
    }
}

/// One source waiting in a batch: its accumulator, template, lattice position and value
/// (scaled for its template).
#[derive(Clone, Copy)]
pub(super) struct Entry {
    slot: u32,
    bin: u64,
    y: i64,
    x: i64,
    v: [f32; 4],
}

/// Sources waiting to be drawn by their templates (see [`flush`]).
#[derive(Default)]
pub(super) struct RowBatch {
    entries: Vec<Entry>,
    run: Vec<[f32; 4]>,
    /// Whether an entry went to an accumulator other than 0 (band passes): then the entries
    /// are grouped by sorting; otherwise a run is taken in arrival (column) order, where a
    /// bin's sources already follow each other wherever the depth is smooth (the sort was 9%
    /// of a CoC-16 render).
    sort: bool,
}

impl RowBatch {
    /// Adds a source at `(x, y)` with value `v` (scaled for template `bin`) to accumulator
    /// `slot`. Sources of one template and row must come in column order.
    #[inline]
    pub(super) fn push(&mut self, slot: usize, bin: u64, (x, y): (i64, i64), v: [f32; 4]) {
        self.sort |= slot != 0;
        self.entries.push(Entry { slot: slot as u32, bin, y, x, v });
    }
}

/// Draws the batched sources into the accumulators `accs`, per accumulator, row and template
/// in runs of consecutive sources at most `GAP` apart (templates from `templates`, built there on first
/// use), and empties the batch. Returns the writes. Allocation-free once the batch and the
/// templates have grown.
pub(super) fn flush(bins: &Bins, templates: &mut Templates, batch: &mut RowBatch, accs: &mut [Stripe]) -> u64 {
    if batch.entries.is_empty() {
        return 0;
    }
    if batch.sort {
        // Entries arrive in column order per row; a stable sort keeps it within a group.
        batch.entries.sort_by_key(|e| (e.slot, e.y, e.bin));
    }
    let mut ops = 0;
    let mut i = 0;
    let es = &batch.entries;
    while i < es.len() {
        // The run: entries of one (slot, row, template) each within GAP of the previous.
        let first = es[i];
        let same = |e: &Entry| e.slot == first.slot && e.y == first.y && e.bin == first.bin;
        let mut j = i + 1;
        while j < es.len() && same(&es[j]) && (0..=GAP).contains(&(es[j].x - es[j - 1].x)) {
            j += 1;
        }
        let x0 = first.x;
        batch.run.clear();
        batch.run.resize((es[j - 1].x - x0 + 1) as usize, [0.0; 4]);
        let t = templates.get(bins, first.bin);
        for e in &es[i..j] {
            let c = if bins.cat.is_some() { bins.cut_flux(t, e.bin, (e.x, e.y)) } else { 1.0 };
            for (o, v) in batch.run[(e.x - x0) as usize].iter_mut().zip(e.v) {
                *o += v * c;
            }
        }
        ops += t.draw(&mut accs[first.slot as usize], first.y, x0, &batch.run);
        i = j;
    }
    batch.entries.clear();
    batch.sort = false;
    ops
}

#[cfg(test)]
mod tests {
    use super::super::footprint::coverage_disk;
    use super::super::scratch::Scratch;
    use super::*;

    /// A run of sources drawn from a template equals the same sources drawn one by one at the
    /// bin's radius (the template is the one-by-one footprint, only shifted), in both
    /// profiles and for a coarse grid's disks off the lattice, including runs clipped by the
    /// grid's edges and the window, with gaps inside the run.
    #[test]
    fn a_run_is_its_sources_drawn_one_by_one() {
        let (w, y0, y1) = (40usize, 3usize, 19usize);
        let shapes = [Shape::Physical, Shape::Official { soft_below: 8.0 }, Shape::Coarse { window: 9.5 }, Shape::Coarse { window: 40.0 }];
        for (shape, (r, p)) in shapes.into_iter().flat_map(|s| [(4.0f32, 30usize), (6.375, 30), (11.5, 8), (15.875, 60)].map(|c| (s, c))) {
            let bins = Bins::new(shape, 0.125, p);
            // Coarse: a centre off the lattice, on one of the template positions.
            let (fx, fy) = match shape {
                Shape::Coarse { .. } => (3.0 / 8.0, 5.0 / 8.0),
                _ => (0.0, 0.0),
            };
            let (k, factor) = bins.bin(r);
            assert_eq!(bins.radius(k), r);
            let mut sc = Scratch::default();
            sc.accs.push(Stripe::new(w));
            sc.accs[0].reset(y0, y1);
            let mut one = Stripe::new(w);
            one.reset(y0, y1);
            let mut e = Vec::new();
            // Sources from left of the grid to right of it, with gaps, on a row above the stripe.
            let sy = 1i64;
            for x in (-6i64..46).filter(|x| x % 7 != 3) {
                let v = [0.1 * (x as f32).sin().abs(), 0.5, 0.2 + 0.01 * x as f32, 0.7];
                let (k, x0, y0, factor) = match shape {
                    Shape::Coarse { .. } => bins.place(x as f32 + fx, sy as f32 + fy, r, false, (0.0, 0.0)),
                    _ => (k, x, sy, factor),
                };
                assert_eq!((x0, y0), (x, sy));
                sc.bins.push(0, k, (x0, y0), v.map(|c| c * factor));
                match shape {
                    Shape::Physical => {
                        coverage_disk(&mut one, (x, sy), r, disk_norm(r), p as i64, v, &mut e);
                    }
                    Shape::Coarse { window } => {
                        let norm = flux_scale(r, fy);
                        one.disk(x as f32 + fx, sy as f32 + fy, r, Window::Disk(window), v.map(|c| c * norm));
                    }
                    Shape::Official { .. } => {
                        for &(off, wt) in shape.edge(r) {
                            one.disk(x as f32, sy as f32, equivalent_radius(r) + off, Window::Lattice(p as i64), v.map(|c| c * wt));
                        }
                    }
                    // Apertures are checked against the exact kernel (tests/aperture.rs).
                    Shape::Aperture(_) | Shape::CoarseAperture { .. } => unreachable!("not among this test's shapes"),
                }
            }
            assert!(flush(&bins, &mut Templates::default(), &mut sc.bins, &mut sc.accs) > 0);
            assert!(sc.bins.entries.is_empty());
            for row in 0..y1 - y0 {
                let (mut a, mut b) = (vec![0f32; w * 4], vec![0f32; w * 4]);
                sc.accs[0].add_row_to(row, &mut a);
                one.add_row_to(row, &mut b);
                for (x, (u, v)) in a.iter().zip(&b).enumerate() {
                    assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "{shape:?} r={r} p={p} row {row} col {}: {u} vs {v}", x / 4);
                }
            }
        }
    }

    /// Bins round to the nearest radius; the factor is the bin's unit flux (physical) or the
    /// ratio of areas that keeps an official source's flux (the bin's nested disks with the
    /// source's area).
    #[test]
    fn bins_round_to_the_nearest_and_keep_the_flux() {
        for width in [0.25f32, 0.125, 0.0625] {
            for shape in [Shape::Physical, Shape::Official { soft_below: 8.0 }] {
                let bins = Bins::new(shape, width, 200);
                for r in [4.0f32, 4.06, 4.07, 7.97, 8.01, 9.99, 15.99] {
                    let (k, factor) = bins.bin(r);
                    let rk = bins.radius(k);
                    assert!((rk - r).abs() <= 0.5 * width + 1e-6, "r={r}: bin {k}");
                    let total = factor * Templates::default().get(&bins, k).scale;
                    let expected = match shape {
                        Shape::Physical => 1.0 / disk_norm(rk),
                        _ => {
                            let (a, ak) = (equivalent_radius(r), equivalent_radius(rk));
                            let area = |rho: f32| shape.edge(rk).iter().map(|&(off, wt)| wt * (rho + off).powi(2)).sum::<f32>();
                            area(a) / area(ak)
                        }
                    };
                    assert!((total - expected).abs() <= 1e-6 * expected, "{shape:?} r={r}: {total} vs {expected}");
                }
            }
        }
    }

    /// A cat's eye's templates built as the mirror images of others ([`Bins::mirror_of`]) are
    /// the templates built directly, weight for weight (within 1e-5 of the largest): full
    /// resolution and coarse (centres off the lattice), behind and in front of the focal
    /// plane, cuts from every quadrant of the frame, for the disc's polygon (both mirrors),
    /// a hexagon at 0° (both), a pentagon at 90° (x only) and a 7-blade at 10° (none: every
    /// key its own).
    #[test]
    fn mirrored_cat_eye_templates_are_the_templates() {
        use crate::render::aperture::{Aperture, CatEye, ShapeSpec};
        let dense = |t: &Template| {
            let mut m = std::collections::HashMap::new();
            for (row, tr) in t.rows.iter().enumerate() {
                let (d, c) = (&t.diffs[tr.diffs.0 as usize..tr.diffs.1 as usize], &t.taps[tr.taps.0 as usize..tr.taps.1 as usize]);
                let j = row as i64 - t.rr;
                if let (Some(lo), Some(hi)) = (d.iter().map(|e| e.0).min(), d.iter().map(|e| e.0).max()) {
                    let mut acc = 0.0;
                    for dx in lo..hi {
                        acc += d.iter().filter(|e| e.0 == dx).map(|e| e.1).sum::<f64>();
                        *m.entry((dx, j)).or_insert(0.0) += acc;
                    }
                }
                for &(dx, w) in c {
                    *m.entry((dx, j)).or_insert(0.0) += w as f64;
                }
            }
            m.retain(|_, w| w.abs() > 1e-12);
            m
        };
        let cat = CatEye::new(1.0, 64, 48);
        for (name, mirrors) in [
            ("disc", [true, true]),
            ("blades:6", [true, true]),
            ("blades:5,rotation=90", [true, false]),
            ("blades:7,rotation=10", [false, false]),
        ] {
            let spec = ShapeSpec::parse(name, "test").unwrap();
            let g = Aperture::new(&spec, 1.0, "test").unwrap().with_cat_eye(1.0).unwrap().geometry().unwrap();
            assert_eq!(g.mirrors(), mirrors, "{name}");
            for shape in [Shape::Aperture(g), Shape::CoarseAperture { shape: g, window: 12.5 }] {
                let coarse = matches!(shape, Shape::CoarseAperture { .. });
                let bins = Bins::new(shape, 0.25, 30).with_cat_eye(Some(cat), if coarse { 4.0 } else { 1.0 });
                let (mut templates, mut mirrored) = (Templates::default(), 0);
                for (x, y) in [(3.0f32, 5.0f32), (60.0, 4.0), (5.0, 44.0), (58.0, 41.0), (31.5, 23.5), (31.5, 3.0), (10.0, 23.5)] {
                    for (r, flip) in [(2.3f32, false), (6.1, true), (9.0, false), (9.0, true)] {
                        let key = match shape {
                            Shape::CoarseAperture { .. } => bins.place(x / 4.0 + 0.3, y / 4.0 + 0.55, r, flip, (x, y)).0,
                            _ => bins.bin_flipped(r, flip, (x, y)).0,
                        };
                        mirrored += usize::from(bins.mirror_of(key).is_some());
                        let (want, got) = (dense(&bins.template(key)), dense(templates.get(&bins, key)));
                        let top = want.values().fold(0.0f64, |a, w| a.max(w.abs()));
                        for at in want.keys().chain(got.keys()) {
                            let (a, b) = (want.get(at).copied().unwrap_or(0.0), got.get(at).copied().unwrap_or(0.0));
                            assert!(
                                (a - b).abs() <= 1e-5 * top,
                                "{name} coarse {coarse} at ({x}, {y}) r {r} flip {flip}: weight at {at:?} {b}, built {a}"
                            );
                        }
                    }
                }
                // The mirrors were used where the shape has them.
                assert_eq!(mirrored > 0, g.mirrors().iter().any(|&m| m), "{name} {shape:?}: {mirrored} mirrored keys");
            }
        }
    }

    /// A coarse disk's centre goes to the nearest of `PHASES²` template positions around its
    /// lattice point, in any quadrant; the factor keeps its flux.
    #[test]
    fn coarse_centres_round_to_the_nearest_position() {
        let bins = Bins::new(Shape::Coarse { window: 100.0 }, 0.125, 0);
        let n = PHASES as f32;
        for (cx, cy) in [(0.0f32, 0.0f32), (3.49, -2.51), (-0.03, 7.97), (-5.2, -0.7), (12.0625, 3.9374)] {
            for rho in [7.0f32, 9.3, 16.96] {
                let (key, x, y, factor) = bins.place(cx, cy, rho, false, (0.0, 0.0));
                let n2 = PHASES as u64;
                let (k, py, px) = (key / n2 / n2, key / n2 % n2, key % n2);
                let (qx, qy) = (x as f32 + px as f32 / n, y as f32 + py as f32 / n);
                assert!((qx - cx).abs() <= 0.5 / n + 1e-5 && (qy - cy).abs() <= 0.5 / n + 1e-5, "({cx}, {cy}) -> ({qx}, {qy})");
                let rk = bins.radius(k);
                assert!((rk - rho).abs() <= 0.0625 + 1e-5);
                let total = factor * Templates::default().get(&bins, key).scale;
                // The disk of radius ρ's flux, over the area the bin's rows draw.
                let expected = PI * rho * rho / crate::render::splat::midpoint_area(rk, py as f32 / n);
                assert!((total - expected).abs() <= 1e-5 * expected, "rho {rho}: factor {total} vs {expected}");
            }
        }
    }
}
