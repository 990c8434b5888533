//! Telea (2004) fast-marching inpainting.
//!
//! Follows OpenCV's `cv::inpaint(.., INPAINT_TELEA)` (modules/photo/src/inpaint.cpp) step by
//! step, because OpenCV is the oracle the tests compare against:
//!
//! 1. The known pixels 4-adjacent to the hole form the band (T = 0).
//! 2. A first march runs *outwards* from the band over the known pixels within Chebyshev
//!    distance `radius` of the hole; those distances are stored negated, so that T increases
//!    monotonically across the hole boundary and its gradient is meaningful there.
//! 3. The main march runs inwards. Each hole pixel gets its T from OpenCV's 4-neighbour eikonal
//!    solve the first time a neighbour is popped, and its value at that same moment from the
//!    known pixels (original or already filled) inside a disc of `radius`, weighted by
//!    `dir · dst · lev` (alignment with ∇T, inverse cube distance, similarity of T).
//!
//! Like OpenCV, a T value is computed once and never revised, and ties in the queue are popped
//! first-in first-out; both matter for reproducing OpenCV's fill order and thus its values.
//! The plain mean (no [`OpenCvCompat`]) has no such values to reproduce: it pops cells from
//! buckets 1/16 px of T wide (first-in first-out within one), which differs from OpenCV's order
//! only among cells whose T differ by less than that, and is cheaper (see `Buckets`). It
//! marches first, then fills the cells half a pixel of T at a time, each from the known
//! pixels and the earlier half pixels only, so that the cells of one such level are filled in
//! parallel (`March::fill_plain`).
//!
//! OpenCV's finish is not scale free: to the weighted mean it adds a "nudge", the component sum
//! of a unit vector built from image gradients (between -√2 and √2 code values), and integer
//! types round `value + 0.5`. [`OpenCvCompat`] reproduces that finish for data whose code value
//! is `unit` image units (checked bit-exact against OpenCV 4.12 in tests/telea_opencv.rs);
//! without it (the default) the fill is the plain weighted mean, which is what float data
//! (radiance, disparity) wants. Older OpenCV releases also added +0.5 to float results.

use crate::error::{Error, Result};
use crate::image::Image;
use std::cmp::Reverse;
use std::collections::BinaryHeap;

/// Options of the Telea fill.
#[derive(Clone, Copy, Debug)]
pub struct TeleaOptions {
    /// Neighbourhood radius in pixels (OpenCV's `inpaintRadius`). Like OpenCV, rounded to the
    /// nearest integer (ties to even) and clamped to `1..=100`. NaN or negative is an error.
    pub radius: f32,
    /// Stop the fast march once the distance to the known region exceeds this many pixels;
    /// pixels beyond it are not computed (they keep their input value). `None` = fill everything.
    /// A hole pixel 4-adjacent to a known pixel is at distance 1. NaN is an error.
    pub max_distance: Option<f32>,
    /// Reproduce OpenCV's per-type finish (offset, nudge, rounding; see [`OpenCvCompat`]).
    /// `None` (the default): the filled value is the plain weighted mean, scale independent.
    pub compat: Option<OpenCvCompat>,
}

impl TeleaOptions {
    /// The given radius, no distance limit, no OpenCV finish.
    pub fn new(radius: f32) -> Self {
        TeleaOptions { radius, max_distance: None, compat: None }
    }
}

/// How OpenCV finishes a filled value, in terms of the data's code values.
///
/// OpenCV computes `mean + nudge`, where `nudge ∈ [-√2, √2]` code values is the component sum of
/// a unit vector built from image gradients. For CV_8U / CV_16U it then stores
/// `round(mean + nudge + 0.5)` (ties to even) clamped to `0..=max_code`, and later pixels use the
/// rounded value; CV_32F stores `mean + nudge` as is. `unit` is the size of one code value in
/// image units: 8-bit data normalized to 0..1 uses `unit = 1/255`, raw codes use `unit = 1`.
/// With `max_code`, known values are read as the nearest code (as converting the image to that
/// integer type would); they are not modified.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OpenCvCompat {
    /// Size of one code value in image units (finite, > 0).
    pub unit: f32,
    /// Largest code; `Some` rounds and clamps like an integer type, `None` keeps the value (CV_32F).
    pub max_code: Option<f32>,
}

impl OpenCvCompat {
    /// `cv::inpaint` on `CV_8U`/`CV_8UC3` data; `unit` = one code value in image units.
    pub fn u8(unit: f32) -> Self {
        OpenCvCompat { unit, max_code: Some(255.0) }
    }
    /// `cv::inpaint` on `CV_16U` data; `unit` = one code value in image units.
    pub fn u16(unit: f32) -> Self {
        OpenCvCompat { unit, max_code: Some(65535.0) }
    }
    /// `cv::inpaint` on `CV_32F` data holding the image values as they are: the nudge is added in
    /// absolute units (up to ±1.41, huge for 0..1 data), no rounding.
    pub fn f32() -> Self {
        OpenCvCompat { unit: 1.0, max_code: None }
    }
}

