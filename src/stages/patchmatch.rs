//! Exemplar-based colour fill behind the foreground (`[inpaint] method = "patchmatch"`).
//!
//! Telea ([`super::inpaint`]) continues colours smoothly into the hole: right for gradients,
//! a blur for texture. This fill copies texture instead: every hole pixel gets a weighted vote
//! of the visible background patches that best match the patches around it (Wexler, Shechtman
//! & Irani 2007, "Space-time completion of video"), with the patch correspondences found by a
//! PatchMatch nearest-neighbour field (Barnes et al. 2009: random init, propagation, random
//! search), coarse to fine. Written here from the papers: no maintained Rust crate implements
//! it, and the pipeline needs its own masks, reach limit and depth term.
//!
//! - **Where**: the colour holes of [`super::background::FillRegion::colour_holes`] (kept
//!   highlights included, so no patch touching one is ever a source), restricted to the pixels
//!   within `reach` (Euclidean, pixels) of the visible background: deeper ones cannot be seen
//!   through any blur and keep their input. The work runs on the holes' bounding box grown by
//!   a context margin, so its cost follows the reachable hole, not the photo.
//! - **Sources**: patches lying entirely on visible background (no hole, no highlight) inside
//!   that window. The patch distance adds a depth term, `depth_weight · n · (ΔD)²` between the
//!   (Telea-filled) disparity at the target and the source's, so the background behind a
//!   subject continues the surface at its depth rather than a nearer or farther one.
//! - **Start**: Telea's fill, box-averaged down to the coarsest level; each finer level starts
//!   from the coarser field, upsampled.
//! - **Determinism**: each search round reads the previous field and writes a new one
//!   (jump-flood style propagation at steps 4, 2, 1), and every random draw is a hash of
//!   (seed, level, iteration, round, pixel), so the result is bit-identical for any thread
//!   count. Rounds and votes run in parallel with rayon.
//!
//! Colours are compared as √(linear) (roughly perceptual, and an HDR value does not dominate a
//! patch) and voted in linear light, so the fill stays a convex combination of visible
//! background values.

use crate::error::{Error, Result};
use crate::image::Image;
use rayon::prelude::*;

/// Options of the exemplar fill. Costs scale with the field's size `n` (the reachable hole
/// grown by half a patch) per level: a searched level costs about
/// `n · iterations · 3 rounds · (4 + log2(level side)) · 3·patch²` multiply-adds (less with the
/// early exit on partial distances), a polished one `n · 8 · 3·patch²`; votes `n · patch²`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchMatchOptions {
    /// Patch side, pixels (odd, 3 … 15).
    pub patch: usize,
    /// Search-and-vote iterations per level (3 propagation rounds, at steps 4, 2, 1, each with a
    /// random search over the whole level). On a 72x64 stripe test 3 left a seam of wrong
    /// phase (RMSE 0.04), 4 converged (1e-7).
    pub iterations: usize,
    /// Levels whose field has more entries than this are only polished: the coarser field,
    /// upsampled, then one round of propagation at step 1 and random search within ±4 pixels,
    /// and a vote; the texture is still copied at full resolution. At 12.2 MP (0.61 M pixels
    /// within reach) full search at every level cost 43 s; the bench's 256x256 scenes stay
    /// below the limit (searched at every level).
    pub search_entries: usize,
    /// Weight of the disparity term, per patch value: a disparity difference ΔD (normalized
    /// units) costs as much as a √-colour difference of `√depth_weight · ΔD` in every value.
    pub depth_weight: f32,
    /// Seed of the random init and search.
    pub seed: u64,
    /// Extra context around the holes' bounding box where sources are sought, pixels at full
    /// resolution (at least 4 patches).
    pub context: usize,
}

impl Default for PatchMatchOptions {
    fn default() -> Self {
        PatchMatchOptions { patch: 7, iterations: 4, search_entries: 1 << 16, depth_weight: 1.0, seed: 0x5eed, context: 64 }
    }
}

/// What the fill did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PatchMatchStats {
    /// Hole pixels within reach, voted from patches.
    pub filled: usize,
    /// Pyramid levels used (0 when nothing was filled: no hole within reach, or no source).
    pub levels: usize,
    /// Valid source patches at full resolution.
    pub sources: usize,
}

