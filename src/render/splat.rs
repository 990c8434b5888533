//! Scatter primitives of the fast kernel: 4-channel accumulation of taps and antialiased
//! disks, one horizontal stripe of rows at a time.
//!
//! A disk is written as one span per row into a row-wise difference array (4 writes per row
//! and channel, whatever the radius); a prefix sum per row then turns the differences into
//! values. Each stripe owns its rows, so stripes run in parallel without locks, and the result
//! does not depend on the thread count. Sums run in f64: a difference array cancels large
//! terms, which f32 would not survive over a 4000-pixel row. A [`Stripe`] is scratch that a
//! worker reuses from stripe to stripe (a fresh multi-megabyte buffer per stripe made the
//! kernel spend a third of its time in the OS zeroing pages).

use rayon::prelude::*;

/// Rows per stripe: the unit of parallel work (fixed, so results are thread-count independent).
pub const STRIPE_ROWS: usize = 64;

/// A grid of 4-channel values (R, G, B, W), interleaved, `width * height * 4` f32.
#[derive(Clone, Debug)]
pub struct Grid4 {
    /// Width in grid pixels.
    pub width: usize,
    /// Height in grid pixels.
    pub height: usize,
    /// Row-major values, 4 per pixel.
    pub data: Vec<f32>,
}

impl Grid4 {
    /// A zeroed grid (allocates `width·height·4` f32).
    pub fn new(width: usize, height: usize) -> Self {
        Grid4 { width, height, data: vec![0.0; width * height * 4] }
    }

    /// The 4 values of pixel `i` (row-major index).
    #[inline]
    pub fn at(&self, i: usize) -> &[f32] {
        &self.data[i * 4..i * 4 + 4]
    }

    /// Adds row `y` of this grid upsampled bilinearly by `factor` to a full-resolution row
    /// `out` (`out.len() / 4` pixels): full-resolution pixel centre `x + 0.5` maps to grid
    /// coordinate `(x + 0.5)/factor - 0.5` (grid pixel centres at integers), clamped at the
    /// edges. `tmp` is scratch (one grid row).
    pub fn add_upsampled_row(&self, y: usize, factor: f32, out: &mut [f32], tmp: &mut Vec<f32>) {
        let v = ((y as f32 + 0.5) / factor - 0.5).clamp(0.0, (self.height - 1) as f32);
        let y0 = v as usize;
        let y1 = (y0 + 1).min(self.height - 1);
        let fy = v - y0 as f32;
        // Vertical interpolation once per grid row, then horizontal per output pixel.
        let (r0, r1) =
            (&self.data[y0 * self.width * 4..(y0 + 1) * self.width * 4], &self.data[y1 * self.width * 4..(y1 + 1) * self.width * 4]);
        tmp.clear();
        tmp.extend(r0.iter().zip(r1).map(|(a, b)| a + fy * (b - a)));
        let last = (self.width - 1) as f32;
        for (x, o) in out.chunks_exact_mut(4).enumerate() {
            let u = ((x as f32 + 0.5) / factor - 0.5).clamp(0.0, last);
            // u ≥ 0: truncation is floor.
            let x0 = u as usize;
            let x1 = (x0 + 1).min(self.width - 1);
            let fx = u - x0 as f32;
            for c in 0..4 {
                let (a, b) = (tmp[x0 * 4 + c], tmp[x1 * 4 + c]);
                o[c] += a + fx * (b - a);
            }
        }
    }
}

/// The largest `|dx|` with `dx² + dy² < p²` (the official strict lattice window of half-size
/// `p`) in row `dy`; None where the row is outside it. Integer arithmetic, exact.
#[inline]
pub fn lattice_row_reach(p: i64, dy: i64) -> Option<i64> {
    let rem = p * p - dy * dy;
    if rem <= 0 {
        return None;
    }
    // The hardware square root, then corrected to the exact integer one (std's isqrt is a
    // software loop, measurably slower in the per-row path).
    let n = rem - 1;
    let mut m = (n as f64).sqrt() as i64;
    while m * m > n {
        m -= 1;
    }
    while (m + 1) * (m + 1) <= n {
        m += 1;
    }
    Some(m)
}