/// Fills, in place, every pixel where `mask[y*width + x]` is true from the pixels where it is false.
/// Any channel count (RGB, single-channel depth/disparity), any value scale.
///
/// The fill uses OpenCV's fill order (to 1/16 px of T without `compat`), distance field and
/// weights, so it matches
/// cv2.inpaint(..., INPAINT_TELEA) up to OpenCV's per-type finish (a nudge of at most ±√2 code
/// values, `+0.5` and rounding for integer types), which `opts.compat` reproduces exactly when set.
/// Without it each filled value is a convex combination of known (or earlier filled) values: it
/// never leaves their range. Values are in the image's own units; distances in pixels.
///
/// Returns the number of pixels filled. Pixels that stay unfilled keep their input value: all of
/// them when the mask covers the whole image (nothing to fill from; OpenCV does the same), and
/// those beyond `max_distance`. Non-finite known values propagate into the fill.
///
/// Errors (the image is not modified): `mask.len() != width * height`, `img.data` not matching
/// its shape, a NaN or negative radius, a NaN `max_distance`, a `compat.unit` that is not finite
/// and positive, a negative or NaN `compat.max_code`, an image too large to index (more than 2³²
/// cells once padded by the radius).
///
/// Works on the window the fill can touch only (the hole's box, cut to `max_distance` beyond the
/// known pixels' box, grown by the radius; see `fill_window`), with the same result as on the
/// whole image: a small hole, or a short `max_distance` around a small known region, costs a
/// small fill however large the image. One pass over the mask finds the window; the march
/// reads and writes the image in place. Allocates O(window pixels) working memory once per call
/// (flags and distances over the window padded by the radius, the queue; with an integer
/// `compat`, also the window as codes in an image-sized buffer whose other pages are never
/// touched); nothing per pixel. The plain mean computes its weights on rayon's threads, ahead
/// of the weighted sums (same values on any number of threads); OpenCV's finishes run on the
/// calling thread. Several images with the same mask are filled by one march with
/// [`inpaint_telea_many`].
pub fn inpaint_telea(img: &mut Image, mask: &[bool], opts: TeleaOptions) -> Result<usize> {
    inpaint_telea_many(&mut [img], mask, opts)
}

/// [`inpaint_telea`] on several images of the same size (any channel counts) with the same
/// mask: one march (one distance field, fill order and weight computation) fills them all, each
/// exactly as [`inpaint_telea`] alone would (bit for bit). Returns the number of pixels filled
/// in each. Errors as [`inpaint_telea`] for each image, and when the images differ in size; then
/// no image is modified. Cost: one march, plus each image's weighted sums (about a tenth of the
/// march per channel on the 12.2 MP end-to-end scene).
pub fn inpaint_telea_many(imgs: &mut [&mut Image], mask: &[bool], opts: TeleaOptions) -> Result<usize> {
    let Some(first) = imgs.first() else { return Ok(0) };
    let (w, h) = (first.width, first.height);
    for img in imgs.iter() {
        check(img, mask, &opts)?;
        if (img.width, img.height) != (w, h) {
            return Err(Error::usage(format!("inpaint: images of {w}x{h} and {}x{} share one mask", img.width, img.height)));
        }
    }
    if w * h == 0 || !mask.contains(&true) {
        return Ok(0);
    }
    // `as` saturates (+inf becomes i64::MAX), so every radius lands in 1..=100 as in OpenCV.
    let radius = (opts.radius.round_ties_even() as i64).clamp(1, 100) as usize;
    let (gw, gh) = (w + 2 * radius, h + 2 * radius);
    if gw.checked_mul(gh).is_none_or(|n| n > u32::MAX as usize) {
        return Err(Error::usage(format!("inpaint: image of {w}x{h} is too large")));
    }
    let max_distance = opts.max_distance.unwrap_or(f32::INFINITY);
    let Some(win) = fill_window(mask, w, h, radius, max_distance) else { return Ok(0) };
    // Everything the march reads or writes lies inside the window: run it there.
    Ok(fill_all(imgs, mask, win, radius, max_distance, opts.compat))
}

/// The argument checks of [`inpaint_telea`] for one image.
fn check(img: &Image, mask: &[bool], opts: &TeleaOptions) -> Result<()> {
    let (w, h, c) = (img.width, img.height, img.channels);
    let pixels = w.checked_mul(h).ok_or_else(|| Error::usage("inpaint: image size overflows"))?;
    if mask.len() != pixels {
        return Err(Error::usage(format!("inpaint: mask has {} values but the image is {w}x{h} ({pixels} pixels)", mask.len())));
    }
    if pixels.checked_mul(c) != Some(img.data.len()) {
        return Err(Error::usage(format!("inpaint: image data has {} values, expected {w}x{h}x{c}", img.data.len())));
    }
    if opts.radius.is_nan() || opts.radius < 0.0 {
        return Err(Error::usage(format!("inpaint: radius must be >= 0, got {}", opts.radius)));
    }
    if opts.max_distance.is_some_and(f32::is_nan) {
        return Err(Error::usage("inpaint: max_distance is NaN"));
    }
    if let Some(cv) = opts.compat {
        if !(cv.unit.is_finite() && cv.unit > 0.0) {
            return Err(Error::usage(format!("inpaint: compat unit must be finite and > 0, got {}", cv.unit)));
        }
        if cv.max_code.is_some_and(|m| m.is_nan() || m < 0.0) {
            return Err(Error::usage("inpaint: compat max_code must be >= 0"));
        }
    }
    Ok(())
}

