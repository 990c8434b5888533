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
use super::stripe::Scratch;
use crate::render::lens::{disk_coverage, disk_norm};
use crate::render::splat::{Stripe, Window, disk_chord, span_edges};
use std::f32::consts::PI;
use std::sync::OnceLock;

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
}

impl Shape {
    /// The hard disks (radius offset, weight) a source of radius `r` is drawn as, around its
    /// equivalent radius.
    fn edge(self, r: f32) -> &'static [(f32, f32)] {
        match self {
            Shape::Official { soft_below } if r < soft_below => &SOFT_EDGE,
            _ => &HARD_EDGE,
        }
    }

    /// The area of the nested disks `edge` around the equivalent radius of (drawn) radius
    /// `r`: an official source's density is scaled by its area over its bin's, so the bin keeps
    /// its flux (exact for the disks' continuous areas).
    fn area(edge: &[(f32, f32)], r: f32) -> f32 {
        let rho = equivalent_radius(r);
        edge.iter().map(|&(off, wt)| wt * PI * (rho + off) * (rho + off)).sum()
    }
}

/// One radius bin's footprint, for a source of value 1 before its scale (see
/// [`Template::flux`]).
struct Template {
    /// Physical: `disk_norm` of the bin's radius (a source's value is divided by it once);
    /// official: [`Shape::area`] of the bin's radius and nested disks `edge`.
    flux: f32,
    edge: &'static [(f32, f32)],
    /// Largest row offset; row `dy` is `rows[dy + rr]`.
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
    /// The footprint of radius `r` (CoC or scatter radius, per `shape`) in a window of
    /// half-size `p`: the rows, spans and taps the one-by-one draw of a source at an integer
    /// position makes.
    fn new(shape: Shape, r: f32, p: i64) -> Self {
        let mut t = Template { flux: 0.0, edge: shape.edge(r), rr: 0, rows: Vec::new(), diffs: Vec::new(), taps: Vec::new() };
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
                t.flux = disk_norm(r);
            }
            Shape::Official { .. } => {
                let (edge, rho) = (t.edge, equivalent_radius(r));
                let window = Window::Lattice(p);
                t.rr = (rho + edge[edge.len() - 1].0).floor().max(0.0) as i64;
                for dy in -t.rr..=t.rr {
                    let mut diffs = Vec::new();
                    for &(off, wt) in edge {
                        let Some(hw) = disk_chord(rho + off, window, dy as f32).filter(|_| (dy as f32).abs() <= rho + off) else {
                            continue;
                        };
                        let (l, r) = (-hw + 0.5, hw + 0.5);
                        if r > l {
                            let edges = span_edges(l, r, l.floor() as i64, r.floor() as i64);
                            diffs.extend(edges.iter().map(|&(dx, f)| (dx, f * wt as f64)));
                        }
                    }
                    t.push_row(&diffs, &[]);
                }
                t.flux = Shape::area(edge, r);
            }
        }
        t
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

/// The radius bins of one layer: templates built on first use, shared by every stripe.
pub(super) struct Bins {
    shape: Shape,
    /// Window half-size.
    p: i64,
    /// Width of a bin, pixels.
    width: f32,
    /// Bin of the smallest radius drawn here; `templates[k - k0]` is bin `k` (radius
    /// `k·width`).
    k0: usize,
    templates: Vec<OnceLock<Template>>,
}

impl Bins {
    /// Bins `width` px wide for radii `[r_lo, r_hi)` of footprint `shape` in a window of
    /// half-size `p`. O(bins); templates are built when first drawn (O(r) each).
    pub(super) fn new(shape: Shape, r_lo: f32, r_hi: f32, width: f32, p: usize) -> Self {
        let bin_of = |r: f32| (r.max(0.0) / width).round() as usize;
        let (k0, k1) = (bin_of(r_lo), bin_of(r_hi));
        Bins { shape, p: p as i64, width, k0, templates: (k0..=k1.max(k0)).map(|_| OnceLock::new()).collect() }
    }

    /// The bin of radius `r` (within the range [`Bins::new`] was given) and the factor that
    /// scales a source's value for it: `1 / disk_norm` of the bin (physical, unit flux), or the
    /// ratio of the source's area to the bin's (official; its density is applied besides).
    #[inline]
    pub(super) fn bin(&self, r: f32) -> (u32, f32) {
        let k = ((r.max(0.0) / self.width).round() as usize).clamp(self.k0, self.k0 + self.templates.len() - 1);
        let t = self.template(k);
        let factor = match self.shape {
            Shape::Physical => 1.0 / t.flux,
            Shape::Official { .. } => Shape::area(t.edge, r) / t.flux,
        };
        (k as u32, factor)
    }

    /// The radius of bin `k`, pixels.
    fn radius(&self, k: usize) -> f32 {
        k as f32 * self.width
    }

    fn template(&self, k: usize) -> &Template {
        self.templates[k - self.k0].get_or_init(|| Template::new(self.shape, self.radius(k), self.p))
    }
}

/// One source waiting in a row: its accumulator, bin, column and value at unit flux.
#[derive(Clone, Copy)]
pub(super) struct Entry {
    slot: u32,
    bin: u32,
    x: i64,
    v: [f32; 4],
}