/// The lens window's edge for a disk span: how far a row may extend.
#[derive(Clone, Copy, Debug)]
pub enum Window {
    /// The official lattice mask `i² + j² < p²` (full-resolution grid, integer centres).
    Lattice(i64),
    /// A continuous disk of this radius in grid pixels (coarse grids).
    Disk(f32),
}

impl Window {
    /// Largest |dx| (continuous, edge-inclusive) allowed on row offset `dy`; `None` = row excluded.
    #[inline]
    pub(crate) fn half_width(self, dy: f32) -> Option<f32> {
        match self {
            // The last pixel of the row extends to m + 0.5.
            Window::Lattice(p) => lattice_row_reach(p, dy.round() as i64).map(|m| m as f32 + 0.5),
            Window::Disk(r) => (dy.abs() < r).then(|| (r * r - dy * dy).sqrt()),
        }
    }
}

/// The rows `[y0, y1)` of a grid being accumulated by one stripe, as row-wise differences.
pub struct Stripe {
    width: usize,
    y0: i64,
    y1: i64,
    /// Row-wise differences (spans), `(width + 2) * 4` per row, column shifted by one.
    diff: Vec<f64>,
    /// Plain values (taps), `width * 4` per row.
    direct: Vec<f32>,
    /// Whether anything was written to `diff` / `direct` since the last reset (a clean
    /// buffer is neither zeroed again nor summed: most layers use only one of the two).
    spans: bool,
    taps: bool,
}

/// A stripe buffer's first write: marked written, sized to `len` zeros (kept if it already is:
/// a clean buffer of that size).
fn first_write<T: Copy + Default>(written: &mut bool, buf: &mut Vec<T>, len: usize) {
    *written = true;
    if buf.len() != len {
        buf.resize(len, T::default());
    }
}

impl Stripe {
    /// Empty scratch; [`Stripe::reset`] sizes it.
    pub fn new(width: usize) -> Self {
        Stripe { width, y0: 0, y1: 0, diff: Vec::new(), direct: Vec::new(), spans: false, taps: false }
    }

    /// Starts accumulating rows `[y0, y1)` from zero, reusing the buffers. A buffer is sized
    /// and zeroed on its first write of the stripe ([`Stripe::spans_ready`],
    /// [`Stripe::taps_ready`]): one a stripe never writes is never touched, so a worker's
    /// scratch holds only the kinds of buffer its layer writes (12.2 MP: an accumulator's
    /// span buffer is 8 MB, its tap buffer 4 MB).
    pub fn reset(&mut self, y0: usize, y1: usize) {
        (self.y0, self.y1) = (y0 as i64, y1 as i64);
        // A clean buffer of the right size is all zeros already; any other is emptied.
        if self.spans || self.diff.len() != self.diff_len() {
            self.diff.clear();
        }
        if self.taps || self.direct.len() != self.direct_len() {
            self.direct.clear();
        }
        (self.spans, self.taps) = (false, false);
    }

    fn diff_len(&self) -> usize {
        (self.y1 - self.y0) as usize * (self.width + 2) * 4
    }

    fn direct_len(&self) -> usize {
        (self.y1 - self.y0) as usize * self.width * 4
    }

    /// Marks the span buffer written, sizing it (zeros) on the stripe's first span.
    #[inline(always)]
    fn spans_ready(&mut self) {
        if !self.spans {
            let n = self.diff_len();
            first_write(&mut self.spans, &mut self.diff, n);
        }
    }

    /// Marks the tap buffer written, sizing it (zeros) on the stripe's first tap.
    #[inline(always)]
    fn taps_ready(&mut self) {
        if !self.taps {
            let n = self.direct_len();
            first_write(&mut self.taps, &mut self.direct, n);
        }
    }

    /// The rows `[y0, y1)` being accumulated.
    pub fn rows(&self) -> (i64, i64) {
        (self.y0, self.y1)
    }

    #[inline(always)]
    fn add_diff(&mut self, row: i64, col: i64, v: [f32; 4], f: f64) {
        // Column index shifted by one: col may be -1 .. width (clipped spans write there).
        let col = col.clamp(-1, self.width as i64) + 1;
        self.spans_ready();
        let i = (((row - self.y0) as usize) * (self.width + 2) + col as usize) * 4;
        for (d, &vc) in self.diff[i..i + 4].iter_mut().zip(&v) {
            *d += vc as f64 * f;
        }
    }