/// The part of the image a fill can touch, `(x0, y0, x1, y1)` with exclusive ends; None when
/// nothing can be filled (nothing is known, or no hole pixel is within reach of a known one).
///
/// A filled pixel is a hole pixel whose T is at most `max_distance`. The eikonal solve gives a
/// cell at least 1/√2 more than its smallest accepted 4-neighbour (OpenCV's two-sided solve
/// `(a + b + √(2 - (a-b)²))/2` is smallest, `a + 1/√2`, at `a = b`), and a hole pixel's
/// accepted neighbours are band cells (T = 0) or filled ones. So a filled pixel is within
/// `√2·max_distance` 4-steps of a known pixel: inside the known pixels' box grown by that
/// (1.5× here, for rounding), and inside the hole's box. Grown by `radius + 2`, the window
/// holds every cell the march reads for them (disc taps, one more for differences) and the
/// whole ring of known cells within `radius` of the hole that the outward march covers (a
/// ring cell is within `radius` of a band cell, which is known and next to a hole pixel of the
/// window), so the fill inside the window is the same, bit for bit, as on the whole image.
/// One pass over the mask.
fn fill_window(mask: &[bool], w: usize, h: usize, radius: usize, max_distance: f32) -> Option<(usize, usize, usize, usize)> {
    let (hole, known) = (super::mask::bbox(mask, w, true)?, super::mask::bbox(mask, w, false)?);
    let reach = if max_distance < (w + h) as f32 { (1.5 * max_distance.max(0.0)).ceil() as usize + 2 } else { w + h };
    let grow =
        |b: (usize, usize, usize, usize), m: usize| (b.0.saturating_sub(m), b.1.saturating_sub(m), (b.2 + m).min(w), (b.3 + m).min(h));
    let k = grow(known, reach);
    let r = (hole.0.max(k.0), hole.1.max(k.1), hole.2.min(k.2), hole.3.min(k.3));
    if r.0 >= r.2 || r.1 >= r.3 {
        // No hole pixel is close enough to a known one to be filled.
        return None;
    }
    Some(grow(r, radius + 2))
}

/// The march on the window `win` `(x0, y0, x1, y1)` (exclusive ends) of the images (already
/// checked, all of the mask's size); returns the number of pixels filled in each.
fn fill_all(
    imgs: &mut [&mut Image],
    mask: &[bool],
    win: (usize, usize, usize, usize),
    radius: usize,
    max_distance: f32,
    compat: Option<OpenCvCompat>,
) -> usize {
    let Some(first) = imgs.first() else { return 0 };
    if first.data.is_empty() || !mask.contains(&true) {
        return 0;
    }
    let mut m = March::new(mask, first.width, win, radius);
    m.outside_distances(radius);
    match compat {
        None => m.fill_plain(imgs, radius, max_distance, crate::cpu::has_avx2()),
        Some(cv) if cv.max_code.is_none() => m.fill::<CV_FLOAT>(imgs, radius, max_distance, cv),
        Some(cv) => m.fill::<CV_INT>(imgs, radius, max_distance, cv),
    }
}

// Cell states, as in OpenCV. VOID is the padding around the image: never unknown (so the eikonal
// solve and ∇T treat it like OpenCV's known border with T = FAR), never a source of colour.
const KNOWN: u8 = 0;
const BAND: u8 = 1;
const INSIDE: u8 = 2;
const VOID: u8 = 3;
/// OpenCV's initial T of every cell that is not band.
const FAR: f32 = 1.0e6;

// Kernel modes: the plain weighted mean, OpenCV's CV_32F finish, OpenCV's integer finish.
const PLAIN: u8 = 0;
const CV_FLOAT: u8 = 1;
const CV_INT: u8 = 2;

/// Min-queue of grid cells keyed by T, ties first-in first-out (OpenCV's sorted list behaves so).
/// T is never negative while queued, so its bit pattern orders like the value. The heap holds
/// one `u64` per entry, `T bits << 32 | push number`, and the cells sit in push order beside it:
/// half the bytes a `(key, cell)` heap moves per sift.
struct Queue {
    heap: BinaryHeap<Reverse<u64>>,
    cells: Vec<u32>,
}

impl Queue {
    fn with_capacity(n: usize) -> Self {
        Queue { heap: BinaryHeap::with_capacity(n), cells: Vec::with_capacity(n) }
    }
    fn push(&mut self, t: f32, cell: usize) {
        debug_assert!(t >= 0.0);
        // At most one push per cell per march and cells < 2^32, so the push number fits.
        let key = ((t.to_bits() as u64) << 32) | self.cells.len() as u64;
        self.cells.push(cell as u32);
        self.heap.push(Reverse(key));
    }
    fn pop(&mut self) -> Option<usize> {
        self.heap.pop().map(|Reverse(key)| self.cells[(key & u32::MAX as u64) as usize] as usize)
    }
}

/// Monotone bucket queue for the plain mean's march: T rounded down to 1/`BUCKETS_PER_PX` px,
/// first-in first-out within a bucket. A cell's T exceeds the cell it is reached from by at
/// least 1/√2, so pushes land in later buckets (a push below the current bucket, possible
/// only where `max_distance` left a cell unknown, goes to the current one). O(1) per push and
/// pop where the heap pays O(log n) cache misses, and cells of one bucket leave in the order
/// their parents did, which follows the front instead of the bits of T: the disc reads of
/// consecutive cells share cache lines. The order differs from OpenCV's only among cells whose
/// T differ by less than the bucket width.
struct Buckets {
    buckets: Vec<Vec<u32>>,
    cur: usize,
    pos: usize,
}

/// Buckets per pixel of T (see [`Buckets`]).
const BUCKETS_PER_PX: f32 = 16.0;

/// Buckets per level of the plain fill ([`March::fill_plain`]): half a pixel of T, less than
/// the least step from a cell to the one it is reached from (1/√2), so a cell's parent is
/// always of an earlier level.
const LEVEL_BUCKETS: usize = 8;

