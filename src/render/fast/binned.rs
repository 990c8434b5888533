//! Medium physical disks by radius bin: sources whose CoC lies between the stencils and the
//! coarse grids (`stencil_max ≤ r < 2·r0`, 4 to 16 px at quality 2) are drawn per row of
//! sources and per radius bin, as shifted copies of the row.
//!
//! Drawn one by one ([`super::footprint::coverage_disk`]), each such source costs O(r) scattered
//! writes with a square root and a coverage per rim tap, and at CoCs of 8–16 px that was the
//! slowest range of the kernel (12.2 MP at focus 0.2 of the end-to-end scene: 1.9 G writes,
//! 6.3 s, where CoC 64 took 1.1 s). Here a source's radius is rounded to a bin
//! ([`super::FastParams::radius_bin`] px wide: 1/8 at quality 2);
//! a bin's footprint (plateau spans and rim taps, unit flux) is a [`Template`] built once per
//! layer; and the sources of one row that share a bin and lie within `GAP` px of each other
//! form a run, drawn by adding the run, shifted by each tap's offset, into the stripe's
//! accumulators: contiguous adds instead of one scattered write per tap and source.
//!
//! The rounding moves a disk's edge by at most half a bin, so a rim tap's coverage by at most
//! half a bin times the source's density; the flux stays exactly one (the template is
//! normalized by its own [`disk_norm`]).

use super::footprint::{EDGE, rim_row_taps};
use super::stripe::Scratch;
use crate::render::lens::{disk_coverage, disk_norm};
use crate::render::splat::Stripe;
use std::sync::OnceLock;

/// Sources of one bin at most this many pixels apart share a run (the zeros between them are
/// added too). A run costs a loop per template row and tap; a zero element, one add per tap.
pub(super) const GAP: i64 = 8;

/// One radius bin's footprint at unit flux.
struct Template {
    /// `1 / disk_norm(r)` of the bin's radius: a source's value is scaled by it once.
    inv_norm: f32,
    /// Largest row offset; row `dy` is `rows[dy + rr]`.
    rr: i64,
    /// Per row offset: the plateau `|dx| ≤ xi` (none when `xi < 0`) and the taper's taps
    /// `taps[start..start + len]` for `dx = xi + 1 ..`, mirrored on the left.
    rows: Vec<TemplateRow>,
    taps: Vec<f32>,
}

#[derive(Clone, Copy)]
struct TemplateRow {
    xi: i64,
    start: u32,
    len: u32,
}

impl Template {
    /// The footprint of a disk of radius `r` in a window of half-size `p` (the same rows and
    /// taps [`super::footprint::coverage_disk`] draws for a source of that radius).
    fn new(r: f32, p: i64) -> Self {
        let (reach, inner) = (r + EDGE, r - EDGE);
        let rr = (reach.ceil() as i64).min(p);
        let mut taps = Vec::new();
        let mut e = Vec::new();
        let rows = (-rr..=rr)
            .map(|dy| match rim_row_taps(reach, inner, p, dy, |rho| disk_coverage(r, rho), &mut e) {
                Some((xi, _)) => {
                    let start = taps.len() as u32;
                    taps.extend_from_slice(&e);
                    TemplateRow { xi, start, len: e.len() as u32 }
                }
                None => TemplateRow { xi: -1, start: 0, len: 0 },
            })
            .collect();
        Template { inv_norm: 1.0 / disk_norm(r), rr, rows, taps }
    }

    /// Draws a run of sources centred at row `sy`, columns `x0 ..` (`run[i]` at `x0 + i`, values
    /// already at unit flux) into `st`, clipped to its rows. Returns the writes.
    fn draw(&self, st: &mut Stripe, sy: i64, x0: i64, run: &[[f32; 4]]) -> u64 {
        let (y0, y1) = st.rows();
        let mut ops = 0;
        for row in (sy - self.rr).max(y0)..=(sy + self.rr).min(y1 - 1) {
            let tr = self.rows[(row - sy + self.rr) as usize];
            if tr.xi >= 0 {
                st.diff_run(row, x0 - tr.xi, run, 1.0);
                st.diff_run(row, x0 + tr.xi + 1, run, -1.0);
                ops += 2;
            }
            let taps = &self.taps[tr.start as usize..(tr.start + tr.len) as usize];
            for (k, &c) in taps.iter().enumerate() {
                let dx = tr.xi + 1 + k as i64;
                st.tap_run(row, x0 + dx, run, c);
                // The left taper mirrors the right one, without the centre column.
                if dx > 0 {
                    st.tap_run(row, x0 - dx, run, c);
                }
            }
            ops += 2 * taps.len() as u64;
        }
        ops * run.len() as u64
    }
}