    /// Adds `v·e[k]` to pixel `(x0 + k, row)` for each k (one stencil row), clipped to the
    /// stripe and grid.
    #[inline]
    pub fn tap_row(&mut self, x0: i64, row: i64, e: &[f32], v: [f32; 4]) {
        if row < self.y0 || row >= self.y1 {
            return;
        }
        let (ka, kb) = ((-x0).max(0) as usize, ((self.width as i64 - x0).max(0) as usize).min(e.len()));
        if ka >= kb {
            return;
        }
        self.taps_ready();
        let base = ((row - self.y0) as usize * self.width) as i64 + x0;
        let dst = &mut self.direct[((base + ka as i64) * 4) as usize..((base + kb as i64) * 4) as usize];
        for (o, &ek) in dst.chunks_exact_mut(4).zip(&e[ka..kb]) {
            for c in 0..4 {
                o[c] += v[c] * ek;
            }
        }
    }

    /// Adds `f·run[i]` to the row difference of column `x0 + i` of `row` for each `i`: the
    /// starts (`f = 1`) or ends (`f = -1`, one past the last pixel) of a span per element of a
    /// run of equal footprints. Clipped as [`Stripe::pixels`] clips: a column left of the grid
    /// counts as column -1 (the span starts at 0), one right of it is dropped. O(run).
    // Inline: called per template row and run by `fast::binned` (another module).
    #[inline]
    pub fn diff_run(&mut self, row: i64, x0: i64, run: &[[f32; 4]], f: f64) {
        if row < self.y0 || row >= self.y1 || run.is_empty() {
            return;
        }
        self.spans_ready();
        let w = self.width as i64;
        let base = (row - self.y0) as usize * (self.width + 2);
        // Elements i < a land left of column -1, i ≥ b right of the grid.
        let n = run.len() as i64;
        let a = (-1 - x0).clamp(0, n) as usize;
        let b = (w - x0).clamp(0, n) as usize;
        if a > 0 {
            let d = &mut self.diff[base * 4..base * 4 + 4];
            for v in &run[..a] {
                for c in 0..4 {
                    d[c] += v[c] as f64 * f;
                }
            }
        }
        if b > a {
            let start = (base as i64 + x0 + a as i64 + 1) as usize * 4;
            let dst = &mut self.diff[start..start + (b - a) * 4];
            // Flat slices: one vectorized multiply-add loop.
            for (o, &v) in dst.iter_mut().zip(run[a..b].as_flattened()) {
                *o += v as f64 * f;
            }
        }
    }

    /// Adds `wgt·run[i]` to pixel `(x0 + i, row)` for each `i` (one tap of a run of equal
    /// footprints), clipped to the stripe and grid. O(run).
    // Inline: called per template tap and run by `fast::binned` (another module).
    #[inline]
    pub fn tap_run(&mut self, row: i64, x0: i64, run: &[[f32; 4]], wgt: f32) {
        if row < self.y0 || row >= self.y1 {
            return;
        }
        let n = run.len() as i64;
        let (a, b) = ((-x0).clamp(0, n) as usize, (self.width as i64 - x0).clamp(0, n) as usize);
        if a >= b {
            return;
        }
        self.taps_ready();
        let start = ((row - self.y0) as usize * self.width) as i64 + x0 + a as i64;
        let dst = &mut self.direct[start as usize * 4..(start as usize + b - a) * 4];
        // Flat slices: one vectorized multiply-add loop.
        for (o, &v) in dst.iter_mut().zip(run[a..b].as_flattened()) {
            *o += v * wgt;
        }
    }

    /// Adds the values of stripe row `r` (prefix sum of the spans plus the taps) to `out`
    /// (up to `width * 4` f32: its first columns).
    pub fn add_row_to(&self, r: usize, out: &mut [f32]) {
        // `out` may hold the row's first columns only (a band row up to its last target).
        self.add_row_range_to(r, 0, (out.len() / 4).min(self.width), out);
    }