impl Buckets {
    fn new() -> Self {
        Buckets { buckets: vec![Vec::new()], cur: 0, pos: 0 }
    }
    /// Queues `cell` at T `t`; returns the bucket it went to.
    fn push(&mut self, t: f32, cell: usize) -> usize {
        // `as` saturates: a huge T gets the last bucket the window can need.
        let b = ((t * BUCKETS_PER_PX) as usize).max(self.cur);
        if b >= self.buckets.len() {
            self.buckets.resize_with(b + 1, Vec::new);
        }
        self.buckets[b].push(cell as u32);
        b
    }
    fn pop(&mut self) -> Option<usize> {
        loop {
            let bucket = self.buckets.get_mut(self.cur)?;
            if let Some(&c) = bucket.get(self.pos) {
                self.pos += 1;
                return Some(c as usize);
            }
            // Done with this bucket: free it and move on.
            *bucket = Vec::new();
            self.cur += 1;
            self.pos = 0;
        }
    }
}

/// Working state on a window of the image, padded by `pad` cells on each side.
struct March {
    /// The window's size.
    w: usize,
    h: usize,
    /// The window's first column and row in the image.
    x0: usize,
    y0: usize,
    pad: usize,
    gw: usize,
    flags: Vec<u8>,
    t: Vec<f32>,
    /// Band cells in raster order (both marches start from them).
    band: Vec<u32>,
}

/// The disc of taps around a filled pixel, precomputed once per call: its cells in OpenCV's
/// tap order (row by row, left to right) as one run of consecutive grid cells per row, the
/// centre included (it is unknown while its value is computed, so it never counts). Per-cell
/// values are kept in separate arrays so that the weight loop runs on whole rows (SIMD).
struct Disc {
    /// Per disc row: the grid offset of its first cell and its number of cells.
    rows: Vec<(isize, usize)>,
    /// Per cell: (dy, dx), the offset from the centre.
    offsets: Vec<(isize, isize)>,
    /// Per cell: offset in the image, pixels (`dy · stride + dx`).
    pixel: Vec<isize>,
    /// Per cell: r = p - q (OpenCV's `r`), as floats.
    rx: Vec<f32>,
    /// See `rx`.
    ry: Vec<f32>,
    /// Per cell: 1 / |r|³ as OpenCV's 3-channel path computes it (the root in double; 0 at the
    /// centre).
    dst3: Vec<f32>,
    /// Per cell: 1 / |r|³ as OpenCV's 1-channel path computes it (the root in float).
    dst1: Vec<f32>,
}

impl Disc {
    /// The disc of `radius` on a grid `gw` cells wide, for images `stride` pixels wide.
    fn new(radius: usize, gw: usize, stride: usize) -> Self {
        let r = radius as isize;
        let mut d = Disc {
            rows: Vec::new(),
            offsets: Vec::new(),
            pixel: Vec::new(),
            rx: Vec::new(),
            ry: Vec::new(),
            dst3: Vec::new(),
            dst1: Vec::new(),
        };
        for dy in -r..=r {
            // The row's half-width: the largest dx with dx² + dy² ≤ r².
            let hw = (0..=r).rev().find(|dx| dx * dx + dy * dy <= r * r).expect("dx = 0 fits");
            d.rows.push((dy * gw as isize - hw, (2 * hw + 1) as usize));
            for dx in -hw..=hw {
                let (rx, ry) = (-dx as f32, -dy as f32);
                let len = rx * rx + ry * ry;
                let centre = len == 0.0;
                d.offsets.push((dy, dx));
                d.pixel.push(dy * stride as isize + dx);
                d.rx.push(rx);
                d.ry.push(ry);
                d.dst3.push(if centre { 0.0 } else { (1.0 / (len as f64 * (len as f64).sqrt())) as f32 });
                d.dst1.push(if centre { 0.0 } else { (1.0 / (len * len.sqrt()) as f64) as f32 });
            }
        }
        d
    }

    /// Number of cells.
    fn len(&self) -> usize {
        self.rx.len()
    }

    /// Every cell's weight for the pixel at grid cell `n` (T `tn`, ∇T `g`) into `out`: OpenCV's
    /// `|dst · lev · dir|` for a known cell (`keys[cell] < below`: KNOWN or BAND flags below
    /// INSIDE, or reached before `n` in the plain march's order), `-0.0` for the others
    /// (unknown, outside the image, the centre). A known weight is an absolute value, so its sign bit is
    /// clear: the sign marks the unknown cells, and `-0.0` adds nothing to any sum, bit for bit.
    /// The rows run without branches, so the compiler vectorizes them (OpenCV's ordering of the
    /// products is kept: the same bits as one tap at a time).
    #[inline(always)]
    fn weights<const MODE: u8, K: Copy + PartialOrd>(
        &self,
        dst: &[f32],
        (keys, below, t): (&[K], K, &[f32]),
        n: usize,
        (gtx, gty): (f32, f32),
        out: &mut [f32],
    ) {
        let tn = t[n];
        let mut k = 0;
        for &(off, len) in &self.rows {
            let base = (n as isize + off) as usize;
            let (fl, tt) = (&keys[base..base + len], &t[base..base + len]);
            let (rx, ry, dst) = (&self.rx[k..k + len], &self.ry[k..k + len], &dst[k..k + len]);
            for (j, o) in out[k..k + len].iter_mut().enumerate() {
                let dt = (tt[j] - tn).abs();
                // OpenCV divides in double; the plain mean has no need to be bit-exact.
                let lev = if MODE == PLAIN { 1.0 / (1.0 + dt) } else { (1.0 / (1.0 + dt as f64)) as f32 };
                let dir = rx[j] * gtx + ry[j] * gty;
                let dir = if (dir.abs() as f64) <= 0.01 { 1.0e-6 } else { dir };
                let wgt = (dst[j] * lev * dir).abs();
                *o = if fl[j] < below { wgt } else { -0.0 };
            }
            k += len;
        }
    }
}

