//! Binary-mask helpers shared by the stages: distance fields, dilation, erosion, softening.
//!
//! Masks are `&[bool]` of `width * height`, row-major, `true` = inside.

use crate::image::Image;
use image::{ImageBuffer, Luma};
use rayon::prelude::*;

/// Euclidean distance (pixels) from every pixel to the nearest `true` pixel of `mask`;
/// `f32::INFINITY` everywhere when the mask is empty. Linear time ([`sq_distance_window`] on the
/// whole image). Allocates the answer and one u32 plane.
pub fn distance_to(mask: &[bool], width: usize, height: usize) -> Vec<f32> {
    distance_in(mask, width, height, (0, 0, width, height))
}

/// [`distance_to`], exact wherever the distance is at most `limit` and `INFINITY` or a value
/// above `limit` elsewhere. Works on the mask's bounding box grown by `limit` only (every
/// pixel that close to the mask is inside it, and so is every mask pixel): a subject that
/// covers a small part of a 12 MP frame costs a fraction of the whole transform.
pub fn distance_within(mask: &[bool], width: usize, height: usize, limit: f32) -> Vec<f32> {
    match grown_bbox(mask, width, height, limit) {
        Some(bb) => distance_in(mask, width, height, bb),
        None => vec![f32::INFINITY; mask.len()],
    }
}

/// Bounding box `(x0, y0, x1, y1)` (exclusive ends) of the `true` pixels grown by `margin`
/// and clipped to the image; None for an empty mask. One pass over the mask ([`bbox`]).
pub fn grown_bbox(mask: &[bool], width: usize, height: usize, margin: f32) -> Option<(usize, usize, usize, usize)> {
    bbox(mask, width, true).map(|b| grow(b, width, height, margin))
}

/// The box of the pixels with `alpha > 0` (any one-channel plane) grown by `margin` and clipped
/// to the plane, as [`grown_bbox`] of that mask gives it, without the mask: one pass over the
/// plane, rows in parallel.
pub fn visible_box(alpha: &crate::image::Image, margin: f32) -> Option<(usize, usize, usize, usize)> {
    use rayon::prelude::*;
    let (w, h) = (alpha.width, alpha.height);
    let rows =
        alpha.data.par_chunks_exact(w.max(1)).enumerate().filter_map(|(y, row)| row_span(row, |a| a > 0.0).map(|(a, b)| (a, y, b, y + 1)));
    rows.reduce_with(|p, q| (p.0.min(q.0), p.1.min(q.1), p.2.max(q.2), p.3.max(q.3))).map(|b| grow(b, w, h, margin))
}

/// Box `b` grown by `margin` on every side and clipped to `width` x `height`.
fn grow((x0, y0, x1, y1): (usize, usize, usize, usize), width: usize, height: usize, margin: f32) -> (usize, usize, usize, usize) {
    // `as` saturates a huge margin to usize::MAX: the additions must saturate too (a blur of
    // 1e30 gives such margins; a wrapped sum shrank the box to the mask's own).
    let m = if margin.is_finite() { (margin.max(0.0).ceil() as usize).saturating_add(1) } else { width.max(height) };
    (x0.saturating_sub(m), y0.saturating_sub(m), x1.saturating_add(m).min(width), y1.saturating_add(m).min(height))
}

/// Bounding box `(x0, y0, x1, y1)` (exclusive ends) of the pixels of `mask` (rows of `width`)
/// equal to `value`; None when there is none. One pass over the mask, 64 pixels at a time
/// until a row's first and last match ([`row_span`]).
pub fn bbox(mask: &[bool], width: usize, value: bool) -> Option<(usize, usize, usize, usize)> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (y, row) in mask.chunks_exact(width).enumerate() {
        if let Some((a, b)) = row_span(row, |m| m == value) {
            (x0, x1, y0, y1) = (x0.min(a), x1.max(b), y0.min(y), y + 1);
        }
    }
    (x0 != usize::MAX).then_some((x0, y0, x1, y1))
}

/// Pixels a block of [`row_span`]'s scan holds: the compiler ORs a block without branches
/// (SIMD). The boxes of a 12.2 MP mask with a 31% ellipse and of its complement: 2.4-3.5 ms a
/// pixel at a time (`position`/`rposition`), 0.5-1.1 ms by blocks.
const SPAN_BLOCK: usize = 64;

/// The first and one past the last index of `row` whose value `hit` accepts; None when there
/// is none.
fn row_span<T: Copy>(row: &[T], hit: impl Fn(T) -> bool) -> Option<(usize, usize)> {
    let any = |block: &[T]| block.iter().fold(false, |any, &m| any | hit(m));
    let first = row.chunks(SPAN_BLOCK).position(any)? * SPAN_BLOCK;
    let a = first + row[first..].iter().position(|&m| hit(m)).expect("the block holds a match");
    let last = row.len() - row.rchunks(SPAN_BLOCK).position(any).expect("a match exists") * SPAN_BLOCK;
    let b = row[..last].iter().rposition(|&m| hit(m)).expect("the block holds a match") + 1;
    Some((a, b))
}