/// Replaces the colour of the hole pixels of `rgb` (linear RGB) within `reach` pixels of the
/// non-hole pixels by an exemplar fill; `rgb` holds the start (Telea's fill) and is modified
/// only there. `disparity` (1 channel, the same size, filled behind the hole) drives the depth
/// term. With no hole within reach, or no patch of visible background to copy, `rgb` is left
/// as it is.
///
/// Errors: sizes or channel counts that do not match, an even or out-of-range patch size, a
/// NaN reach (usage errors naming the parameter).
///
/// Allocates a few planes over the working window (pyramid ≈ 4/3 of it) and the field over the
/// reachable hole grown by half a patch; threads: rayon (result independent of their count).
pub fn fill(rgb: &mut Image, holes: &[bool], disparity: &Image, reach: f32, opts: &PatchMatchOptions) -> Result<PatchMatchStats> {
    let (w, h) = (rgb.width, rgb.height);
    if rgb.channels != 3 || holes.len() != w * h || disparity.width != w || disparity.height != h || disparity.channels != 1 {
        return Err(Error::usage(format!(
            "patchmatch: image {w}x{h}x{}, mask of {} values and disparity {}x{}x{} do not match",
            rgb.channels,
            holes.len(),
            disparity.width,
            disparity.height,
            disparity.channels
        )));
    }
    if opts.patch.is_multiple_of(2) || !(3..=15).contains(&opts.patch) {
        return Err(Error::usage(format!("inpaint.patch: must be odd in 3..=15, got {}", opts.patch)));
    }
    if reach.is_nan() {
        return Err(Error::usage("inpaint: reach is NaN"));
    }
    let Some(win) = window(holes, w, h, reach, opts) else { return Ok(PatchMatchStats::default()) };
    let base = Level::base(rgb, holes, disparity, reach, win);
    let filled = base.target.iter().filter(|&&t| t).count();
    let r = opts.patch / 2;
    let mut pyramid = vec![base.with_sources(r)];
    let mut sources = pyramid[0].valid.iter().filter(|&&v| v).count();
    if filled == 0 || sources == 0 {
        return Ok(PatchMatchStats { filled: 0, levels: 0, sources });
    }
    // Coarser levels while the hole is still more than a patch deep and the window holds enough
    // whole source patches to choose from.
    let deepest = pyramid[0].deepest;
    while deepest / (1 << pyramid.len()) as f32 > r as f32 {
        let coarse = pyramid.last().expect("level").down().with_sources(r);
        if coarse.w.min(coarse.h) < 2 * opts.patch || coarse.valid.iter().filter(|&&v| v).count() < MIN_SOURCES {
            break;
        }
        pyramid.push(coarse);
    }
    let levels = pyramid.len();
    let mut field: Option<Field> = None;
    for l in (0..levels).rev() {
        let lv = &mut pyramid[l];
        let mut f = match &field {
            None => Field::random(lv, r, opts.seed),
            Some(parent) => {
                let f = Field::upsample(lv, r, parent, opts.seed ^ l as u64);
                lv.vote(&f, r);
                f
            }
        };
        let polish = field.is_some() && f.at.len() > opts.search_entries;
        let (iters, steps, max_radius): (usize, &[usize], usize) =
            if polish { (1, &[1], POLISH_RADIUS) } else { (opts.iterations, &STEPS, lv.w.max(lv.h)) };
        for it in 0..iters {
            f.refresh(lv, r, opts.depth_weight);
            for (round, &step) in steps.iter().enumerate() {
                let salt = opts.seed ^ ((l as u64) << 56) ^ ((it as u64) << 48) ^ ((round as u64) << 40);
                f = f.search(lv, r, opts.depth_weight, (step, max_radius), salt);
            }
            lv.vote(&f, r);
        }
        field = Some(f);
    }
    sources = pyramid[0].valid.iter().filter(|&&v| v).count();
    pyramid[0].paste(rgb, win);
    Ok(PatchMatchStats { filled, levels, sources })
}