/// Round half to even without a libm call (baseline x86-64 has no rounding instruction):
/// adding and subtracting 1.5·2²³ leaves the nearest integer under IEEE round-to-nearest-even.
#[inline(always)]
fn round_even_f32(v: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0;
    if v.abs() < 4_194_304.0 { (v + MAGIC) - MAGIC } else { v.round_ties_even() }
}

/// [`round_even_f32`] for f64 (1.5·2⁵²).
#[inline(always)]
fn round_even_f64(v: f64) -> f64 {
    const MAGIC: f64 = 6_755_399_441_055_744.0;
    if v.abs() < 2_251_799_813_685_248.0 { (v + MAGIC) - MAGIC } else { v.round_ties_even() }
}

#[inline]
fn solve(flags: &[u8], t: &[f32], a: usize, b: usize) -> f32 {
    let (ta, tb) = (t[a] as f64, t[b] as f64);
    let sol = match (flags[a] != INSIDE, flags[b] != INSIDE) {
        (true, true) => {
            let d = ta - tb;
            if d.abs() >= 1.0 { 1.0 + ta.min(tb) } else { (ta + tb + (2.0 - d * d).sqrt()) * 0.5 }
        }
        (true, false) => 1.0 + ta,
        (false, true) => 1.0 + tb,
        (false, false) => 1.0 + ta.min(tb),
    };
    sol as f32
}

/// T at `n` from its 4 neighbours (OpenCV's four one-quadrant solves, smallest wins).
#[inline]
fn eikonal(flags: &[u8], t: &[f32], n: usize, gw: usize) -> f32 {
    let (up, down, left, right) = (n - gw, n + gw, n - 1, n + 1);
    let a = solve(flags, t, up, left).min(solve(flags, t, down, left));
    let b = solve(flags, t, up, right).min(solve(flags, t, down, right));
    a.min(b)
}

/// One-sided or central difference of `v` along one axis, using only non-unknown neighbours.
#[inline]
fn known_diff(known: impl Fn(usize) -> bool, t: &[f32], n: usize, step: usize) -> f32 {
    match (known(n + step), known(n - step)) {
        (true, true) => (t[n + step] - t[n - step]) * 0.5,
        (true, false) => t[n + step] - t[n],
        (false, true) => t[n] - t[n - step],
        (false, false) => 0.0,
    }
}

impl March {
    /// The grid of the window `(x0, y0, x1, y1)` of an image `width` pixels wide, from the
    /// image's `mask`.
    fn new(mask: &[bool], width: usize, (x0, y0, x1, y1): (usize, usize, usize, usize), pad: usize) -> Self {
        use rayon::prelude::*;
        let (w, h) = (x1 - x0, y1 - y0);
        let gw = w + 2 * pad;
        let gh = h + 2 * pad;
        let mut flags = vec![VOID; gw * gh];
        flags[pad * gw..(pad + h) * gw].par_chunks_mut(gw).enumerate().for_each(|(y, row)| {
            for (f, &m) in row[pad..pad + w].iter_mut().zip(&mask[(y0 + y) * width + x0..][..w]) {
                *f = if m { INSIDE } else { KNOWN };
            }
        });
        // The band: known cells with an unknown 4-neighbour, in raster order. Each row's test
        // runs on whole rows without branches (a few ms at 12 MP, where a cell at a time took
        // tens); marking a cell BAND changes no other cell's test.
        let rows: Vec<Vec<u32>> = (pad..pad + h)
            .into_par_iter()
            .map(|gy| {
                let row = |y: usize| &flags[y * gw..(y + 1) * gw];
                let (up, mid, down) = (row(gy - 1), row(gy), row(gy + 1));
                let mut is_band = vec![false; gw - 2];
                for (((((b, &c), &u), &d), &l), &r) in
                    is_band.iter_mut().zip(&mid[1..]).zip(&up[1..]).zip(&down[1..]).zip(&mid[..gw - 2]).zip(&mid[2..])
                {
                    *b = (c == KNOWN) & ((u == INSIDE) | (d == INSIDE) | (l == INSIDE) | (r == INSIDE));
                }
                is_band.iter().enumerate().filter(|(_, b)| **b).map(|(x, _)| (gy * gw + x + 1) as u32).collect()
            })
            .collect();
        let band: Vec<u32> = rows.concat();
        let mut t = vec![FAR; gw * gh];
        for &n in &band {
            flags[n as usize] = BAND;
            t[n as usize] = 0.0;
        }
        March { w, h, x0, y0, pad, gw, flags, t, band }
    }

    /// The outward march: negated distances from the band over the known pixels within
    /// Chebyshev distance `radius` of the hole (OpenCV's dilation by a square).
    fn outside_distances(&mut self, radius: usize) {
        let (w, h, pad, gw) = (self.w, self.h, self.pad, self.gw);
        // The ring: known cells within Chebyshev distance `radius` of an unknown cell, which
        // become INSIDE in a separate state grid. Per row, a window OR of the unknown cells
        // along the row, then along the column, on whole rows without branches (the padding,
        // `pad ≥ radius` cells of VOID, keeps every window in the grid).
        use rayon::prelude::*;
        debug_assert!(pad >= radius);
        let near: Vec<u8> = (pad..pad + h)
            .into_par_iter()
            .flat_map_iter(|gy| {
                let row = &self.flags[gy * gw..(gy + 1) * gw];
                let inside: Vec<u8> = row.iter().map(|&f| u8::from(f == INSIDE)).collect();
                let mut out = vec![0u8; w];
                for k in pad - radius..=pad + radius {
                    for (o, &v) in out.iter_mut().zip(&inside[k..k + w]) {
                        *o |= v;
                    }
                }
                out
            })
            .collect();
        let flags = &self.flags;
        let mut state = vec![KNOWN; flags.len()];
        state[pad * gw..(pad + h) * gw].par_chunks_mut(gw).enumerate().for_each(|(y, srow)| {
            let mut col = vec![0u8; w];
            for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                for (c, &v) in col.iter_mut().zip(&near[yy * w..(yy + 1) * w]) {
                    *c |= v;
                }
            }
            let frow = &flags[(y + pad) * gw + pad..][..w];
            for ((s, &c), &f) in srow[pad..pad + w].iter_mut().zip(&col).zip(frow) {
                *s = if (c != 0) & (f == KNOWN) { INSIDE } else { KNOWN };
            }
        });
        drop(near);

