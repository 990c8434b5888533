//! The exact per-layer kernel: the official Dr.Bokeh forward formula, tap by tap.
//!
//! This is the oracle every faster kernel is measured against. It reproduces the official
//! implementation's quirks on purpose (see README "Fidelity to the official renderer"):
//! the `+1` in the scatter radius, the strict disk mask, the soft step giving a same-depth
//! neighbour a small weight even at K = 0, and replicate padding (implemented as clamped
//! reads, so no padded copy is allocated).
//!
//! Cost: O(W·H·taps) with taps ≈ π·(lens/2)²; one transcendental pair (exp, tanh) per tap.

use super::aperture::Tap;
use super::aperture::shape::Geometry;
use super::aperture::sources::ShapedSources;
use super::layer::{A, CHANNELS, D, Layer};
use super::lens::{self, Profile, energy, focal_defocus, occlusion, scatter_radius, visibility_half_size, weight_unit};
use super::{RawLayer, RenderSettings, Role, raw};
use rayon::prelude::*;

/// Renders one layer into its raw sums: per pixel `[ΣR, ΣG, ΣB, W, o]` where the colour sums
/// are weighted by `w·O·α`, `W` is the total weight and `o` the non-focal visibility (eq. 4).
/// Allocates the 5-channel output and two planes of per-pixel terms.
pub fn scatter_layer(layer: &Layer, s: &RenderSettings, taps: &[Tap], role: Role) -> RawLayer {
    match s.profile {
        Profile::Official => scatter_layer_official(layer, s, taps),
        Profile::Physical => scatter_layer_physical(layer, s, taps, role),
    }
}

/// The official formula (golden vectors).
fn scatter_layer_official(layer: &Layer, s: &RenderSettings, taps: &[Tap]) -> RawLayer {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let p = s.lens / 2;
    // Per-pixel terms that every tap reads: relative disparity and scatter radius.
    let d: Vec<f32> = img.data.chunks_exact(CHANNELS).map(|px| px[D] - s.focus).collect();
    let sigma: Vec<f32> = d.iter().map(|&d| scatter_radius(d, s.blur)).collect();
    let unit = weight_unit(super::min_visible_radius(img, &sigma));

    let mut out = vec![0f32; w * h * raw::CHANNELS];
    out.par_chunks_mut(w * raw::CHANNELS).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let i = y * w + x;
            let dp = d[i];
            let q = if s.occlusion { focal_defocus(dp, s.blur) } else { 1.0 };
            // f64 sums: thousands of taps of similar size would drift in f32 (a uniform
            // colour moved by 5e-5 at K = 60).
            let (mut sr, mut sg, mut sb, mut sw) = (0f64, 0f64, 0f64, 0f64);
            for t in taps {
                let yy = (y as i64 + t.di as i64).clamp(0, h as i64 - 1) as usize;
                let xx = (x as i64 + t.dj as i64).clamp(0, w as i64 - 1) as usize;
                let j = yy * w + xx;
                let px = &img.data[j * CHANNELS..(j + 1) * CHANNELS];
                // Both skips are exact: a transparent tap adds +0, and at q == 1 the
                // occlusion is exactly 1 whatever the tanh gives.
                if px[A] == 0.0 {
                    continue;
                }
                let wt = energy(sigma[j], t.r, unit);
                let v = if (t.di == 0 && t.dj == 0) || q == 1.0 { 1.0 } else { occlusion(q, d[j], dp) };
                let k = wt * v * px[A];
                sr += (k * px[0]) as f64;
                sg += (k * px[1]) as f64;
                sb += (k * px[2]) as f64;
                sw += k as f64;
            }
            let o = box_alpha(img, x, y, visibility_half_size(sigma[i], p));
            row[x * raw::CHANNELS..(x + 1) * raw::CHANNELS].copy_from_slice(&[sr as f32, sg as f32, sb as f32, sw as f32, o]);
        }
    });
    RawLayer::new(w, h, out, layer)
}