/// Fewest whole source patches a coarser level must hold to be used.
const MIN_SOURCES: usize = 32;
/// Propagation steps of one search iteration (jump flood: far first, then near).
const STEPS: [usize; 3] = [4, 2, 1];
/// Random search window (± pixels) of a polished level: the coarser level chose the region.
const POLISH_RADIUS: usize = 4;

/// The working window `(x0, y0, x1, y1)` (exclusive ends): the reachable holes' bounding box
/// grown by the context margin; None when no hole pixel is within reach.
fn window(holes: &[bool], w: usize, h: usize, reach: f32, opts: &PatchMatchOptions) -> Option<(usize, usize, usize, usize)> {
    let bb = super::mask::grown_bbox(holes, w, h, 1.0)?;
    let margin = opts.context.max(4 * opts.patch) + if reach.is_finite() { reach.ceil() as usize } else { 0 };
    let m = margin.min(w.max(h));
    Some((bb.0.saturating_sub(m), bb.1.saturating_sub(m), (bb.2 + m).min(w), (bb.3 + m).min(h)))
}

/// One pyramid level over the working window.
struct Level {
    w: usize,
    h: usize,
    /// Linear RGB, 3 values per pixel.
    lin: Vec<f32>,
    /// √(linear RGB), the values patches are compared on.
    feat: Vec<f32>,
    /// Disparity (filled behind the hole).
    disp: Vec<f32>,
    /// Visible background (not a hole): at coarse levels, all four children are.
    known: Vec<bool>,
    /// Pixels the fill computes: at coarse levels, any child is one.
    target: Vec<bool>,
    /// Largest distance (pixels, full resolution) from a target to the visible background.
    deepest: f32,
    /// Centres of whole source patches (every pixel known, inside the level).
    valid: Vec<bool>,
    /// The valid centres, as indices (for random draws).
    sources: Vec<u32>,
}

fn sqrt_feat(v: f32) -> f32 {
    v.max(0.0).sqrt()
}