/// Distance to the mask's pixels inside the window `(x0, y0, x1, y1)`, computed on that window
/// only; `INFINITY` outside it. Exact (see [`sq_distance_window`]). Allocates the full plane
/// (4 bytes per pixel) plus the window's squared distances.
pub fn distance_in(mask: &[bool], width: usize, height: usize, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> Vec<f32> {
    let mut out = vec![f32::INFINITY; width * height];
    let cw = x1 - x0;
    if cw == 0 || y1 == y0 {
        return out;
    }
    let d2 = sq_distance_window(mask, width, (x0, y0, x1, y1), true);
    out[y0 * width..y1 * width].par_chunks_exact_mut(width).zip(d2.par_chunks_exact(cw)).for_each(|(row, src)| {
        for (o, &d) in row[x0..x1].iter_mut().zip(src) {
            *o = root(d);
        }
    });
    out
}

/// "No mask pixel in the window" in [`sq_distance_window`]'s output.
pub const NONE: u32 = u32::MAX;

/// Squared Euclidean distance (pixels²) from every pixel of the window `(x0, y0, x1, y1)`
/// (exclusive ends) to the nearest pixel of `mask` inside it that equals `value` (`true`: the
/// mask, `false`: its complement), row-major over the window; [`NONE`] everywhere when the
/// window holds no such pixel.
///
/// Exact, in integers (Felzenszwalb–Huttenlocher: per column the distance to the nearest mask
/// pixel, then per row the lower envelope of the parabolas `(x - q)² + g(q)²`), so the values
/// are those of any exact transform (imageproc's, used before, gives the same squares).
/// O(window pixels): two sequential sweeps down the window for the columns, then the rows in
/// parallel (rayon). Allocates the answer and one scratch row per row task (imageproc's
/// transform also needed a u8 copy of the mask and answered in f64: on the 12.2 MP end-to-end
/// scene the command's peak RSS fell from 1325 to 1226 MB with this one).
pub fn sq_distance_window(mask: &[bool], width: usize, (x0, y0, x1, y1): (usize, usize, usize, usize), value: bool) -> Vec<u32> {
    let cw = x1 - x0;
    let mut g = column_distances(mask, width, (x0, y0, x1, y1), value);
    // Row pass: the lower envelope of the column parabolas, each row on its own.
    g.par_chunks_exact_mut(cw).for_each_init(
        || (Vec::with_capacity(cw), Vec::with_capacity(cw + 1), Vec::with_capacity(cw)),
        |(v, z, f): &mut (Vec<usize>, Vec<f64>, Vec<u64>), row| {
            v.clear();
            z.clear();
            f.clear();
            f.extend(row.iter().map(|&d| if d == NONE { u64::MAX } else { d as u64 * d as u64 }));
            for q in 0..cw {
                if f[q] == u64::MAX {
                    continue;
                }
                // Where parabola q starts to lie below the envelope's last one.
                let fq = (f[q] + (q * q) as u64) as f64;
                let mut start = f64::NEG_INFINITY;
                while let Some(&p) = v.last() {
                    let s = (fq - (f[p] + (p * p) as u64) as f64) / (2 * (q - p)) as f64;
                    if s > *z.last().expect("one boundary per parabola") {
                        start = s;
                        break;
                    }
                    v.pop();
                    z.pop();
                }
                z.push(start);
                v.push(q);
            }
            if v.is_empty() {
                return;
            }
            let mut k = 0;
            for (x, out) in row.iter_mut().enumerate() {
                while k + 1 < v.len() && z[k + 1] < x as f64 {
                    k += 1;
                }
                let p = v[k];
                let d = (x.abs_diff(p) * x.abs_diff(p)) as u64 + f[p];
                *out = d.min(NONE as u64 - 1) as u32;
            }
        },
    );
    g
}

/// Per column of the window, rows to the nearest pixel of `mask` equal to `value` in the same
/// column of the window ([`NONE`]: none), row-major over the window: the first pass of
/// [`sq_distance_window`] and [`sq_distance_capped`]. The rows are cut into blocks swept down
/// and up on their own in parallel; then one row per block carries the nearest pixel above and
/// below the block across the others, and a parallel pass takes the nearer (the values are
/// those of two sweeps over the whole window, which ran on one thread and took ~25 ms of a
/// 12.2 MP frame's work box).
fn column_distances(mask: &[bool], width: usize, (x0, y0, x1, y1): (usize, usize, usize, usize), value: bool) -> Vec<u32> {
    let (cw, ch) = (x1 - x0, y1 - y0);
    let mut g = vec![NONE; cw * ch];
    if cw == 0 || ch == 0 {
        return g;
    }
    let rows = ch.div_ceil(4 * rayon::current_num_threads()).max(32);
    let step = |from: u32| if from == NONE { NONE } else { from + 1 };
    // Within each block: down (the nearest at or above), then up (or below).
    g.par_chunks_mut(rows * cw).enumerate().for_each(|(b, block)| {
        let n = block.len() / cw;
        for y in 0..n {
            let src = &mask[(y0 + b * rows + y) * width + x0..][..cw];
            let (done, rest) = block.split_at_mut(y * cw);
            let row = &mut rest[..cw];
            match y {
                0 => row.iter_mut().zip(src).for_each(|(v, &m)| *v = if m == value { 0 } else { NONE }),
                _ => row.iter_mut().zip(src).zip(&done[(y - 1) * cw..]).for_each(|((v, &m), &a)| *v = if m == value { 0 } else { step(a) }),
            }
        }
        for y in (0..n.saturating_sub(1)).rev() {
            let (head, tail) = block.split_at_mut((y + 1) * cw);
            head[y * cw..].iter_mut().zip(&tail[..cw]).for_each(|(v, &b)| *v = (*v).min(step(b)));
        }
    });
    let blocks = ch.div_ceil(rows);
    if blocks == 1 {
        return g;
    }
    let height = |b: usize| rows.min(ch - b * rows) as u32;
    // Per block and column: rows from its first row up to the nearest pixel in the blocks above
    // (a block's last row holds its own nearest at or above), and from its last row down.
    let mut above = vec![NONE; blocks * cw];
    for b in 1..blocks {
        let last = &g[(b * rows - 1) * cw..][..cw];
        let (done, rest) = above.split_at_mut(b * cw);
        let prev = &done[(b - 1) * cw..];
        for ((o, &l), &p) in rest[..cw].iter_mut().zip(last).zip(prev) {
            *o = if l != NONE {
                l + 1
            } else if p != NONE {
                p + height(b - 1)
            } else {
                NONE
            };
        }
    }
    let mut below = vec![NONE; blocks * cw];
    for b in (0..blocks - 1).rev() {
        let first = &g[(b + 1) * rows * cw..][..cw];
        let (head, done) = below.split_at_mut((b + 1) * cw);
        let next = &done[..cw];
        for ((o, &f), &nx) in head[b * cw..].iter_mut().zip(first).zip(next) {
            *o = if f != NONE {
                f + 1
            } else if nx != NONE {
                nx + height(b + 1)
            } else {
                NONE
            };
        }
    }
    g.par_chunks_mut(rows * cw).enumerate().for_each(|(b, block)| {
        let n = (block.len() / cw) as u32;
        let (up, down) = (&above[b * cw..][..cw], &below[b * cw..][..cw]);
        for (y, row) in block.chunks_exact_mut(cw).enumerate() {
            let y = y as u32;
            for ((v, &u), &d) in row.iter_mut().zip(up).zip(down) {
                if u != NONE {
                    *v = (*v).min(u + y);
                }
                if d != NONE {
                    *v = (*v).min(d + (n - 1 - y));
                }
            }
        }
    });
    g
}

/// [`sq_distance_window`], exact wherever the distance is at most `limit` pixels and some value
/// above `limit²` elsewhere: all a threshold test up to `limit` needs (dilation, erosion, "near
/// the mask"). Per pixel the minimum of `(x - q)² + g(q)²` over the `2·limit + 1` columns `q`
/// around it (the nearest mask pixel within `limit` lies in one of them), with `g` capped at
/// `limit + 1`: no envelope, no branch, vectorized. O(window pixels · limit); rows in parallel;
/// allocates the answer and a padded row per row task. A 1459x2729 window (the 12.2 MP
/// end-to-end scene's subject box; 2 threads, load average ~3): 20-23 ms at limit 3, 15-24 at
/// 6, 28-29 at 16, against 36-45 ms for the exact transform.
pub fn sq_distance_capped(
    mask: &[bool],
    width: usize,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    value: bool,
    limit: usize,
) -> Vec<u32> {
    let cw = x1 - x0;
    let mut g = column_distances(mask, width, (x0, y0, x1, y1), value);
    if cw == 0 {
        return g;
    }
    let far = ((limit + 1) * (limit + 1)) as u32;
    let avx2 = crate::cpu::has_avx2();
    g.par_chunks_exact_mut(cw).for_each_init(|| vec![far; cw + 2 * limit], |padded, row| capped_row(avx2, padded, row, limit));
    g
}

/// One row of [`sq_distance_capped`]: `row` holds the column distances in and the squared
/// distances out; `padded` is scratch of the row's length plus `limit` cells of "nothing near"
/// on each side. With `avx2` (the CPU has it), the same integer arithmetic on wider vectors
/// (the baseline build has no unsigned 32-bit minimum: SSE2).
fn capped_row(avx2: bool, padded: &mut [u32], row: &mut [u32], limit: usize) {
    crate::cpu::with_avx2(avx2, || capped_row_body(padded, row, limit))
}

#[inline(always)]
fn capped_row_body(padded: &mut [u32], row: &mut [u32], limit: usize) {
    let cw = row.len();
    // Squares of the capped column distances, `limit` columns of "nothing near" each side.
    for (p, &d) in padded[limit..limit + cw].iter_mut().zip(row.iter()) {
        *p = d.min(limit as u32 + 1).pow(2);
    }
    row.fill(u32::MAX);
    for k in 0..=2 * limit {
        let dx2 = (k.abs_diff(limit) * k.abs_diff(limit)) as u32;
        for (o, &p) in row.iter_mut().zip(&padded[k..k + cw]) {
            *o = (*o).min(dx2 + p);
        }
    }
}

/// Largest `limit` (pixels) for which [`sq_distance_upto`] takes [`sq_distance_capped`]: its
/// cost grows with the limit, the exact transform's does not (1459x2729 window, load average
/// ~3: 28-29 ms at 16, 38-39 at 24, exact 36-45).
pub const CAPPED_MAX: f32 = 16.0;

/// Squared distances exact up to `limit` pixels (see [`sq_distance_capped`]; the exact
/// [`sq_distance_window`] above [`CAPPED_MAX`] or for a NaN limit).
pub fn sq_distance_upto(mask: &[bool], width: usize, bbox: (usize, usize, usize, usize), value: bool, limit: f32) -> Vec<u32> {
    if limit <= CAPPED_MAX {
        sq_distance_capped(mask, width, bbox, value, limit.max(0.0).ceil() as usize)
    } else {
        sq_distance_window(mask, width, bbox, value)
    }
}

/// Distances (pixels) to a mask's pixels inside a box, kept on the box only: what
/// [`distance_in`] gives, without its full-size plane. 4 bytes per pixel of the box.
pub struct BoxDistance {
    width: usize,
    bbox: (usize, usize, usize, usize),
    d2: Vec<u32>,
}

impl BoxDistance {
    /// The exact distances to `mask`'s pixels inside `bbox` `(x0, y0, x1, y1)` (exclusive ends),
    /// on that box ([`sq_distance_window`]).
    pub fn new(mask: &[bool], width: usize, bbox: (usize, usize, usize, usize)) -> Self {
        BoxDistance { width, bbox, d2: sq_distance_window(mask, width, bbox, true) }
    }

    /// [`BoxDistance::new`] exact only up to `limit` pixels (above it, some distance above
    /// `limit`; see [`sq_distance_upto`]): for tests against a threshold up to `limit`.
    pub fn upto(mask: &[bool], width: usize, bbox: (usize, usize, usize, usize), limit: f32) -> Self {
        BoxDistance { width, bbox, d2: sq_distance_upto(mask, width, bbox, true, limit) }
    }

    /// No mask pixel anywhere: every distance is infinite.
    pub fn none(width: usize) -> Self {
        BoxDistance { width, bbox: (0, 0, 0, 0), d2: Vec::new() }
    }

    /// Image row `y`'s distances into `out` (the image's width of values): what
    /// [`BoxDistance::at`] gives along the row, without a division per pixel.
    pub fn row_into(&self, y: usize, out: &mut [f32]) {
        let (x0, y0, x1, y1) = self.bbox;
        out.fill(f32::INFINITY);
        if (y0..y1).contains(&y) {
            let cw = x1 - x0;
            for (o, &d) in out[x0..x1].iter_mut().zip(&self.d2[(y - y0) * cw..][..cw]) {
                *o = root(d);
            }
        }
    }

    /// The distance at pixel index `i` (row-major in the image): `INFINITY` outside the box,
    /// or where the box holds no mask pixel. The same value as [`distance_in`] on that box.
    #[inline]
    pub fn at(&self, i: usize) -> f32 {
        let (x, y) = (i % self.width, i / self.width);
        let (x0, y0, x1, y1) = self.bbox;
        if (x0..x1).contains(&x) && (y0..y1).contains(&y) { root(self.d2[(y - y0) * (x1 - x0) + x - x0]) } else { f32::INFINITY }
    }
}

/// A fast-marching `max_distance` (Telea) that surely covers every pixel within Euclidean
/// distance `d`: fast marching overestimates distance by a few percent on diagonals.
pub fn marching_reach(d: f32) -> f32 {
    d * 1.1 + 2.0
}

/// Pixels within `radius` of the mask (disk structuring element).
pub fn dilate(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    if !by_stencil(radius) {
        return dilate_by_distance(mask, width, height, radius);
    }
    let mut out = vec![false; mask.len()];
    // Every pixel within `radius` of the mask lies in its box grown by `radius`.
    if let Some(bb) = grown_bbox(mask, width, height, radius) {
        stencil_any(mask, width, height, bb, &disc_rows(radius), true, &mut out);
    }
    out
}

/// [`dilate`] through distances capped at `radius` (any radius; [`dilate`] takes it above
/// [`STENCIL_MAX`]).
fn dilate_by_distance(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    let mut out = vec![false; mask.len()];
    if let Some(bb) = grown_bbox(mask, width, height, radius) {
        window_map(&mut out, width, bb, &sq_distance_upto(mask, width, bb, true, radius), |_, d| d <= radius);
    }
    out
}

/// Largest radius (pixels) at which [`dilate`] and [`erode`] look at the disc's pixels directly
/// instead of taking distances: the same answer (a pixel is within `radius` exactly when one
/// of the offsets [`disc_rows`] lists, the ones whose [`root`] is at most `radius`, reaches the
/// mask), OR-ed a whole row at a time. A 1700x2850 work box of the 12.2 MP end-to-end scene:
/// a 2-3 px dilation or erosion took ~20 ms through the capped distances (see
/// [`sq_distance_capped`]), the disc's 13-29 row passes a few ms; at 6 px, 113 passes.
const STENCIL_MAX: f32 = 6.0;

/// Whether [`dilate`] and [`erode`] take the disc's pixels for `radius` (not for a NaN one,
/// which the distance route answers).
fn by_stencil(radius: f32) -> bool {
    radius <= STENCIL_MAX
}

/// Whether [`dilate`] by `radius` of the pixels for which `set(index)` holds would cover any
/// pixel of the box `(x0, y0, x1, y1)` (inclusive) of a plane `width` x `height`: whether
/// such a pixel lies within `radius` of the box. Reads the box grown by `radius`, nothing
/// frame-sized: for the few boxes of a sparse question a dilated plane costs far more.
pub fn any_within(
    set: impl Fn(usize) -> bool,
    width: usize,
    height: usize,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    radius: f32,
) -> bool {
    let rows = disc_rows(radius);
    let r = rows.len() / 2;
    // A pixel's nearest point of the box is along each axis the box's nearest row / column:
    // it is covered when that offset lies in the disc.
    let outside = |v: usize, lo: usize, hi: usize| lo.saturating_sub(v).max(v.saturating_sub(hi));
    (y0.saturating_sub(r)..=(y1 + r).min(height - 1)).any(|y| {
        let dy = outside(y, y0, y1);
        dy <= r && {
            let hw = rows[r + dy].1;
            (x0.saturating_sub(hw)..=(x1 + hw).min(width - 1)).any(|x| set(y * width + x))
        }
    })
}

/// The disc of offsets whose distance ([`root`] of `dx² + dy²`) is at most `radius`, as one
/// `(dy, half-width)` per row: `|dx| ≤ half-width`.
fn disc_rows(radius: f32) -> Vec<(isize, usize)> {
    // root(dy²) = |dy| for these small integers.
    let r = radius.max(0.0).floor() as isize;
    (-r..=r)
        .map(|dy| {
            let dy2 = (dy * dy) as u32;
            let hw = (0..=r as u32).take_while(|dx| root(dx * dx + dy2) <= radius).count() - 1;
            (dy, hw)
        })
        .collect()
}

/// For every pixel of the window `(x0, y0, x1, y1)` of `out` (a plane of `width` x `height`),
/// whether some offset of the disc `rows` ([`disc_rows`]) from it lands on a pixel of `mask`
/// equal to `value` (offsets off the plane never count); pixels outside the window are left as
/// they are. Rows in parallel, each an OR of shifted rows of the mask.
fn stencil_any(
    mask: &[bool],
    width: usize,
    height: usize,
    (x0, y0, x1, y1): (usize, usize, usize, usize),
    rows: &[(isize, usize)],
    value: bool,
    out: &mut [bool],
) {
    if x1 <= x0 {
        return;
    }
    let avx2 = crate::cpu::has_avx2();
    out[y0 * width..y1 * width].par_chunks_exact_mut(width).enumerate().for_each(|(y, row)| {
        crate::cpu::with_avx2(avx2, || {
            let y = y0 + y;
            let acc = &mut row[x0..x1];
            acc.fill(false);
            for &(dy, hw) in rows {
                let Some(yy) = y.checked_add_signed(dy).filter(|&yy| yy < height) else { continue };
                let src = &mask[yy * width..(yy + 1) * width];
                for dx in -(hw as isize)..=hw as isize {
                    // Window columns x with x + dx on the plane.
                    let lo = x0.max(dx.min(0).unsigned_abs());
                    let hi = x1.min(width.saturating_sub(dx.max(0) as usize));
                    if lo >= hi {
                        continue;
                    }
                    let from = lo.checked_add_signed(dx).expect("lo + dx is on the plane");
                    for (a, &m) in acc[lo - x0..hi - x0].iter_mut().zip(&src[from..from + (hi - lo)]) {
                        *a |= m == value;
                    }
                }
            }
        })
    });
}

/// Writes `f(pixel index, distance)` for every pixel of the window `(x0, y0, x1, y1)` of `out`
/// (a full plane), from the window's squared distances `d2`; rows in parallel.
fn window_map(
    out: &mut [bool],
    width: usize,
    (x0, y0, x1, _): (usize, usize, usize, usize),
    d2: &[u32],
    f: impl Fn(usize, f32) -> bool + Sync,
) {
    let cw = x1 - x0;
    if cw == 0 {
        return;
    }
    out[y0 * width..].par_chunks_exact_mut(width).zip(d2.par_chunks_exact(cw)).enumerate().for_each(|(y, (row, src))| {
        let base = (y0 + y) * width;
        for (x, (o, &d)) in row[x0..x1].iter_mut().zip(src).enumerate() {
            *o = f(base + x0 + x, root(d));
        }
    });
}

/// The distance (pixels) of a squared distance from [`sq_distance_window`]; `INFINITY` for
/// [`NONE`]. The root in f64, rounded to f32 (what the f64 transform before gave). Below 2²⁴,
/// where the square converts to f32 exactly, the f32 root gives those bits (a root rounded to
/// f64 then to f32 is rounded once: 53 ≥ 2·24 + 2; `root_in_f32_is_the_f64_root` checks every
/// value), at twice the f64 root's throughput.
#[inline]
pub fn root(d2: u32) -> f32 {
    if d2 == NONE {
        f32::INFINITY
    } else if d2 < 1 << 24 {
        (d2 as f32).sqrt()
    } else {
        (d2 as f64).sqrt() as f32
    }
}

/// Pixels farther than `radius` from the mask's complement (disk structuring element).
/// Pixels on the image border are not eroded by the outside: the mask may run off-frame.
pub fn erode(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    if radius <= 0.0 {
        return mask.to_vec();
    }
    if !by_stencil(radius) {
        return erode_by_distance(mask, width, height, radius);
    }
    // Only the mask's own box can stay; there, a pixel stays unless the outside is near.
    let Some(own) = bbox(mask, width, true) else { return mask.to_vec() };
    let mut out = vec![false; mask.len()];
    stencil_any(mask, width, height, own, &disc_rows(radius), false, &mut out);
    out.par_iter_mut().zip(mask).for_each(|(o, &m)| *o = m & !*o);
    out
}

/// [`erode`] through distances capped at `radius` (any radius; [`erode`] takes it above
/// [`STENCIL_MAX`]).
fn erode_by_distance(mask: &[bool], width: usize, height: usize, radius: f32) -> Vec<bool> {
    // Only mask pixels can stay; the complement pixels that decide them are within `radius`.
    let Some(bb) = grown_bbox(mask, width, height, radius) else { return mask.to_vec() };
    let mut out = vec![false; mask.len()];
    window_map(&mut out, width, bb, &sq_distance_upto(mask, width, bb, false, radius), |i, d| mask[i] && d > radius);
    out
}

/// The median of `v` (the upper one for an even count), reordering `v`; None when empty.
/// O(n) (selection, not a sort).
pub fn median(v: &mut [f32]) -> Option<f32> {
    if v.is_empty() {
        return None;
    }
    let k = v.len() / 2;
    Some(*v.select_nth_unstable_by(k, f32::total_cmp).1)
}

/// Gaussian blur of a one-channel image (`sigma` in pixels; ≤ 0 returns a copy).
pub fn gaussian_blur(plane: &Image, sigma: f32) -> Image {
    debug_assert_eq!(plane.channels, 1);
    if sigma <= 0.0 || plane.is_empty() {
        return plane.clone();
    }
    let buf =
        ImageBuffer::<Luma<f32>, Vec<f32>>::from_raw(plane.width as u32, plane.height as u32, plane.data.clone()).expect("plane size");
    let out = imageproc::filter::gaussian_blur_f32(&buf, sigma);
    Image::from_vec(plane.width, plane.height, 1, out.into_raw()).expect("plane size")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The f32 root below 2^24 against the f64 root rounded to f32, every value; above, NONE.
    #[test]
    fn root_in_f32_is_the_f64_root() {
        let bad = (0u32..1 << 24).into_par_iter().filter(|&d| root(d).to_bits() != ((d as f64).sqrt() as f32).to_bits()).count();
        assert_eq!(bad, 0);
        for d in [1 << 24, (1 << 24) + 1, u32::MAX - 1] {
            assert_eq!(root(d), (d as f64).sqrt() as f32);
        }
        assert_eq!(root(NONE), f32::INFINITY);
    }

    /// A huge margin (a blur of 1e30 makes them) grows the box to the whole frame; a small one
    /// by its ceiling plus one; an empty mask has no box.
    #[test]
    fn grown_box_saturates() {
        let (w, h) = (20, 10);
        let mut mask = vec![false; w * h];
        assert_eq!(grown_bbox(&mask, w, h, 1.0), None);
        mask[5 * w + 8] = true;
        assert_eq!(grown_bbox(&mask, w, h, 1.5), Some((5, 2, 12, 9)));
        for m in [1e30, f32::MAX, f32::INFINITY, 1e9] {
            assert_eq!(grown_bbox(&mask, w, h, m), Some((0, 0, w, h)), "margin {m}");
        }
    }

    /// The column pass cut into blocks of rows gives each pixel the rows to the nearest mask
    /// pixel of its column, however many blocks away (or NONE): single pixels at the top and
    /// the bottom of tall columns, an empty column, a full one, and a window.
    #[test]
    fn column_pass_carries_across_blocks() {
        let (w, h) = (5, 333);
        let mut mask = vec![false; w * h];
        mask[5 * w] = true;
        mask[320 * w + 2] = true;
        mask[40 * w + 3] = true;
        mask[290 * w + 3] = true;
        (0..h).for_each(|y| mask[y * w + 4] = true);
        for win in [(0, 0, w, h), (1, 3, 5, 330)] {
            let (x0, y0, x1, y1) = win;
            let g = column_distances(&mask, w, win, true);
            for y in y0..y1 {
                for x in x0..x1 {
                    let near = (y0..y1).filter(|&yy| mask[yy * w + x]).map(|yy| yy.abs_diff(y) as u32).min().unwrap_or(NONE);
                    assert_eq!(g[(y - y0) * (x1 - x0) + x - x0], near, "window {win:?}, pixel ({x}, {y})");
                }
            }
        }
    }

    /// The integer transform against imageproc's f64 one (the oracle it replaced) and a brute
    /// force, on seeded random masks of several densities, windows included.
    #[test]
    fn distances_match_imageproc_and_brute_force() {
        let mut s = 7u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 33) as u32
        };
        // Tall sparse frames cut the column pass into several blocks, with columns whose nearest
        // pixel lies blocks away or nowhere.
        for (w, h, per_mille) in [
            (1, 1, 500),
            (1, 9, 200),
            (13, 1, 100),
            (37, 23, 3),
            (40, 31, 50),
            (29, 40, 600),
            (16, 16, 0),
            (7, 301, 4),
            (4, 257, 30),
            (3, 400, 1),
        ] {
            let mask: Vec<bool> = (0..w * h).map(|_| rnd() % 1000 < per_mille).collect();
            let buf = ImageBuffer::<Luma<u8>, Vec<u8>>::from_raw(w as u32, h as u32, mask.iter().map(|&m| m as u8).collect()).unwrap();
            let oracle = imageproc::distance_transform::euclidean_squared_distance_transform(&buf).into_raw();
            let ours = sq_distance_window(&mask, w, (0, 0, w, h), true);
            let complement: Vec<bool> = mask.iter().map(|&m| !m).collect();
            assert_eq!(sq_distance_window(&complement, w, (0, 0, w, h), false), ours);
            for i in 0..w * h {
                let brute =
                    (0..w * h).filter(|&j| mask[j]).map(|j| ((i % w).abs_diff(j % w).pow(2) + (i / w).abs_diff(j / w).pow(2)) as u32).min();
                assert_eq!(Some(ours[i]).filter(|&d| d != NONE), brute, "{w}x{h} pixel {i}");
                if brute.is_some() {
                    assert_eq!(ours[i] as f64, oracle[i], "{w}x{h} pixel {i}");
                }
            }
            let (x0, y0, x1, y1) = (w / 4, h / 3, w - w / 5, h);
            let win = distance_in(&mask, w, h, (x0, y0, x1, y1));
            for y in 0..h {
                for x in 0..w {
                    let inside = (x0..x1).contains(&x) && (y0..y1).contains(&y);
                    let brute = (y0..y1)
                        .flat_map(|yy| (x0..x1).map(move |xx| (xx, yy)))
                        .filter(|&(xx, yy)| mask[yy * w + xx])
                        .map(|(xx, yy)| ((x.abs_diff(xx).pow(2) + y.abs_diff(yy).pow(2)) as f64).sqrt() as f32)
                        .fold(f32::INFINITY, f32::min);
                    let want = if inside { brute } else { f32::INFINITY };
                    assert_eq!(win[y * w + x].to_bits(), want.to_bits(), "{w}x{h} window, ({x}, {y})");
                }
            }
        }
    }

    /// Dilation and erosion on the window against their plain formulas on whole-image
    /// distances, seeded random masks, radii with and without a root exactly on a pixel.
    #[test]
    fn windowed_morphology_is_the_plain_formula() {
        let (w, h) = (41, 29);
        let mut s = 5u64;
        for per_mille in [2, 30, 400, 900] {
            let mask: Vec<bool> = (0..w * h)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 33) % 1000 < per_mille
                })
                .collect();
            let to_mask = distance_to(&mask, w, h);
            let to_outside = distance_to(&mask.iter().map(|&m| !m).collect::<Vec<_>>(), w, h);
            for r in [0.5, 1.0, 2.0, 3.0, 5.0_f32.sqrt(), 6.5] {
                let want: Vec<bool> = to_mask.iter().map(|&d| d <= r).collect();
                assert_eq!(dilate(&mask, w, h, r), want, "dilate {per_mille} {r}");
                // Erosion: the outside within the mask's box grown by r decides (as before).
                let want: Vec<bool> = mask.iter().zip(&to_outside).map(|(&m, &d)| m && d > r).collect();
                let got = erode(&mask, w, h, r);
                if grown_bbox(&mask, w, h, r) == Some((0, 0, w, h)) {
                    assert_eq!(got, want, "erode {per_mille} {r}");
                }
            }
        }
    }

    /// The capped rows' AVX2 build against the baseline one: same values on random column
    /// distances (NONE among them) at every limit up to [`CAPPED_MAX`].
    #[test]
    fn capped_rows_agree_across_builds() {
        if !crate::cpu::has_avx2() {
            return;
        }
        let mut s = 7u64;
        for limit in 0..=CAPPED_MAX as usize {
            for cw in [1usize, 7, 33, 300] {
                let col: Vec<u32> = (0..cw)
                    .map(|_| {
                        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        if (s >> 60) == 0 { NONE } else { ((s >> 33) % 40) as u32 }
                    })
                    .collect();
                let far = ((limit + 1) * (limit + 1)) as u32;
                let (mut a, mut b) = (col.clone(), col);
                capped_row(false, &mut vec![far; cw + 2 * limit], &mut a, limit);
                capped_row(true, &mut vec![far; cw + 2 * limit], &mut b, limit);
                assert_eq!(a, b, "limit {limit}, width {cw}");
            }
        }
    }

    /// The disc's direct OR ([`stencil_any`], radii up to [`STENCIL_MAX`]) against the distance
    /// route it replaces, bit for bit: random masks of several densities, masks on the edges,
    /// thin and one-pixel planes, radii with and without a root exactly on a pixel.
    #[test]
    fn stencil_morphology_is_the_distance_route() {
        let mut s = 11u64;
        for (w, h) in [(1, 1), (1, 17), (23, 1), (37, 29), (80, 13)] {
            for per_mille in [0, 5, 60, 500, 950, 1000] {
                let mut mask: Vec<bool> = (0..w * h)
                    .map(|_| {
                        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        (s >> 33) % 1000 < per_mille
                    })
                    .collect();
                if per_mille == 5 {
                    // Pixels on the frame's edges and corners.
                    for i in [0, w - 1, w * (h - 1), w * h - 1, w * (h / 2)] {
                        mask[i] = true;
                    }
                }
                for r in [0.5, 1.0, 1.5, 2.0, 2.5, 5.0_f32.sqrt(), 3.0, 4.2, 5.9, STENCIL_MAX] {
                    assert_eq!(dilate(&mask, w, h, r), dilate_by_distance(&mask, w, h, r), "dilate {w}x{h} {per_mille} {r}");
                    assert_eq!(erode(&mask, w, h, r), erode_by_distance(&mask, w, h, r), "erode {w}x{h} {per_mille} {r}");
                }
            }
        }
        // A NaN radius takes the distance route (the disc has no rows for it).
        let mask = vec![true; 12];
        assert_eq!(dilate(&mask, 4, 3, f32::NAN), dilate_by_distance(&mask, 4, 3, f32::NAN));
        assert_eq!(erode(&mask, 4, 3, f32::NAN), erode_by_distance(&mask, 4, 3, f32::NAN));
        assert_eq!(disc_rows(1.0), vec![(-1, 0), (0, 1), (1, 0)]);
        assert_eq!(disc_rows(2.0f32.sqrt()), vec![(-1, 1), (0, 1), (1, 1)]);
    }

    /// The block scan's boxes against a pixel-by-pixel scan (rows longer than a block, matches
    /// at block edges, empty rows, both values), and `row_into` against `at`.
    #[test]
    fn boxes_and_distance_rows_are_the_plain_scans() {
        let mut s = 3u64;
        for (w, h) in [(1, 1), (63, 4), (64, 3), (65, 5), (200, 7), (130, 9)] {
            for per_mille in [0, 2, 20, 500, 1000] {
                let mut mask: Vec<bool> = (0..w * h)
                    .map(|_| {
                        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        (s >> 33) % 1000 < per_mille
                    })
                    .collect();
                if w > 64 && per_mille == 2 {
                    (mask[63], mask[64], mask[w - 65]) = (true, true, true);
                }
                for value in [true, false] {
                    let hits: Vec<(usize, usize)> = (0..w * h).filter(|&i| mask[i] == value).map(|i| (i % w, i / w)).collect();
                    let want = (!hits.is_empty()).then(|| {
                        let (xs, ys) = (hits.iter().map(|p| p.0), hits.iter().map(|p| p.1));
                        (xs.clone().min().unwrap(), ys.clone().min().unwrap(), xs.max().unwrap() + 1, ys.max().unwrap() + 1)
                    });
                    assert_eq!(bbox(&mask, w, value), want, "{w}x{h} {per_mille} {value}");
                }
                if let Some(bb) = grown_bbox(&mask, w, h, 1.5) {
                    let near = BoxDistance::new(&mask, w, bb);
                    let mut row = vec![0.0; w];
                    for y in 0..h {
                        near.row_into(y, &mut row);
                        for (x, d) in row.iter().enumerate() {
                            assert_eq!(d.to_bits(), near.at(y * w + x).to_bits(), "{w}x{h} ({x}, {y})");
                        }
                    }
                }
            }
        }
    }

    /// The capped transform against the exact one: equal wherever the distance is at most the
    /// limit, above the limit elsewhere; seeded random masks, windows, both values.
    #[test]
    fn capped_distances_are_exact_up_to_the_limit() {
        let mut s = 11u64;
        for (w, h, per_mille) in [(1, 1, 500), (9, 1, 100), (1, 12, 100), (37, 23, 3), (40, 31, 50), (29, 40, 600), (16, 16, 0)] {
            let mask: Vec<bool> = (0..w * h)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 33) % 1000 < per_mille
                })
                .collect();
            for win in [(0, 0, w, h), (w / 4, h / 3, w - w / 5, h)] {
                for value in [true, false] {
                    let exact = sq_distance_window(&mask, w, win, value);
                    for limit in [0, 1, 2, 3, 6, 16] {
                        let capped = sq_distance_capped(&mask, w, win, value, limit);
                        for (i, (&e, &c)) in exact.iter().zip(&capped).enumerate() {
                            let ok = if e <= (limit * limit) as u32 { c == e } else { c > (limit * limit) as u32 };
                            assert!(ok, "{w}x{h} {win:?} {value} limit {limit} cell {i}: exact {e}, capped {c}");
                        }
                    }
                }
            }
        }
    }

    /// A box test against the dilated plane it stands for: every box of small random masks
    /// (edges of the frame included), radii below, at and between the integers.
    #[test]
    fn any_within_is_the_dilated_plane_read_over_the_box() {
        let mut s = 5u64;
        for (w, h, per_mille) in [(1, 1, 500), (7, 1, 150), (1, 9, 150), (13, 11, 20), (12, 10, 2), (9, 9, 0)] {
            let mask: Vec<bool> = (0..w * h)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (s >> 33) % 1000 < per_mille
                })
                .collect();
            for radius in [0.0, 1.0, 1.5, 2.0, 2.3, 3.0] {
                let grown = dilate(&mask, w, h, radius);
                for (y0, y1) in (0..h).flat_map(|y0| (y0..h).map(move |y1| (y0, y1))) {
                    for (x0, x1) in (0..w).flat_map(|x0| (x0..w).map(move |x1| (x0, x1))) {
                        let want = (y0..=y1).any(|y| (x0..=x1).any(|x| grown[y * w + x]));
                        let got = any_within(|i| mask[i], w, h, (x0, y0, x1, y1), radius);
                        assert_eq!(got, want, "{w}x{h} radius {radius} box {:?}", (x0, y0, x1, y1));
                    }
                }
            }
        }
    }

    #[test]
    fn morphology() {
        let (w, h) = (9, 9);
        let mut m = vec![false; w * h];
        m[4 * w + 4] = true;
        let d = dilate(&m, w, h, 2.0);
        assert_eq!(d.iter().filter(|&&v| v).count(), 13);
        assert_eq!(erode(&d, w, h, 1.0).iter().filter(|&&v| v).count(), 5);
        assert!(distance_to(&[false; 4], 2, 2).iter().all(|d| d.is_infinite()));
    }
}