    /// [`Stripe::add_row_to`] for columns `[x0, x1)` only (`out` holds the whole row):
    /// valid when nothing was written left of `x0` or right of `x1` in this row (spans clipped
    /// at the left edge count as column 0). O(x1 - x0).
    pub fn add_row_range_to(&self, r: usize, x0: usize, x1: usize, out: &mut [f32]) {
        let w = self.width;
        // A buffer the stripe never wrote is empty (zeros by meaning).
        let direct = self.taps.then(|| &self.direct[r * w * 4..(r + 1) * w * 4]);
        if !self.spans {
            if let Some(direct) = direct {
                out[x0 * 4..x1 * 4].iter_mut().zip(&direct[x0 * 4..x1 * 4]).for_each(|(o, t)| *o += t);
            }
            return;
        }
        let d = &self.diff[r * (w + 2) * 4..(r + 1) * (w + 2) * 4];
        // Column -1 holds spans clipped at the left edge: it counts when the range starts at 0.
        let mut acc = if x0 == 0 { [d[0], d[1], d[2], d[3]] } else { [0.0; 4] };
        match direct {
            Some(direct) => {
                for x in x0..x1 {
                    for c in 0..4 {
                        acc[c] += d[(x + 1) * 4 + c];
                        out[x * 4 + c] += acc[c] as f32 + direct[x * 4 + c];
                    }
                }
            }
            None => {
                for x in x0..x1 {
                    for c in 0..4 {
                        acc[c] += d[(x + 1) * 4 + c];
                        out[x * 4 + c] += acc[c] as f32;
                    }
                }
            }
        }
    }

    /// Adds `v` to pixels `x0..=x1` of `row` (one span), clipped to the grid; rows outside the
    /// stripe are ignored.
    // Inline: the per-row step of every exact disk (another module); a call was ~30% of a
    // render at CoC 16.
    #[inline]
    pub fn pixels(&mut self, row: i64, x0: i64, x1: i64, v: [f32; 4]) {
        // Whole pixels: two differences (the antialiased span's other two weigh 0).
        let (a, b) = (x0.max(0), (x1 + 1).min(self.width as i64));
        if row >= self.y0 && row < self.y1 && b > a {
            self.add_diff(row, a, v, 1.0);
            self.add_diff(row, b, v, -1.0);
        }
    }

    /// Adds `v` times the coverage of each pixel of `row` by the interval `[l, r]` in edge
    /// coordinates (pixel i covers [i, i+1]).
    // Always inlined: it is the inner step of every disk row (a call per span cost ~10%).
    #[inline(always)]
    fn span(&mut self, row: i64, l: f32, r: f32, v: [f32; 4]) {
        let w = self.width as f32;
        let (l, r) = (l.max(0.0), r.min(w));
        if r <= l {
            return;
        }
        // l, r ≥ 0 here: truncation is floor (and avoids a libm call per span).
        let (il, ir) = (l as i64, r as i64);
        if il == ir {
            self.add_diff(row, il, v, (r - l) as f64);
            self.add_diff(row, il + 1, v, -(r - l) as f64);
            return;
        }
        for (col, f) in span_edges(l, r, il, ir) {
            self.add_diff(row, col, v, f);
        }
    }

    /// Adds `v` over an antialiased disk of radius `rho` centred at (cx, cy) (grid pixels,
    /// centres at integers), clipped to `window` around the centre. Rows use their centre's
    /// chord (midpoint rule), columns exact coverage. Returns the covered area, pixels.
    pub fn disk(&mut self, cx: f32, cy: f32, rho: f32, window: Window, v: [f32; 4]) -> f32 {
        let lo = ((cy - rho).ceil() as i64).max(self.y0);
        let hi = ((cy + rho).floor() as i64).min(self.y1 - 1);
        let mut area = 0.0;
        for row in lo..=hi {
            let Some(hw) = disk_chord(rho, window, row as f32 - cy) else { continue };
            self.span(row, cx - hw + 0.5, cx + hw + 0.5, v);
            area += 2.0 * hw;
        }
        area
    }
}