impl Level {
    fn base(rgb: &Image, holes: &[bool], disparity: &Image, reach: f32, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> Level {
        let (w, h) = (x1 - x0, y1 - y0);
        let mut lin = Vec::with_capacity(w * h * 3);
        let mut disp = Vec::with_capacity(w * h);
        let mut known = Vec::with_capacity(w * h);
        for y in y0..y1 {
            lin.extend_from_slice(&rgb.data[(y * rgb.width + x0) * 3..(y * rgb.width + x1) * 3]);
            disp.extend_from_slice(&disparity.data[y * rgb.width + x0..y * rgb.width + x1]);
            known.extend(holes[y * rgb.width + x0..y * rgb.width + x1].iter().map(|&m| !m));
        }
        // Every hole pixel's nearest visible pixel within reach lies inside the window (the
        // context margin covers the reach), except at the photo's border where it stops too.
        let d = super::mask::distance_to(&known, w, h);
        let target: Vec<bool> = known.iter().zip(&d).map(|(&k, &d)| !k && d <= reach).collect();
        let deepest = d.iter().zip(&target).filter(|(_, t)| **t).map(|(&d, _)| d).fold(0.0, f32::max);
        let feat = lin.iter().map(|&v| sqrt_feat(v)).collect();
        Level { w, h, lin, feat, disp, known, target, deepest, valid: Vec::new(), sources: Vec::new() }
    }

    /// Marks the whole source patches of radius `r` (a box count of unknown pixels).
    fn with_sources(mut self, r: usize) -> Level {
        let (w, h) = (self.w, self.h);
        let mut sat = vec![0u32; (w + 1) * (h + 1)];
        for y in 0..h {
            let mut run = 0;
            for x in 0..w {
                run += !self.known[y * w + x] as u32;
                sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + run;
            }
        }
        self.valid = vec![false; w * h];
        for y in r..h.saturating_sub(r) {
            for x in r..w.saturating_sub(r) {
                let (a, b, c, d) = (y - r, y + r + 1, x - r, x + r + 1);
                let bad = sat[b * (w + 1) + d] + sat[a * (w + 1) + c] - sat[a * (w + 1) + d] - sat[b * (w + 1) + c];
                self.valid[y * w + x] = bad == 0;
            }
        }
        self.sources = (0..w * h).filter(|&i| self.valid[i]).map(|i| i as u32).collect();
        self
    }

    /// The level at half the size: colours and disparity box-averaged over 2x2 (edges
    /// replicate), known where all children are, a target where any child is.
    fn down(&self) -> Level {
        let (w, h) = (self.w.div_ceil(2), self.h.div_ceil(2));
        let mut lv = Level {
            w,
            h,
            lin: vec![0.0; w * h * 3],
            feat: vec![0.0; w * h * 3],
            disp: vec![0.0; w * h],
            known: vec![true; w * h],
            target: vec![false; w * h],
            deepest: self.deepest,
            valid: Vec::new(),
            sources: Vec::new(),
        };
        for y in 0..h {
            for x in 0..w {
                let o = y * w + x;
                for (cy, cx) in [(2 * y, 2 * x), (2 * y, 2 * x + 1), (2 * y + 1, 2 * x), (2 * y + 1, 2 * x + 1)] {
                    let i = cy.min(self.h - 1) * self.w + cx.min(self.w - 1);
                    for c in 0..3 {
                        lv.lin[o * 3 + c] += 0.25 * self.lin[i * 3 + c];
                    }
                    lv.disp[o] += 0.25 * self.disp[i];
                    lv.known[o] &= self.known[i];
                    lv.target[o] |= self.target[i];
                }
            }
        }
        lv.feat = lv.lin.iter().map(|&v| sqrt_feat(v)).collect();
        lv
    }

    /// Squared distance between the patches at target `t` and source `s` (pixel indices), plus
    /// the depth term; stops early (returning a value ≥ `best`) once the sum passes `best`.
    /// Source patches lie inside the level; target pixels outside it are skipped.
    #[inline]
    fn distance(&self, t: usize, s: usize, r: usize, depth_weight: f32, best: f32) -> f32 {
        let side = 2 * r + 1;
        let dd = self.disp[t] - self.disp[s];
        let mut sum = depth_weight * (3 * side * side) as f32 * dd * dd;
        let (tx, ty, sx, sy) = (t % self.w, t / self.w, s % self.w, s / self.w);
        if tx >= r && ty >= r && tx + r < self.w && ty + r < self.h {
            for dy in 0..side {
                let a = ((ty + dy - r) * self.w + tx - r) * 3;
                let b = ((sy + dy - r) * self.w + sx - r) * 3;
                sum += self.feat[a..a + 3 * side].iter().zip(&self.feat[b..b + 3 * side]).map(|(p, q)| (p - q) * (p - q)).sum::<f32>();
                if sum >= best {
                    return sum;
                }
            }
            return sum;
        }
        for dy in 0..side {
            let y = ty + dy;
            if y < r || y - r >= self.h {
                continue;
            }
            for dx in 0..side {
                let x = tx + dx;
                if x < r || x - r >= self.w {
                    continue;
                }
                let a = ((y - r) * self.w + x - r) * 3;
                let b = ((sy + dy - r) * self.w + sx + dx - r) * 3;
                for c in 0..3 {
                    let e = self.feat[a + c] - self.feat[b + c];
                    sum += e * e;
                }
            }
            if sum >= best {
                return sum;
            }
        }
        sum
    }

    /// Sets every target pixel to the weighted mean of what the patches covering it (the
    /// field's entries within `r`) copy there; weights `exp(-d / 2σ²)` with σ² the field's 75th
    /// percentile distance (Wexler et al.): good matches dominate, the texture stays sharp.
    fn vote(&mut self, f: &Field, r: usize) {
        let mut ds: Vec<f32> = f.dist.iter().copied().filter(|d| d.is_finite()).collect();
        let scale = if ds.is_empty() {
            1.0
        } else {
            let k = (ds.len() * 3 / 4).min(ds.len() - 1);
            let (_, v, _) = ds.select_nth_unstable_by(k, f32::total_cmp);
            (2.0 * *v).max(1e-6)
        };
        let weights: Vec<f32> = f.dist.iter().map(|&d| if d.is_finite() { (-d / scale).exp().max(1e-12) } else { 0.0 }).collect();
        let (w, h) = (self.w, self.h);
        let lin = &self.lin;
        let target = &self.target;
        let voted: Vec<(usize, [f32; 3])> = (0..w * h)
            .into_par_iter()
            .filter(|&p| target[p])
            .map(|p| {
                let (px, py) = (p % w, p / w);
                let (mut acc, mut wsum) = ([0.0f32; 3], 0.0f32);
                for qy in py.saturating_sub(r)..(py + r + 1).min(h) {
                    for qx in px.saturating_sub(r)..(px + r + 1).min(w) {
                        let e = f.entry[qy * w + qx];
                        if e == NONE || weights[e as usize] == 0.0 {
                            continue;
                        }
                        let s = f.src[e as usize] as usize;
                        // The source pixel at the same offset from the source centre.
                        let (sx, sy) = (s % w + px - qx, s / w + py - qy);
                        let wgt = weights[e as usize];
                        let i = (sy * w + sx) * 3;
                        for c in 0..3 {
                            acc[c] += wgt * lin[i + c];
                        }
                        wsum += wgt;
                    }
                }
                (p, if wsum > 0.0 { acc.map(|a| a / wsum) } else { [lin[p * 3], lin[p * 3 + 1], lin[p * 3 + 2]] })
            })
            .collect();
        for (p, v) in voted {
            self.lin[p * 3..p * 3 + 3].copy_from_slice(&v);
            for (f, &v) in self.feat[p * 3..p * 3 + 3].iter_mut().zip(&v) {
                *f = sqrt_feat(v);
            }
        }
    }

    /// Writes the target pixels back into the photo-sized image.
    fn paste(&self, rgb: &mut Image, (x0, y0, _, _): (usize, usize, usize, usize)) {
        for (p, _) in self.target.iter().enumerate().filter(|(_, t)| **t) {
            let (x, y) = (p % self.w + x0, p / self.w + y0);
            let i = (y * rgb.width + x) * 3;
            rgb.data[i..i + 3].copy_from_slice(&self.lin[p * 3..p * 3 + 3]);
        }
    }
}

/// Marks a pixel with no field entry.
const NONE: u32 = u32::MAX;

/// The nearest-neighbour field over the patch centres whose patch overlaps a target (targets
/// grown by `r`): for each, a source centre and its distance.
struct Field {
    /// Field entry of each level pixel, or [`NONE`].
    entry: Vec<u32>,
    /// Level pixel of each entry.
    at: Vec<u32>,
    /// Source centre of each entry (a level pixel index, always a valid source).
    src: Vec<u32>,
    /// Patch distance of each entry (with the depth term), for the current colours.
    dist: Vec<f32>,
}

/// SplitMix64: a hash from the draw's coordinates, so draws do not depend on the order work is
/// done in.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Field {
    /// The entries of `lv` (pixels within Chebyshev `r` of a target), sources unset.
    fn domain(lv: &Level, r: usize) -> Field {
        let (w, h) = (lv.w, lv.h);
        let mut near = vec![false; w * h];
        for (p, _) in lv.target.iter().enumerate().filter(|(_, t)| **t) {
            let (px, py) = (p % w, p / w);
            for qy in py.saturating_sub(r)..(py + r + 1).min(h) {
                near[qy * w + px.saturating_sub(r)..qy * w + (px + r + 1).min(w)].fill(true);
            }
        }
        let at: Vec<u32> = (0..w * h).filter(|&p| near[p]).map(|p| p as u32).collect();
        let mut entry = vec![NONE; w * h];
        for (e, &p) in at.iter().enumerate() {
            entry[p as usize] = e as u32;
        }
        let n = at.len();
        Field { entry, at, src: vec![0; n], dist: vec![f32::INFINITY; n] }
    }