        let mut queue = Queue::with_capacity(self.band.len() * 2);
        for &n in &self.band {
            queue.push(0.0, n as usize);
        }
        let mut done = Vec::with_capacity(self.band.len() * 2);
        while let Some(p) = queue.pop() {
            // Popped cells must no longer count as unknown; any value other than INSIDE works.
            state[p] = KNOWN;
            done.push(p as u32);
            for q in [p - gw, p - 1, p + gw, p + 1] {
                if state[q] == INSIDE {
                    let d = eikonal(&state, &self.t, q, gw);
                    self.t[q] = d;
                    state[q] = BAND;
                    queue.push(d, q);
                }
            }
        }
        for &p in &done {
            self.t[p as usize] = -self.t[p as usize];
        }
    }

    /// The plain weighted mean's inward march that fills the hole of every image of `imgs` (the
    /// image the window lies in; all of one size); returns the number of pixels filled (in each).
    ///
    /// The march runs first, alone (cheap: T and the order); each reached cell's level is the
    /// half pixel of T it was queued in ([`LEVEL_BUCKETS`]). A cell is then filled from the
    /// known pixels and the cells of earlier levels in its disc, so the cells of one level
    /// need none of each other's values and are filled in parallel, level after level:
    /// both the weights and the weighted sums use every core (the sums were one sequential
    /// pass in march order, the stage's serial part at 16 threads; issue 39). A cell of the
    /// same level lies along the front, where Telea's direction factor already weighs it
    /// almost nothing. Each value depends on neither the thread count nor the CPU's vector
    /// width.
    fn fill_plain(&mut self, imgs: &mut [&mut Image], radius: usize, max_distance: f32, avx2: bool) -> usize {
        use rayon::prelude::*;
        /// Cells per parallel task; a level with at most this many runs on the calling thread.
        const RUN: usize = 64;
        let (pad, gw) = (self.pad, self.gw);
        let iw = imgs[0].width;
        // Each cell's level: 0 for the known cells, 1 + its bucket for the reached ones, MAX for
        // the padding and the cells never reached.
        let mut level: Vec<u32> = self.flags.iter().map(|&f| if f < INSIDE { 0 } else { u32::MAX }).collect();
        let mut order: Vec<u32> = Vec::new();
        let mut queue = Buckets::new();
        for &n in &self.band {
            queue.push(0.0, n as usize);
        }
        while let Some(p) = queue.pop() {
            reach_from(&mut self.flags, &mut self.t, gw, p, max_distance, |_, _, q, d| {
                let b = queue.push(d, q);
                level[q] = (b / LEVEL_BUCKETS) as u32 + 1;
                order.push(q as u32);
            });
        }
        // The cells grouped by level (stable: march order within a level).
        let levels = order.iter().map(|&q| level[q as usize] as usize).max().unwrap_or(0) + 1;
        let mut start = vec![0usize; levels + 1];
        for &q in &order {
            start[level[q as usize] as usize + 1] += 1;
        }
        for l in 0..levels {
            start[l + 1] += start[l];
        }
        let mut grouped = vec![0u32; order.len()];
        let mut at = start.clone();
        for &q in &order {
            let l = level[q as usize] as usize;
            grouped[at[l]] = q;
            at[l] += 1;
        }
        drop(order);
        let disc = Disc::new(radius, gw, iw);
        let taps = disc.len();
        let ctx = PlainWeights { flags: &self.flags, t: &self.t, reached: &level, disc: &disc, gw };
        let channels: usize = imgs.iter().map(|im| im.channels).sum();
        let centre_of = |n: usize| (n / gw - pad + self.y0) * iw + (n % gw - pad + self.x0);
        // A run of cells' values (all images' channels, cell after cell) from the images as
        // they stand: every tap read is known or of an earlier level, already written.
        let values = |imgs: &[&mut Image], cells: &[u32], out: &mut [f32], scratch: &mut Scratch| {
            let (wts, nums, count, all) = (&mut scratch.0, &mut scratch.1, &mut scratch.2, &mut scratch.3);
            ctx.weigh(avx2, cells, (&mut wts[..cells.len() * taps], &mut nums[..cells.len() * taps], &mut count[..cells.len()]), all);
            for ((i, &n), out) in cells.iter().enumerate().zip(out.chunks_exact_mut(channels)) {
                let centre = centre_of(n as usize);
                let known = (&wts[i * taps..][..count[i]], &nums[i * taps..][..count[i]]);
                match imgs {
                    // The background fill's colour and disparity: one pass over the taps.
                    [rgb, one] if (rgb.channels, one.channels) == (3, 1) => mean_rgb_one(&disc, (&rgb.data, &one.data), known, centre, out),
                    _ => {
                        let mut c0 = 0;
                        for img in imgs.iter() {
                            mean(&disc, &img.data, img.channels, known, centre, &mut out[c0..c0 + img.channels]);
                            c0 += img.channels;
                        }
                    }
                }
            }
        };
        let scratch = || -> Scratch { (vec![0.0f32; RUN * taps], vec![0u32; RUN * taps], vec![0usize; RUN], vec![0.0f32; taps]) };
        let mut out = Vec::new();
        let mut own = scratch();
        for l in 1..levels {
            let cells = &grouped[start[l]..start[l + 1]];
            if cells.is_empty() {
                continue;
            }
            out.resize(cells.len() * channels, 0.0);
            if cells.len() <= RUN {
                values(imgs, cells, &mut out, &mut own);
            } else {
                let shared: &[&mut Image] = imgs;
                out.par_chunks_mut(RUN * channels)
                    .zip(cells.par_chunks(RUN))
                    .for_each_init(scratch, |sc, (out, cells)| values(shared, cells, out, sc));
            }
            for (&n, v) in cells.iter().zip(out.chunks_exact(channels)) {
                let centre = centre_of(n as usize);
                let mut c0 = 0;
                for img in imgs.iter_mut() {
                    let ch = img.channels;
                    img.data[centre * ch..(centre + 1) * ch].copy_from_slice(&v[c0..c0 + ch]);
                    c0 += ch;
                }
            }
        }
        grouped.len()
    }

    /// OpenCV's inward march (`MODE` one of its finishes) that fills the hole of every image of
    /// `imgs` (the image the window lies in; all of one size); returns the number of pixels
    /// filled (in each).
    fn fill<const MODE: u8>(&mut self, imgs: &mut [&mut Image], radius: usize, max_distance: f32, cv: OpenCvCompat) -> usize {
        let (pad, gw, r) = (self.pad, self.gw, radius as isize);
        let (iw, ih) = (imgs[0].width, imgs[0].height);
        let disc = Disc::new(radius, gw, iw);
        // Per-pixel scratch, reused: every cell's weight for each path OpenCV takes (3 channels or
        // not, see `Disc::dst3`; computed only when some image needs it), the known cells.
        let need = |three: bool| imgs.iter().any(|im| (im.channels == 3) == three);
        let (need3, need1) = (need(true), need(false));
        let mut weights3 = vec![0.0f32; if need3 { disc.len() } else { 0 }];
        let mut weights1 = vec![0.0f32; if need1 { disc.len() } else { 0 }];
        let mut known = vec![0u32; disc.len()];
        let mut grads = Vec::with_capacity(disc.len());
        let mut queue = Queue::with_capacity(self.band.len() + self.flags.len() / 8);
        for &n in &self.band {
            queue.push(0.0, n as usize);
        }
        // OpenCV's integer path works on codes: keep the window as the nearest codes (what
        // converting it to that type gives), so that rounding ties fall exactly as there. The
        // buffer has the image's size; its pages outside the window are never touched.
        let inv_unit = 1.0 / cv.unit;
        let mut codes: Vec<Vec<f32>> = Vec::new();
        if MODE == CV_INT {
            for img in imgs.iter() {
                let ch = img.channels;
                let mut c = vec![0.0f32; img.data.len()];
                for y in self.y0..self.y0 + self.h {
                    let row = (y * iw + self.x0) * ch..(y * iw + self.x0 + self.w) * ch;
                    for (o, &v) in c[row.clone()].iter_mut().zip(&img.data[row]) {
                        *o = round_even_f32(v * inv_unit);
                    }
                }
                codes.push(c);
            }
        }
        let mut filled = 0;
        let (x0, y0) = (self.x0, self.y0);
        while let Some(p) = queue.pop() {
            reach_from(&mut self.flags, &mut self.t, gw, p, max_distance, |flags, t, q, d| {
                // Image coordinates of the cell.
                let (y, x) = ((q / gw - pad + y0) as isize, (q % gw - pad + x0) as isize);
                let ctx = Ctx { flags, t, disc: &disc, gw, w: iw, h: ih, cv };
                let m = ctx.known_weights::<MODE>(q, (&mut weights3, &mut weights1), &mut known);
                // Sources on the image's outer rows/columns need OpenCV's edge handling.
                let interior = y > r && y + r + 1 < ih as isize && x > r && x + r + 1 < iw as isize;
                for (i, img) in imgs.iter_mut().enumerate() {
                    let ch = img.channels;
                    let buf = if MODE == CV_INT { &mut codes[i][..] } else { &mut img.data[..] };
                    let wts = if ch == 3 { &weights3[..] } else { &weights1[..] };
                    if interior {
                        ctx.pixel::<MODE, false>(buf, ch, (wts, &known[..m]), &mut grads, q, y, x);
                    } else {
                        ctx.pixel::<MODE, true>(buf, ch, (wts, &known[..m]), &mut grads, q, y, x);
                    }
                    if MODE == CV_INT {
                        let j = (y as usize * iw + x as usize) * ch;
                        for (v, &code) in img.data[j..j + ch].iter_mut().zip(&codes[i][j..j + ch]) {
                            *v = code * cv.unit;
                        }
                    }
                }
                filled += 1;
                queue.push(d, q);
            });
        }
        filled
    }
}