/// The sources of one row of sources that go to the radius bins (see [`flush`]).
#[derive(Default)]
pub(super) struct RowBatch {
    entries: Vec<Entry>,
    run: Vec<[f32; 4]>,
}

impl RowBatch {
    /// Adds a source at column `x` with value `v` (at unit flux for bin `bin`) to accumulator
    /// `slot`.
    #[inline]
    pub(super) fn push(&mut self, slot: usize, bin: u32, x: i64, v: [f32; 4]) {
        self.entries.push(Entry { slot: slot as u32, bin, x, v });
    }
}

/// Draws the row's batched sources (centred on row `sy`) into the stripe accumulators
/// `sc.accs`, per accumulator and bin in runs of sources at most `GAP` apart, and empties the
/// batch. Returns the writes. Allocation-free once the scratch has grown.
pub(super) fn flush(bins: &Bins, sy: i64, sc: &mut Scratch) -> u64 {
    let batch = &mut sc.bins;
    if batch.entries.is_empty() {
        return 0;
    }
    // Entries arrive in column order; a stable sort by (slot, bin) keeps it within a group.
    batch.entries.sort_by_key(|e| (e.slot, e.bin));
    let mut ops = 0;
    let mut i = 0;
    let es = &batch.entries;
    while i < es.len() {
        // The run: entries of one (slot, bin) each within GAP of the previous.
        let first = es[i];
        let mut j = i + 1;
        while j < es.len() && es[j].slot == first.slot && es[j].bin == first.bin && es[j].x - es[j - 1].x <= GAP {
            j += 1;
        }
        let x0 = first.x;
        batch.run.clear();
        batch.run.resize((es[j - 1].x - x0 + 1) as usize, [0.0; 4]);
        for e in &es[i..j] {
            for (o, v) in batch.run[(e.x - x0) as usize].iter_mut().zip(e.v) {
                *o += v;
            }
        }
        ops += bins.template(first.bin as usize).draw(&mut sc.accs[first.slot as usize], sy, x0, &batch.run);
        i = j;
    }
    batch.entries.clear();
    ops
}

#[cfg(test)]
mod tests {
    use super::super::footprint::coverage_disk;
    use super::*;

    /// A run of sources drawn from a template equals the same sources drawn one by one at the
    /// bin's radius (the template is the one-by-one footprint, only shifted), in both
    /// profiles, including runs clipped by the grid's edges and the window, with gaps inside
    /// the run.
    #[test]
    fn a_run_is_its_sources_drawn_one_by_one() {
        let (w, y0, y1) = (40usize, 3usize, 19usize);
        let shapes = [Shape::Physical, Shape::Official { soft_below: 8.0 }];
        for (shape, (r, p)) in shapes.into_iter().flat_map(|s| [(4.0f32, 30usize), (6.375, 30), (11.5, 8), (15.875, 60)].map(|c| (s, c))) {
            let bins = Bins::new(shape, r, r + 1.0, 0.125, p);
            let (k, factor) = bins.bin(r);
            assert_eq!(bins.radius(k as usize), r);
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
                sc.bins.push(0, k, x, v.map(|c| c * factor));
                match shape {
                    Shape::Physical => {
                        coverage_disk(&mut one, (x, sy), r, disk_norm(r), p as i64, v, &mut e);
                    }
                    Shape::Official { .. } => {
                        assert_eq!(factor, 1.0);
                        for &(off, wt) in shape.edge(r) {
                            one.disk(x as f32, sy as f32, equivalent_radius(r) + off, Window::Lattice(p as i64), v.map(|c| c * wt));
                        }
                    }
                }
            }
            assert!(flush(&bins, sy, &mut sc) > 0);
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

    /// Bins round to the nearest radius and clamp to their range; the factor is the bin's unit
    /// flux (physical) or the ratio of areas that keeps an official source's flux.
    #[test]
    fn bins_round_to_the_nearest_and_keep_the_flux() {
        for width in [0.25f32, 0.125, 0.0625] {
            for shape in [Shape::Physical, Shape::Official { soft_below: 8.0 }] {
                let bins = Bins::new(shape, 4.0, 16.0, width, 200);
                for r in [4.0f32, 4.06, 4.07, 7.97, 8.01, 9.99, 15.99] {
                    let (k, factor) = bins.bin(r);
                    let rk = bins.radius(k as usize);
                    assert!((rk - r).abs() <= 0.5 * width + 1e-6, "r={r}: bin {k}");
                    match shape {
                        Shape::Physical => assert_eq!(factor, 1.0 / disk_norm(rk)),
                        // The bin's nested disks with the source's area.
                        Shape::Official { .. } => {
                            let t = bins.template(k as usize);
                            assert!((factor * t.flux - Shape::area(t.edge, r)).abs() <= 1e-5 * t.flux);
                        }
                    }
                }
                assert_eq!(bins.radius(bins.bin(3.0).0 as usize), 4.0);
                assert_eq!(bins.radius(bins.bin(20.0).0 as usize), 16.0);
            }
        }
    }
}