    /// Random sources (the coarsest level's start).
    fn random(lv: &Level, r: usize, seed: u64) -> Field {
        let mut f = Field::domain(lv, r);
        for (e, s) in f.src.iter_mut().enumerate() {
            *s = lv.sources[(mix(seed ^ e as u64) % lv.sources.len() as u64) as usize];
        }
        f
    }

    /// Sources from the coarser level's field: twice the parent's source plus the pixel's
    /// offset in its 2x2 block, or a random source where that is not valid here.
    fn upsample(lv: &Level, r: usize, parent: &Field, seed: u64) -> Field {
        let mut f = Field::domain(lv, r);
        let pw = lv.w.div_ceil(2);
        for (e, &p) in f.at.iter().enumerate() {
            let (x, y) = (p as usize % lv.w, p as usize / lv.w);
            let pe = parent.entry[(y / 2) * pw + x / 2];
            let cand = (pe != NONE).then(|| {
                let s = parent.src[pe as usize] as usize;
                ((s % pw) * 2 + x % 2, (s / pw) * 2 + y % 2)
            });
            f.src[e] = match cand {
                Some((sx, sy)) if sx < lv.w && sy < lv.h && lv.valid[sy * lv.w + sx] => (sy * lv.w + sx) as u32,
                _ => lv.sources[(mix(seed ^ e as u64) % lv.sources.len() as u64) as usize],
            };
        }
        f
    }