/// The radius bins of one layer: templates built on first use, shared by every stripe.
pub(super) struct Bins {
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
    /// Bins `width` px wide for radii `[r_lo, r_hi)` in a window of half-size `p`. O(bins);
    /// templates are built when first drawn (O(r) each).
    pub(super) fn new(r_lo: f32, r_hi: f32, width: f32, p: usize) -> Self {
        let bin_of = |r: f32| (r.max(0.0) / width).round() as usize;
        let (k0, k1) = (bin_of(r_lo), bin_of(r_hi));
        Bins { p: p as i64, width, k0, templates: (k0..=k1.max(k0)).map(|_| OnceLock::new()).collect() }
    }

    /// The bin of radius `r` (within the range [`Bins::new`] was given) and the factor that
    /// brings a source's value to unit flux there.
    #[inline]
    pub(super) fn bin(&self, r: f32) -> (u32, f32) {
        let k = ((r.max(0.0) / self.width).round() as usize).clamp(self.k0, self.k0 + self.templates.len() - 1);
        (k as u32, self.template(k).inv_norm)
    }

    /// The radius of bin `k`, pixels.
    fn radius(&self, k: usize) -> f32 {
        k as f32 * self.width
    }

    fn template(&self, k: usize) -> &Template {
        self.templates[k - self.k0].get_or_init(|| Template::new(self.radius(k), self.p))
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
    /// bin's radius (the template is `coverage_disk`'s footprint, only shifted), including runs
    /// clipped by the grid's edges and the window, with gaps inside the run.
    #[test]
    fn a_run_is_its_sources_drawn_one_by_one() {
        let (w, y0, y1) = (40usize, 3usize, 19usize);
        for (r, p) in [(4.0f32, 30usize), (6.375, 30), (11.5, 8), (15.875, 60)] {
            let bins = Bins::new(r, r + 1.0, 0.125, p);
            let (k, inv) = bins.bin(r);
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
                sc.bins.push(0, k, x, v.map(|c| c * inv));
                coverage_disk(&mut one, (x, sy), r, disk_norm(r), p as i64, v, &mut e);
            }
            assert!(flush(&bins, sy, &mut sc) > 0);
            assert!(sc.bins.entries.is_empty());
            for row in 0..y1 - y0 {
                let (mut a, mut b) = (vec![0f32; w * 4], vec![0f32; w * 4]);
                sc.accs[0].add_row_to(row, &mut a);
                one.add_row_to(row, &mut b);
                for (x, (u, v)) in a.iter().zip(&b).enumerate() {
                    assert!((u - v).abs() <= 1e-6 * (1.0 + v.abs()), "r={r} p={p} row {row} col {}: {u} vs {v}", x / 4);
                }
            }
        }
    }

    #[test]
    fn bins_round_to_the_nearest_and_stay_in_range() {
        for width in [0.25f32, 0.125, 0.0625] {
            let bins = Bins::new(4.0, 16.0, width, 200);
            for r in [4.0f32, 4.06, 4.07, 9.99, 15.99] {
                let (k, inv) = bins.bin(r);
                assert!((bins.radius(k as usize) - r).abs() <= 0.5 * width + 1e-6, "r={r}: bin {k}");
                assert_eq!(inv, 1.0 / disk_norm(bins.radius(k as usize)));
            }
            assert_eq!(bins.radius(bins.bin(3.0).0 as usize), 4.0);
            assert_eq!(bins.radius(bins.bin(20.0).0 as usize), 16.0);
        }
    }
}