/// The area [`Stripe::disk`] covers for a disk of radius `rho` whose centre lies `fy` rows
/// past a grid row, without a window: the rows' chords ([`disk_chord`]) summed (the midpoint
/// rule). It differs from `π·rho²` by up to ~1.4% at the coarse grids' radii (8–16 grid px),
/// which a disk that stands for a known flux must divide out ([`flux_scale`]). O(rho).
pub fn midpoint_area(rho: f32, fy: f32) -> f32 {
    let (lo, hi) = ((fy - rho).ceil() as i64, (fy + rho).floor() as i64);
    (lo..=hi).filter_map(|row| disk_chord(rho, Window::Disk(f32::INFINITY), row as f32 - fy)).map(|hw| 2.0 * hw).sum()
}

/// The factor that gives a disk drawn by [`Stripe::disk`] (radius `rho`, centre `fy` rows past
/// a grid row, no window) the flux of a disk of area `π·rho²` per unit value: `π·rho²` over
/// [`midpoint_area`] (1 for a disk that draws nothing). Without it a uniform opaque layer
/// drawn by such disks leaks transmittance.
pub fn flux_scale(rho: f32, fy: f32) -> f32 {
    let a = midpoint_area(rho, fy);
    if a > 0.0 { std::f32::consts::PI * rho * rho / a } else { 1.0 }
}

/// Half the chord of a disk of radius `rho` at row offset `dy` from its centre, clipped to
/// `window`; None where the window excludes the row. (Rows use their centre's chord: the
/// midpoint rule of [`Stripe::disk`].)
#[inline]
pub fn disk_chord(rho: f32, window: Window, dy: f32) -> Option<f32> {
    let mw = window.half_width(dy)?;
    Some((rho * rho - dy * dy).max(0.0).sqrt().min(mw))
}

/// The row differences of an antialiased span covering `[l, r]` in edge coordinates (pixel
/// `i` covers `[i, i+1]`; `il`, `ir` the floors of `l` and `r`): each pixel gets its covered
/// fraction. Four (column, weight) pairs, some at the same column when `il == ir`.
#[inline(always)]
pub fn span_edges(l: f32, r: f32, il: i64, ir: i64) -> [(i64, f64); 4] {
    let a = (il as f32 + 1.0 - l) as f64;
    let b = (r - ir as f32) as f64;
    [(il, a), (il + 1, 1.0 - a), (ir, b - 1.0), (ir + 1, -b)]
}