/// One step of the inward march: popped cell `p` becomes known, and each of its unknown
/// 4-neighbours within `max_distance` gets its T (OpenCV's eikonal solve) and is handed to
/// `reached` (flags, T, cell, its T) before it joins the band; a neighbour beyond the limit is
/// left unknown (a later neighbour may still reach it within the limit).
#[inline(always)]
fn reach_from(flags: &mut [u8], t: &mut [f32], gw: usize, p: usize, max_distance: f32, mut reached: impl FnMut(&[u8], &[f32], usize, f32)) {
    flags[p] = KNOWN;
    for q in [p - gw, p - 1, p + gw, p + 1] {
        if flags[q] != INSIDE {
            continue;
        }
        let d = eikonal(flags, t, q, gw);
        if d > max_distance {
            continue;
        }
        t[q] = d;
        reached(flags, t, q, d);
        flags[q] = BAND;
    }
}

/// Per-task scratch of [`March::fill_plain`]: a run's weights, disc cell numbers and counts
/// of known taps, and one disc of weights.
type Scratch = (Vec<f32>, Vec<u32>, Vec<usize>, Vec<f32>);

/// What [`March::fill_plain`] weighs a cell's disc with: the march's flags and T, when each
/// cell was reached, the disc.
struct PlainWeights<'a> {
    flags: &'a [u8],
    t: &'a [f32],
    reached: &'a [u32],
    disc: &'a Disc,
    gw: usize,
}