/// The physical profile, tap by tap: every visible source spreads its premultiplied colour
/// and its alpha over a uniform disk of radius `K·|d|` with a one-pixel ramp edge, normalized
/// to unit flux ([`lens::disk_coverage`] / [`lens::disk_norm`]), or over the aperture's shape
/// of that circumradius ([`super::aperture::shape::Geometry::coverage`] / `norm`). At each target the sources
/// are split by depth relative to the target ([`lens::depth_groups`]: in front, the same
/// surface, behind; with occlusion off, all one group) and the groups are composited front to
/// back ([`lens::over_groups`]). The raw pixel is `[P_r, P_g, P_b, A, V]`: the colour
/// `P / A` and visibility `V = A` composite to `P` (premultiplied), as a lens would; the
/// backdrop layer's visibility is at least its own alpha (see [`Role::Backdrop`]).
/// Allocates the output and three planes of per-pixel terms.
fn scatter_layer_physical(layer: &Layer, s: &RenderSettings, taps: &[Tap], role: Role) -> RawLayer {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let d: Vec<f32> = img.data.chunks_exact(CHANNELS).map(|px| px[D] - s.focus).collect();
    // The thin lens's CoC, capped far beyond any image so ratios stay finite.
    let radius: Vec<f32> = d.iter().map(|&d| lens::coc_radius(d, s.blur).min(lens::MAX_RADIUS)).collect();
    // The disc's own ramp, or the aperture's pixel-integrated shape (`aperture::sources`).
    let shape = ShapedSources::new(s.aperture, w, h);
    let norm: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|j| match &shape {
            None => lens::disk_norm(radius[j]),
            Some(g) => g.norm(radius[j]),
        })
        .collect();
    let mut out = vec![0f32; w * h * raw::CHANNELS];
    let p = (s.lens / 2) as i64;
    // Sources with a cut (a cat's eye) each have their own coverage: no tables.
    let tables = shape
        .as_ref()
        .filter(|g| !g.cut())
        .map(|g| ShapeTables::new(g.geometry(), &radius, |j| d[j] > 0.0, |j| img.data[j * CHANNELS + A] != 0.0, p));
    out.par_chunks_mut(w * raw::CHANNELS).enumerate().for_each(|(y, row)| {
        for x in 0..w {
            let dx = d[y * w + x];
            // A cat's eye's target normalizes the light that passes its cut.
            let gain = shape.as_ref().map_or(1.0, |g| g.target_gain(y * w + x));
            // [in front, same surface, behind] × [P_r, P_g, P_b, A], f64 as in the official kernel.
            let mut groups = [[0f64; 4]; 3];
            for t in taps {
                let yy = (y as i64 + t.di as i64).clamp(0, h as i64 - 1) as usize;
                let xx = (x as i64 + t.dj as i64).clamp(0, w as i64 - 1) as usize;
                let j = yy * w + xx;
                let px = &img.data[j * CHANNELS..(j + 1) * CHANNELS];
                // A transparent source adds nothing (skipped before its coverage is formed).
                if px[A] == 0.0 {
                    continue;
                }
                let cov = match &shape {
                    None => lens::disk_coverage(radius[j], t.r),
                    // A source in front of the focal plane (d > 0) shows the shape point-reflected.
                    Some(g) => match &tables {
                        Some(tables) => tables.coverage(g.geometry(), j, radius[j], d[j] > 0.0, p, t),
                        None => g.coverage(j, radius[j], d[j] > 0.0, t),
                    },
                };
                if cov == 0.0 {
                    continue;
                }
                // cov / norm, not cov · (1/norm): an in-focus source's weight is exactly 1.
                let wt = (px[A] * (cov / norm[j])) as f64;
                let wt = if gain == 1.0 { wt } else { wt * ShapedSources::gain_of(radius[j], gain) as f64 };
                let g = if (t.di == 0 && t.dj == 0) || !s.occlusion { [0.0, 1.0, 0.0] } else { lens::depth_groups(d[j], dx) };
                lens::add_to_groups(&mut groups, wt, g, px);
            }
            let p = lens::over_groups(&groups);
            let a = p[3] as f32;
            let vis = match role {
                Role::Front => a,
                Role::Backdrop => a.max(img.data[(y * w + x) * CHANNELS + A]),
            };
            row[x * raw::CHANNELS..(x + 1) * raw::CHANNELS].copy_from_slice(&[p[0] as f32, p[1] as f32, p[2] as f32, a, vis]);
        }
    });
    RawLayer::new(w, h, out, layer)
}