/// Accumulates into `out` by running `visit` once per stripe of rows; `visit` adds taps and
/// disks (anything outside the stripe is ignored). Deterministic for any thread count.
pub fn accumulate<F>(out: &mut Grid4, visit: F)
where
    F: Fn(&mut Stripe) + Sync,
{
    let (w, h) = (out.width, out.height);
    out.data.par_chunks_mut(STRIPE_ROWS * w * 4).enumerate().for_each_init(
        || Stripe::new(w),
        |stripe, (s, chunk)| {
            let y0 = s * STRIPE_ROWS;
            stripe.reset(y0, (y0 + STRIPE_ROWS).min(h));
            visit(stripe);
            for (r, row) in chunk.chunks_exact_mut(w * 4).enumerate() {
                stripe.add_row_to(r, row);
            }
        },
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The integer row reach equals the float formula it replaced and the definition.
    #[test]
    fn lattice_row_reach_is_the_strict_window() {
        for p in 0..80i64 {
            for dy in -p - 2..=p + 2 {
                let rem = p * p - dy * dy;
                let float = (rem > 0).then(|| ((rem as f64).sqrt().ceil() as i64 - 1).max(0));
                let got = lattice_row_reach(p, dy);
                assert_eq!(got, float, "p {p} dy {dy}");
                if let Some(m) = got {
                    assert!(m * m + dy * dy < p * p && (m + 1) * (m + 1) + dy * dy >= p * p);
                }
            }
        }
    }

    /// A stripe sizes only the buffers it writes (so a worker's scratch holds no span buffer
    /// for a layer drawn by taps alone), a written buffer is emptied for the next stripe, and
    /// a row added to a shorter `out` fills its first columns.
    #[test]
    fn a_stripe_touches_only_the_buffers_it_writes() {
        let mut st = Stripe::new(10);
        st.reset(0, 4);
        st.tap_row(1, 2, &[1.0, 2.0], [1.0; 4]);
        assert!(st.diff.is_empty() && st.direct.len() == 4 * 10 * 4);
        let mut out = vec![0.0; 10 * 4];
        st.add_row_to(2, &mut out);
        let want: Vec<f32> = (0..10).flat_map(|x| [[0.0, 1.0, 2.0][x.min(2)] * (x < 3) as u8 as f32; 4]).collect();
        assert_eq!(out, want);
        st.reset(4, 8);
        assert!(st.direct.is_empty(), "the taps of the last stripe were not emptied");
        st.pixels(5, 3, 5, [1.0; 4]);
        assert!(st.direct.is_empty() && st.diff.len() == 4 * 12 * 4);
        let mut out = vec![0.0; 6 * 4];
        st.add_row_to(1, &mut out);
        assert_eq!(out, (0..6).flat_map(|x| [(x >= 3) as u8 as f32; 4]).collect::<Vec<f32>>());
    }

    #[test]
    fn disk_area_and_values() {
        let mut g = Grid4::new(64, 64);
        let mut area = 0.0;
        let area_ref = std::sync::Mutex::new(0.0f32);
        accumulate(&mut g, |s| {
            let a = s.disk(31.3, 30.7, 12.5, Window::Disk(100.0), [1.0, 2.0, 3.0, 1.0]);
            *area_ref.lock().unwrap() += a;
        });
        area += *area_ref.lock().unwrap();
        let total: f32 = g.data.chunks_exact(4).map(|p| p[3]).sum();
        assert!((total - area).abs() < 1e-2, "{total} vs {area}");
        assert!((area - std::f32::consts::PI * 12.5 * 12.5).abs() / area < 0.01);
        assert!((g.at(31 + 64 * 31)[1] - 2.0).abs() < 1e-6);
        assert!(g.at(0)[0] == 0.0);
    }

    /// The area `Stripe::disk` draws is [`midpoint_area`] (no window clip), whatever the
    /// centre's row phase.
    #[test]
    fn midpoint_area_is_what_a_disk_draws() {
        for (cy, rho) in [(30.0f32, 8.0f32), (30.5, 8.0), (30.25, 8.5), (29.9, 10.0), (30.7, 12.5), (30.0, 15.9)] {
            let mut st = Stripe::new(80);
            st.reset(0, 64);
            let drawn = st.disk(40.3, cy, rho, Window::Disk(1e3), [1.0; 4]);
            let expected = midpoint_area(rho, cy - cy.floor());
            assert!((drawn - expected).abs() <= 1e-4 * expected, "cy {cy} rho {rho}: {drawn} vs {expected}");
        }
        // At radius 8 on a row the chord sum falls short of the disk by more than 1%.
        assert!(midpoint_area(8.0, 0.0) < 0.99 * std::f32::consts::PI * 64.0);
    }

    /// Summing a column range gives the full row's values there when nothing was drawn
    /// outside it.
    #[test]
    fn row_range_is_the_row_where_the_range_holds_everything() {
        let mut st = Stripe::new(40);
        st.reset(0, 8);
        st.disk(20.3, 4.0, 3.5, Window::Disk(100.0), [1.0, 2.0, 3.0, 1.0]);
        st.tap_row(17, 2, &[0.5, 0.25], [1.0, 1.0, 1.0, 1.0]);
        for r in 0..8 {
            let (mut full, mut part) = (vec![0f32; 160], vec![0f32; 160]);
            st.add_row_to(r, &mut full);
            st.add_row_range_to(r, 15, 26, &mut part);
            assert_eq!(full[15 * 4..26 * 4], part[15 * 4..26 * 4], "row {r}");
            assert!(full[..15 * 4].iter().chain(&full[26 * 4..]).all(|&v| v == 0.0));
        }
    }

    #[test]
    fn lattice_window_matches_official_mask() {
        // p = 7: row 0 spans |dx| <= 6, row 6 spans |dx| <= 3 (36 + 9 < 49, 36 + 16 > 49).
        assert_eq!(Window::Lattice(7).half_width(0.0), Some(6.5));
        assert_eq!(Window::Lattice(7).half_width(6.0), Some(3.5));
        assert_eq!(Window::Lattice(7).half_width(7.0), None);
    }
}