    /// Recomputes every entry's distance for the current colours.
    fn refresh(&mut self, lv: &Level, r: usize, depth_weight: f32) {
        let (at, src) = (&self.at, &self.src);
        self.dist.par_iter_mut().enumerate().for_each(|(e, d)| {
            *d = lv.distance(at[e] as usize, src[e] as usize, r, depth_weight, f32::INFINITY);
        });
    }

    /// One PatchMatch round, reading `self` and returning the new field: each entry tries its
    /// neighbours' sources at `step` pixels (shifted back by the step), then random sources
    /// around its best in windows halving from `max_radius` to one pixel.
    fn search(self, lv: &Level, r: usize, depth_weight: f32, (step, max_radius): (usize, usize), salt: u64) -> Field {
        let (w, h) = (lv.w as isize, lv.h as isize);
        let mut next: Vec<(u32, f32)> = vec![(0, 0.0); self.at.len()];
        next.par_iter_mut().enumerate().for_each(|(e, out)| {
            let p = self.at[e] as usize;
            let (px, py) = ((p % lv.w) as isize, (p / lv.w) as isize);
            let (mut best, mut best_d) = (self.src[e] as usize, self.dist[e]);
            let try_src = |sx: isize, sy: isize, best: &mut usize, best_d: &mut f32| {
                if sx < 0 || sy < 0 || sx >= w || sy >= h {
                    return;
                }
                let s = (sy * w + sx) as usize;
                if s == *best || !lv.valid[s] {
                    return;
                }
                let d = lv.distance(p, s, r, depth_weight, *best_d);
                if d < *best_d {
                    (*best, *best_d) = (s, d);
                }
            };
            let k = step as isize;
            for (dx, dy) in [(-k, 0), (k, 0), (0, -k), (0, k)] {
                let (qx, qy) = (px + dx, py + dy);
                if qx < 0 || qy < 0 || qx >= w || qy >= h {
                    continue;
                }
                let q = self.entry[(qy * w + qx) as usize];
                if q == NONE {
                    continue;
                }
                let s = self.src[q as usize] as isize;
                try_src(s % w - dx, s / w - dy, &mut best, &mut best_d);
            }
            let mut radius = max_radius as isize;
            let mut draw = 0u64;
            while radius >= 1 {
                let z = mix(salt ^ ((e as u64) << 8) ^ draw);
                draw += 1;
                let span = 2 * radius as u64 + 1;
                let ox = (z % span) as isize - radius;
                let oy = ((z >> 32) % span) as isize - radius;
                let (bx, by) = ((best % lv.w) as isize, (best / lv.w) as isize);
                try_src(bx + ox, by + oy, &mut best, &mut best_d);
                radius /= 2;
            }
            *out = (best as u32, best_d);
        });
        let (src, dist) = next.into_iter().unzip();
        Field { entry: self.entry, at: self.at, src, dist }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stages::inpaint::{TeleaOptions, inpaint_telea};

    /// Vertical stripes of period 6 (two colours) with a square hole in the middle; flat
    /// disparity.
    fn stripes(w: usize, h: usize, hole: (usize, usize, usize, usize)) -> (Image, Image, Vec<bool>) {
        let mut img = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let on = (x / 3) % 2 == 0;
                img.pixel_mut(x, y).copy_from_slice(if on { &[0.8, 0.2, 0.1] } else { &[0.1, 0.3, 0.7] });
            }
        }
        let holes: Vec<bool> = (0..w * h).map(|i| (hole.0..hole.2).contains(&(i % w)) && (hole.1..hole.3).contains(&(i / w))).collect();
        (img, Image::filled(w, h, 1, 0.5), holes)
    }

    fn hole_rmse(a: &Image, b: &Image, holes: &[bool]) -> f32 {
        let (mut s, mut n) = (0.0, 0);
        for (i, _) in holes.iter().enumerate().filter(|(_, h)| **h) {
            for c in 0..3 {
                s += (a.data[i * 3 + c] - b.data[i * 3 + c]).powi(2);
                n += 1;
            }
        }
        (s / n as f32).sqrt()
    }

    fn telea(img: &Image, holes: &[bool]) -> Image {
        let mut t = img.clone();
        inpaint_telea(&mut t, holes, TeleaOptions::new(5.0)).unwrap();
        t
    }

    #[test]
    fn stripes_are_continued_not_blurred() {
        let (truth, disp, holes) = stripes(72, 64, (24, 20, 48, 44));
        let t = telea(&truth, &holes);
        let mut pm = t.clone();
        let stats = fill(&mut pm, &holes, &disp, f32::INFINITY, &PatchMatchOptions::default()).unwrap();
        assert_eq!(stats.filled, 24 * 24);
        assert!(stats.levels >= 1 && stats.sources > 0);
        let (e_t, e_pm) = (hole_rmse(&t, &truth, &holes), hole_rmse(&pm, &truth, &holes));
        assert!(e_pm < 0.25 * e_t, "patchmatch rmse {e_pm} vs telea {e_t}");
        assert!(pm.all_finite());
        // Outside the hole nothing moves.
        for (i, _) in holes.iter().enumerate().filter(|(_, h)| !**h) {
            assert_eq!(pm.data[i * 3..i * 3 + 3], truth.data[i * 3..i * 3 + 3]);
        }
        // The large-image path (every level but the coarsest only polished) still copies the
        // texture.
        let mut polished = t.clone();
        fill(&mut polished, &holes, &disp, f32::INFINITY, &PatchMatchOptions { search_entries: 0, ..Default::default() }).unwrap();
        let e_pol = hole_rmse(&polished, &truth, &holes);
        eprintln!("polished rmse {e_pol}");
        assert!(e_pol < 0.5 * e_t, "polished patchmatch rmse {e_pol} vs telea {e_t}");
    }

    #[test]
    fn checker_is_continued() {
        let (w, h) = (64, 64);
        let mut truth = Image::new(w, h, 3);
        for y in 0..h {
            for x in 0..w {
                let v = if (x / 4 + y / 4) % 2 == 0 { 0.9 } else { 0.05 };
                truth.pixel_mut(x, y).copy_from_slice(&[v, v, v]);
            }
        }
        let holes: Vec<bool> = (0..w * h).map(|i| ((i % w) as isize - 32).pow(2) + ((i / w) as isize - 30).pow(2) < 100).collect();
        let disp = Image::filled(w, h, 1, 0.3);
        let t = telea(&truth, &holes);
        let mut pm = t.clone();
        fill(&mut pm, &holes, &disp, f32::INFINITY, &PatchMatchOptions::default()).unwrap();
        let (e_t, e_pm) = (hole_rmse(&t, &truth, &holes), hole_rmse(&pm, &truth, &holes));
        assert!(e_pm < 0.5 * e_t, "patchmatch rmse {e_pm} vs telea {e_t}");
    }

    #[test]
    fn depth_term_prefers_the_surface_at_the_hole_depth() {
        // Left half red at disparity 0.2, right half blue at 0.8; the hole straddles nothing but
        // lies in the blue half with its disparity filled as 0.8: a red copy would be wrong.
        let (w, h) = (64, 48);
        let mut img = Image::new(w, h, 3);
        let mut disp = Image::new(w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let left = x < 32;
                let n = ((x * 7 + y * 13) % 5) as f32 * 0.02;
                img.pixel_mut(x, y).copy_from_slice(&if left { [0.7 + n, 0.1, 0.1] } else { [0.1, 0.1, 0.7 + n] });
                disp.data[y * w + x] = if left { 0.2 } else { 0.8 };
            }
        }
        let holes: Vec<bool> = (0..w * h).map(|i| (36..48).contains(&(i % w)) && (16..32).contains(&(i / w))).collect();
        let mut pm = telea(&img, &holes);
        fill(&mut pm, &holes, &disp, f32::INFINITY, &PatchMatchOptions::default()).unwrap();
        for (i, _) in holes.iter().enumerate().filter(|(_, h)| **h) {
            assert!(pm.data[i * 3 + 2] > 0.5 && pm.data[i * 3] < 0.3, "pixel {i}: {:?}", &pm.data[i * 3..i * 3 + 3]);
        }
    }

    #[test]
    fn deterministic_across_thread_counts() {
        let (truth, disp, holes) = stripes(48, 40, (16, 12, 32, 28));
        let start = telea(&truth, &holes);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let mut out = start.clone();
            pool.install(|| fill(&mut out, &holes, &disp, f32::INFINITY, &PatchMatchOptions::default())).unwrap();
            out
        };
        let one = run(1);
        assert_eq!(one, run(1));
        assert_eq!(one, run(3));
    }

    #[test]
    fn reach_limits_the_fill() {
        let (truth, disp, holes) = stripes(64, 64, (8, 8, 56, 56));
        let start = telea(&truth, &holes);
        let mut out = start.clone();
        let stats = fill(&mut out, &holes, &disp, 4.0, &PatchMatchOptions::default()).unwrap();
        // Pixels farther than 4 px from the visible stripes keep their start value.
        let deep = |i: usize| (13..51).contains(&(i % 64)) && (13..51).contains(&(i / 64));
        for i in (0..64 * 64).filter(|&i| deep(i)) {
            assert_eq!(out.data[i * 3..i * 3 + 3], start.data[i * 3..i * 3 + 3]);
        }
        assert!(stats.filled > 0 && stats.filled < 48 * 48);
    }

    #[test]
    fn no_hole_tiny_images_and_no_source_leave_the_input() {
        let opts = PatchMatchOptions::default();
        let (img, disp, _) = stripes(20, 20, (0, 0, 0, 0));
        let mut out = img.clone();
        assert_eq!(fill(&mut out, &[false; 400], &disp, f32::INFINITY, &opts).unwrap(), PatchMatchStats::default());
        assert_eq!(out, img);
        // Images too small for one whole source patch: nothing to copy, nothing changes.
        for (w, h) in [(1, 1), (2, 3), (6, 6)] {
            let img = Image::filled(w, h, 3, 0.5);
            let mut out = img.clone();
            let holes: Vec<bool> = (0..w * h).map(|i| i == 0).collect();
            let s = fill(&mut out, &holes, &Image::filled(w, h, 1, 0.5), f32::INFINITY, &opts).unwrap();
            assert_eq!((s.levels, out), (0, img));
        }
        // All hole.
        let mut out = img.clone();
        assert_eq!(fill(&mut out, &[true; 400], &disp, f32::INFINITY, &opts).unwrap().levels, 0);
        assert_eq!(out, img);
        // A hole with a whole patch beside it on a small image is filled, finitely.
        let (img, disp, holes) = stripes(12, 10, (8, 3, 10, 6));
        let mut out = img.clone();
        assert!(fill(&mut out, &holes, &disp, f32::INFINITY, &opts).unwrap().filled == 6);
        assert!(out.all_finite());
    }

    #[test]
    fn bad_arguments_are_usage_errors() {
        let (img, disp, holes) = stripes(16, 16, (4, 4, 8, 8));
        let mut out = img.clone();
        assert!(fill(&mut out, &holes[1..], &disp, 5.0, &PatchMatchOptions::default()).is_err());
        assert!(fill(&mut out, &holes, &disp, 5.0, &PatchMatchOptions { patch: 6, ..Default::default() }).is_err());
        assert!(fill(&mut out, &holes, &disp, f32::NAN, &PatchMatchOptions::default()).is_err());
        assert_eq!(out, img);
    }
}