/// A layer's tables of a shape's coverage over the lens window, one per CoC and side of the
/// focal plane shared by visible sources (a layer's planes share a few): [`Geometry::coverage`]
/// costs up to 16 area clips on the outline, a table look-up one index. A table costs one
/// window of coverages (about the taps one source meets), so only a (CoC, side) met by at least
/// two visible sources gets one, the [`ShapeTables::MAX`] most common first; the others (a
/// slanted surface has one CoC per pixel) are evaluated tap by tap. The values are the same.
///
/// Built once per layer, in parallel, and looked up through a per-source index: a hash per tap
/// (the workers' lazily filled maps this replaces) was a fifth of a shaped exact render.
/// Allocates the tables and one index per pixel.
struct ShapeTables {
    tables: Vec<Vec<f32>>,
    /// Per source pixel (row-major), its table in `tables`, or [`ShapeTables::NONE`].
    of: Vec<u32>,
}

impl ShapeTables {
    const MAX: usize = 64;
    const NONE: u32 = u32::MAX;

    /// The tables of the sources `j` with `visible(j)`, CoC `radius[j]`, point-reflected when
    /// `flip[j]` (in front of the focal plane), in a window of half-size `p`.
    fn new(g: &Geometry, radius: &[f32], flip: impl Fn(usize) -> bool, visible: impl Fn(usize) -> bool, p: i64) -> ShapeTables {
        let key = |j: usize| (radius[j].to_bits(), flip(j));
        let mut count = std::collections::HashMap::new();
        for j in (0..radius.len()).filter(|&j| visible(j)) {
            *count.entry(key(j)).or_insert(0usize) += 1;
        }
        let mut keys: Vec<_> = count.into_iter().filter(|&(_, n)| n >= 2).collect();
        // Most common first; ties by key, so the choice never depends on the map's order.
        keys.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        keys.truncate(Self::MAX);
        let tables = keys
            .par_iter()
            .map(|&((r, flip), _)| {
                let r = f32::from_bits(r);
                (-p..=p)
                    .flat_map(|di| (-p..=p).map(move |dj| (di, dj)))
                    .map(|(di, dj)| g.coverage(r, -dj as f32, di as f32, flip))
                    .collect()
            })
            .collect();
        let index: std::collections::HashMap<_, u32> = keys.iter().enumerate().map(|(k, &(key, _))| (key, k as u32)).collect();
        let of =
            (0..radius.len()).map(|j| if visible(j) { index.get(&key(j)).copied().unwrap_or(Self::NONE) } else { Self::NONE }).collect();
        ShapeTables { tables, of }
    }

    /// The coverage of tap `t` by source `j` of CoC `r` (point-reflected when `flip`) in a
    /// window of half-size `p`: the target sits `(-dj, di)` from the source (y up).
    fn coverage(&self, g: &Geometry, j: usize, r: f32, flip: bool, p: i64, t: &Tap) -> f32 {
        match self.of[j] {
            Self::NONE => g.coverage(r, -t.dj as f32, t.di as f32, flip),
            k => self.tables[k as usize][((t.di as i64 + p) * (2 * p + 1) + t.dj as i64 + p) as usize],
        }
    }
}

/// Mean alpha over the `(2n+1)²` box centred on (x, y), replicate-padded (eq. 4), summed in
/// f64. O(n²): the plain formula, the oracle of the fast kernel's summed-area visibility.
pub(crate) fn box_alpha(img: crate::ImageRef<'_>, x: usize, y: usize, n: usize) -> f32 {
    let (w, h) = (img.width as i64, img.height as i64);
    let n = n as i64;
    let mut sum = 0f64;
    for yy in (y as i64 - n)..=(y as i64 + n) {
        let row = yy.clamp(0, h - 1) * w;
        for xx in (x as i64 - n)..=(x as i64 + n) {
            sum += img.data[((row + xx.clamp(0, w - 1)) * CHANNELS as i64) as usize + A] as f64;
        }
    }
    (sum / ((2 * n + 1) * (2 * n + 1)) as f64) as f32
}