impl PlainWeights<'_> {
    /// Each cell's known taps (weights, disc cell numbers) into its slot of `taps` entries of
    /// `wts` and `nums`, and their number into `count`; `all` is scratch of `taps` entries.
    /// With `avx2` (the CPU has it), the same arithmetic on wider vectors: the same bits.
    fn weigh(&self, avx2: bool, cells: &[u32], out: (&mut [f32], &mut [u32], &mut [usize]), all: &mut [f32]) {
        crate::cpu::with_avx2(avx2, || self.weigh_cells(cells, out, all))
    }

    #[inline(always)]
    fn weigh_cells(&self, cells: &[u32], (wts, nums, count): (&mut [f32], &mut [u32], &mut [usize]), all: &mut [f32]) {
        let (flags, t, reached, disc) = (self.flags, self.t, self.reached, self.disc);
        let taps = all.len();
        for (((wts, nums), count), &n) in wts.chunks_exact_mut(taps).zip(nums.chunks_exact_mut(taps)).zip(count.iter_mut()).zip(cells) {
            let n = n as usize;
            let before = reached[n];
            // Known when `n` was reached: the padding counts for T's differences (as OpenCV's
            // border does), never as a source.
            let settled = |q: usize| flags[q] == VOID || reached[q] < before;
            let g = (known_diff(settled, t, n, 1), known_diff(settled, t, n, self.gw));
            // One table (the root in double) serves every channel count: the disc is weighed
            // once for all images.
            disc.weights::<PLAIN, u32>(&disc.dst3, (reached, before, t), n, g, all);
            let mut m = 0;
            for (k, &wgt) in all.iter().enumerate() {
                // Branchless compaction of the known taps.
                wts[m] = wgt;
                nums[m] = k as u32;
                m += !wgt.is_sign_negative() as usize;
            }
            *count = m;
        }
    }
}

/// The plain weighted mean of pixel `centre` of `data` (`ch` channels) from its `known` taps
/// of `disc` (their weights and disc cell numbers), written into `out` (`ch` values). The sums
/// run over the taps in disc order, all channels and the weight total in one pass.
#[inline(always)]
fn mean(disc: &Disc, data: &[f32], ch: usize, (weights, known): (&[f32], &[u32]), centre: usize, out: &mut [f32]) {
    let centre = centre * ch;
    // A known tap lies inside the image, so its plain offset is always valid.
    let src = |k: u32| (centre as isize + disc.pixel[k as usize] * ch as isize) as usize;
    let mut s = 1.0e-20f32;
    if ch == 3 {
        let (mut r, mut g, mut b) = (0.0f32, 0.0f32, 0.0f32);
        for (&wgt, &k) in weights.iter().zip(known) {
            let i = src(k);
            s += wgt;
            r += wgt * data[i];
            g += wgt * data[i + 1];
            b += wgt * data[i + 2];
        }
        out.copy_from_slice(&[r / s, g / s, b / s]);
    } else if ch == 1 {
        let mut v = 0.0f32;
        for (&wgt, &k) in weights.iter().zip(known) {
            s += wgt;
            v += wgt * data[src(k)];
        }
        out[0] = v / s;
    } else {
        for &wgt in weights {
            s += wgt;
        }
        for c in 0..ch {
            let mut v = 0.0f32;
            for (&wgt, &k) in weights.iter().zip(known) {
                v += wgt * data[src(k) + c];
            }
            out[c] = v / s;
        }
    }
}

/// [`mean`] of a 3-channel and a 1-channel image at once into `out` (R, G, B, then the one
/// channel): the same sums, in the same order, from one pass over the taps, so the same bits
/// as two calls.
#[inline(always)]
fn mean_rgb_one(disc: &Disc, (rgb, one): (&[f32], &[f32]), (weights, known): (&[f32], &[u32]), centre: usize, out: &mut [f32]) {
    let mut s = 1.0e-20f32;
    let (mut r, mut g, mut b, mut v) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for (&wgt, &k) in weights.iter().zip(known) {
        // A known tap lies inside the image, so its offset is always valid.
        let j = (centre as isize + disc.pixel[k as usize]) as usize;
        let i = 3 * j;
        s += wgt;
        r += wgt * rgb[i];
        g += wgt * rgb[i + 1];
        b += wgt * rgb[i + 2];
        v += wgt * one[j];
    }
    out.copy_from_slice(&[r / s, g / s, b / s, v / s]);
}

mod cell;
use cell::Ctx;

#[cfg(test)]
mod tests;
