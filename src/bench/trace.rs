//! Thin-lens ray tracer for layered billboard scenes: the tool's own physical ground truth.
//!
//! A scene is a stack of fronto-parallel planes (front first). Plane `l` sits at normalized
//! disparity `D_l` and carries a screen-space RGBA image: what a pinhole camera sees of it, in
//! linear radiance (straight colour; alpha = coverage / opacity).
//!
//! ## Geometry
//! For a lens point `a` in the unit disk and a sensor position `p` (pixels), the thin-lens ray
//! that converges on `p` crosses plane `l` at the point whose pinhole projection is
//!
//! ```text
//! q_l = p + K·a·(D_l − f)        (pixels; K = blur strength, f = focus disparity)
//! ```
//!
//! This is the ground-truth README's `u = f·X/z + f·a·(1/z_f − 1/z)` solved for the pinhole
//! position, with `A·f·(1/z − 1/z_f) = K·(D − f)` in normalized disparity. As `a` sweeps the
//! disk a point at relative disparity `d` paints a uniform disk of radius `K·|d|` px, the
//! renderer's CoC. Mitsuba's image x axis runs toward world −x, which flips the sign of `a` in
//! pixel units for every plane at once; the aperture is symmetric, so the image does not depend
//! on that sign, only on all planes sharing the same `a` (which they do).
//!
//! ## Sampling
//! Each pixel averages `spp` rays (rounded up to a power of two). The lens points come from a
//! (0,2)-sequence in base 2 (Sobol' dimensions 1–2), whose power-of-two prefixes are stratified
//! in every elementary interval, digit-scrambled (32 precomputed scrambles, one picked per
//! pixel) and rotated by a random angle per pixel; the square maps to the disk with the
//! Shirley–Chiu concentric map (area preserving, keeps the strata). Everything derives from
//! `seed`: the result is deterministic and independent of the thread count.
//!
//! ## Pixel footprint
//! A layer texel is a pixel value: the mean radiance over that pixel's square (box filter), the
//! way the ground-truth scenes and the benchmark's scenes are made, so the plane's radiance is
//! the texels as boxes. The output pixel is the mean over its own square too. Two ways:
//! - [`Footprint::Analytic`] (default): the footprint integral is done exactly. The pixel-box
//!   average of box texels around a point is the tent (bilinear) interpolant there
//!   (box ⊗ box = tent), so each ray passes through the pixel centre and reads each plane
//!   bilinearly (premultiplied colour and alpha). Only the aperture is sampled, the integrand
//!   is continuous, and the error falls about as 1/spp. An in-focus plane is reproduced exactly.
//! - [`Footprint::Sampled`]: the rays are spread over the pixel square too (a second scrambled
//!   (0,2)-net, randomly paired with the lens points, toroidally shifted per pixel) and read the box texels directly. Same mean for
//!   a single plane; it differs only where several planes' edges meet inside one pixel, and it
//!   converges more slowly (the integrand jumps at every texel edge).
//!
//! Outside the plane's image, reads replicate the border (as the renderer's padding does).
//! Along each ray, planes composite front to back with premultiplied "over"; a ray that leaves
//! the stack with transmittance left sees black.

use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::Layer;
use rayon::prelude::*;

/// How the pixel footprint is integrated (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Footprint {
    /// Exactly: rays through the pixel centre, planes read bilinearly.
    #[default]
    Analytic,
    /// By sampling the pixel square; planes read as box texels.
    Sampled,
}

/// One fronto-parallel plane: premultiplied RGBA texels and a constant disparity.
#[derive(Clone, Debug)]
pub struct Plane {
    /// Texels per row.
    pub width: usize,
    /// Rows of texels.
    pub height: usize,
    /// Normalized disparity of the plane.
    pub disparity: f32,
    /// Premultiplied R, G, B, A per texel, row-major.
    texels: Vec<[f32; 4]>,
}

impl Plane {
    /// A plane from straight (not premultiplied) RGB and alpha of equal size.
    pub fn from_rgb_alpha(rgb: &Image, alpha: &Image, disparity: f32) -> Plane {
        assert_eq!((rgb.width, rgb.height, rgb.channels), (alpha.width, alpha.height, 3), "plane: RGB size");
        assert_eq!(alpha.channels, 1, "plane: alpha channels");
        let texels = rgb
            .data
            .chunks_exact(3)
            .zip(&alpha.data)
            .map(|(c, &a)| {
                let a = a.clamp(0.0, 1.0);
                [c[0] * a, c[1] * a, c[2] * a, a]
            })
            .collect();
        Plane { width: rgb.width, height: rgb.height, disparity, texels }
    }

    /// A plane from a renderer layer (R, G, B, A, D) whose disparity is constant (within
    /// `1e-3`) wherever alpha > 0. `what` names the layer (its file) in the error otherwise.
    /// A fully transparent layer gets disparity 0 (it is invisible anyway).
    pub fn from_layer(layer: &Layer, what: &str) -> Result<Plane> {
        let img = layer.image();
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        let (mut at_lo, mut at_hi) = (0usize, 0usize);
        let (mut sum, mut wsum) = (0f64, 0f64);
        for (i, px) in img.data.chunks_exact(5).enumerate() {
            if px[3] > 0.0 {
                if px[4] < lo {
                    lo = px[4];
                    at_lo = i;
                }
                if px[4] > hi {
                    hi = px[4];
                    at_hi = i;
                }
                sum += px[3] as f64 * px[4] as f64;
                wsum += px[3] as f64;
            }
        }
        if wsum > 0.0 && hi - lo > 1e-3 {
            let xy = |i: usize| (i % img.width, i / img.width);
            return Err(Error::input(
                what,
                format!(
                    "the tracer needs each layer to be one fronto-parallel plane, but this layer's disparity (channel D) \
                     varies where alpha > 0: {lo} at pixel {:?} to {hi} at pixel {:?}; split it into one layer per depth",
                    xy(at_lo),
                    xy(at_hi)
                ),
            ));
        }
        let d = if wsum > 0.0 { (sum / wsum) as f32 } else { 0.0 };
        let rgb = img.select_channels(&[0, 1, 2]);
        Ok(Plane::from_rgb_alpha(&rgb, &img.channel(3), d))
    }

    #[inline(always)]
    fn texel(&self, x: isize, y: isize) -> &[f32; 4] {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        &self.texels[y * self.width + x]
    }

    /// Premultiplied RGBA at continuous position (x, y) (pixel units, texel centres at +0.5):
    /// bilinear for the analytic footprint, the texel's box for the sampled one.
    #[inline(always)]
    fn sample(&self, x: f32, y: f32, footprint: Footprint) -> [f32; 4] {
        match footprint {
            Footprint::Sampled => *self.texel(x.floor() as isize, y.floor() as isize),
            Footprint::Analytic => {
                let (fx, fy) = (x - 0.5, y - 0.5);
                let (x0, y0) = (fx.floor(), fy.floor());
                let (tx, ty) = (fx - x0, fy - y0);
                let (x0, y0) = (x0 as isize, y0 as isize);
                let (a, b, c, d) = (self.texel(x0, y0), self.texel(x0 + 1, y0), self.texel(x0, y0 + 1), self.texel(x0 + 1, y0 + 1));
                let mut o = [0f32; 4];
                for k in 0..4 {
                    let top = a[k] + (b[k] - a[k]) * tx;
                    let bot = c[k] + (d[k] - c[k]) * tx;
                    o[k] = top + (bot - top) * ty;
                }
                o
            }
        }
    }
}

/// Lens, sampling and output window of one trace.
#[derive(Clone, Copy, Debug)]
pub struct TraceSettings {
    /// Blur strength K: CoC radius in pixels per unit of relative disparity.
    pub blur: f32,
    /// Normalized disparity of the focal plane.
    pub focus: f32,
    /// Rays per pixel (rounded up to a power of two: the sequence is stratified there).
    pub spp: u32,
    /// Seed of the sample scrambles: equal seeds give bit-identical traces.
    pub seed: u64,
    /// How the pixel footprint is integrated.
    pub footprint: Footprint,
    /// The aperture's shape: lens samples are weighted by its transmission (see
    /// [`crate::render::aperture::shape`]).
    pub aperture: crate::render::Aperture,
}

impl TraceSettings {
    /// Settings with the analytic footprint.
    pub fn new(blur: f32, focus: f32, spp: u32, seed: u64) -> Self {
        TraceSettings { blur, focus, spp, seed, footprint: Footprint::Analytic, aperture: crate::render::Aperture::DISC }
    }
}

/// The part of the planes' pixel grid to render: `width × height` pixels starting at plane
/// pixel (`x0`, `y0`). Planes may be larger than the output (a margin of off-frame content).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// First column of the window, in plane pixels.
    pub x0: usize,
    /// First row of the window, in plane pixels.
    pub y0: usize,
    /// Output width, pixels.
    pub width: usize,
    /// Output height, pixels.
    pub height: usize,
}

impl Window {
    /// The whole `width × height` grid (no margin).
    pub fn full(width: usize, height: usize) -> Self {
        Window { x0: 0, y0: 0, width, height }
    }
}

/// Checks the inputs of [`trace`].
pub fn validate(planes: &[Plane], s: &TraceSettings) -> Result<()> {
    if planes.is_empty() {
        return Err(Error::usage("nothing to trace: no layers"));
    }
    let (w, h) = (planes[0].width, planes[0].height);
    if let Some((i, p)) = planes.iter().enumerate().find(|(_, p)| (p.width, p.height) != (w, h)) {
        return Err(Error::usage(format!(
            "layer {} is {}x{} but layer 1 is {w}x{h}: all layers must have the same size",
            i + 1,
            p.width,
            p.height
        )));
    }
    if w == 0 || h == 0 {
        return Err(Error::usage("nothing to trace: the layers are empty"));
    }
    crate::render::check_blur("trace.blur", s.blur)?;
    crate::render::check_focus("trace.focus", s.focus)?;
    if s.spp == 0 || s.spp > 1 << 20 {
        return Err(Error::usage(format!("trace.spp must be in 1..=1048576, got {}", s.spp)));
    }
    Ok(())
}

/// Traces the planes (front first) through the thin lens: linear RGB of `window`'s size.
/// `progress` is called with the number of rows finished (from any thread).
pub fn trace(planes: &[Plane], s: &TraceSettings, window: Window, progress: &(dyn Fn(usize) + Sync)) -> Result<Image> {
    Ok(trace_split(planes, s, window, progress)?.0)
}

/// [`trace`], plus the mean of the first half of each pixel's samples (itself a stratified
/// set): the RMS difference between the two halves, halved, estimates the result's noise.
/// With chromatic aberration each colour channel is traced with its own K, as the renderer
/// renders it ([`crate::render::chromatic`]; `progress` then counts every row three times).
pub fn trace_split(planes: &[Plane], s: &TraceSettings, window: Window, progress: &(dyn Fn(usize) + Sync)) -> Result<(Image, Image)> {
    validate(planes, s)?;
    if let Some(scales) = s.aperture.channel_scales() {
        let [full, half] = crate::render::chromatic::per_channel(scales, |scale, _| {
            let sc = TraceSettings { blur: s.blur * scale, aperture: s.aperture.achromatic(), ..*s };
            let (full, half) = trace_split(planes, &sc, window, progress)?;
            Ok([full, half])
        })?;
        return Ok((full, half));
    }
    let (pw, ph) = (planes[0].width, planes[0].height);
    if window.x0 + window.width > pw || window.y0 + window.height > ph {
        return Err(Error::Internal(format!("trace window {window:?} outside the {pw}x{ph} planes")));
    }
    let n = s.spp.next_power_of_two().max(2);
    let tables = SampleTables::new(n, s.seed);
    let ks: Vec<f32> = planes.iter().map(|p| s.blur * (p.disparity - s.focus)).collect();
    let ow = window.width;
    let vignette = Vignette::new(s, window);
    let mut out = Image::new(ow, window.height, 6);
    out.data.par_chunks_mut(ow * 6).enumerate().for_each(|(y, row)| {
        for x in 0..ow {
            let (px, py) = ((x + window.x0) as f32, (y + window.y0) as f32);
            row[x * 6..x * 6 + 6].copy_from_slice(&trace_pixel(planes, &ks, s, &tables, vignette.as_ref(), px, py));
        }
        progress(1);
    });
    Ok((out.select_channels(&[0, 1, 2]), out.select_channels(&[3, 4, 5])))
}

/// A cat's eye as a lens vignettes (`Aperture::with_cat_eye`): the barrel clips a ray by its
/// angle, so whether a lens point passes is decided by the pixel the ray lands on and holds for
/// every plane along it. A pixel's lens points pass through the second circle centred at its
/// own cut ([`crate::render::aperture::CatEye::offset`] of the pixel), and its light is
/// normalized by the weight that passes, so a uniform surface stays uniform (the vignetting's
/// darkening compensated, as the renderer's norms intend).
///
/// Not the source's circle: with a cut per source, the planes a ray meets would each see
/// another subset of the lens, and an occluder's edge would let the background through twice
/// (each plane normalized by its own subset: a bright rim around a blurred foreground, 7% more
/// light than the scene has on bench scene s007 of seed 1, 5 dB against the renderer). The
/// renderer draws the same rule: a source's rays that pass are those in one circle
/// (`CatEye::cut`), and each target normalizes what reaches it (`Geometry::cat_gain`).
struct Vignette {
    cat: crate::render::aperture::CatEye,
    window: Window,
}

impl Vignette {
    fn new(s: &TraceSettings, window: Window) -> Option<Vignette> {
        s.aperture.geometry()?;
        Some(Vignette { cat: s.aperture.cat_eye(window.width, window.height)?, window })
    }

    /// The cut (unit frame, y up) of the frame pixel whose corner is `(px, py)` (continuous
    /// plane coordinates).
    fn cut(&self, px: f32, py: f32) -> [f32; 2] {
        self.cat.offset(px - self.window.x0 as f32, py - self.window.y0 as f32)
    }
}

/// Number of independently scrambled copies of the sample pattern.
const TABLES: usize = 32;

/// Precomputed sample patterns: `TABLES` digit-scrambled (0,2)-nets of `n` lens points (mapped
/// to the disk) and footprint offsets. Each pixel picks one table and randomizes it further
/// with a rotation of the aperture and a toroidal shift of the footprint.
struct SampleTables {
    n: usize,
    lens: Vec<[f32; 2]>,
    /// The lens points before the map to the disk (unit square), for a polygonal aperture's
    /// own map ([`crate::render::aperture::shape::Geometry::sample`]).
    square: Vec<[f32; 2]>,
    foot: Vec<[f32; 2]>,
}

impl SampleTables {
    fn new(n: u32, seed: u64) -> Self {
        let mut h = splitmix(seed ^ 0x5EED);
        let mut next = || {
            h = splitmix(h);
            h
        };
        let (mut lens, mut foot) = (Vec::with_capacity(TABLES * n as usize), Vec::with_capacity(TABLES * n as usize));
        let mut square = Vec::with_capacity(TABLES * n as usize);
        for _ in 0..TABLES {
            let (lx, ly, fx, fy) = (next() as u32, next() as u32, next() as u32, next() as u32);
            // Footprint points pair with lens points through a random permutation (padding):
            // an XOR of the index would not do, the sequence being linear over GF(2).
            let mut perm: Vec<u32> = (0..n).collect();
            for i in (1..n as usize).rev() {
                perm.swap(i, (next() % (i as u64 + 1)) as usize);
            }
            for i in 0..n {
                let (x, y) = sobol02(i);
                let (ax, ay) = concentric_disk(unit(x ^ lx), unit(y ^ ly));
                lens.push([ax, ay]);
                square.push([unit(x ^ lx), unit(y ^ ly)]);
                let (x, y) = sobol02(perm[i as usize]);
                foot.push([unit(x ^ fx), unit(y ^ fy)]);
            }
        }
        SampleTables { n: n as usize, lens, square, foot }
    }
}

/// Mean radiance of the rays through the pixel whose top-left corner is (`px`, `py`), and the
/// mean of the first half of them.
fn trace_pixel(
    planes: &[Plane],
    ks: &[f32],
    s: &TraceSettings,
    tab: &SampleTables,
    vignette: Option<&Vignette>,
    px: f32,
    py: f32,
) -> [f32; 6] {
    let h = splitmix(s.seed ^ splitmix(((px as u64) << 32) ^ py as u64));
    let t = (h % TABLES as u64) as usize;
    let (sin, cos) = ((h >> 8) as u32 as f32 * (std::f32::consts::TAU / 4_294_967_296.0)).sin_cos();
    let h2 = splitmix(h);
    let (shift_x, shift_y) = (unit(h2 as u32), unit((h2 >> 32) as u32));
    let n = tab.n;
    let lens = &tab.lens[t * n..(t + 1) * n];
    let foot = &tab.foot[t * n..(t + 1) * n];
    let sampled = s.footprint == Footprint::Sampled;
    let shape = s.aperture.geometry();
    let square = &tab.square[t * n..(t + 1) * n];
    // A polygon is sampled by its own map, the square shifted per pixel (a rotation would
    // turn the shape).
    let h3 = splitmix(h2);
    let (lens_x, lens_y) = (unit(h3 as u32), unit((h3 >> 32) as u32));
    let mut acc = [0f64; 3];
    let mut half = [0f64; 3];
    // Sums of the lens samples' transmission (all 1 for the disc).
    let (mut wsum, mut whalf) = (0f64, 0f64);
    // A cat's eye: the pixel's second circle (every plane along a ray sees the same lens).
    let cut = vignette.map(|v| v.cut(px, py));
    for i in 0..n {
        if i == n / 2 {
            half = acc;
            whalf = wsum;
        }
        let [lx, ly] = lens[i];
        let (mut ax, mut ay) = (cos * lx - sin * ly, sin * lx + cos * ly);
        // A point behind the focal plane paints `K·|d|·a` around itself (rows down): the
        // shape's y, up, is -ay.
        let polygon = shape.and_then(|g| g.sample((square[i][0] + lens_x).fract(), (square[i][1] + lens_y).fract()));
        if let Some((x, y)) = polygon {
            (ax, ay) = (x, -y);
        }
        let wt = match (shape, polygon) {
            (Some(g), None) => g.transmission(ax, -ay),
            // A bubble's radial profile (1 without one).
            (Some(g), Some((x, y))) => g.intensity(x, y),
            _ => 1.0,
        };
        // The lens point in the shape's frame (y up) outside the pixel's cut: clipped.
        let wt = match cut {
            Some([vx, vy]) if (ax - vx) * (ax - vx) + (-ay - vy) * (-ay - vy) > 1.0 => 0.0,
            _ => wt,
        };
        wsum += wt as f64;
        if wt == 0.0 {
            continue;
        }
        let (sx, sy) = if sampled {
            let [fx, fy] = foot[i];
            (px + (fx + shift_x).fract(), py + (fy + shift_y).fract())
        } else {
            (px + 0.5, py + 0.5)
        };
        let mut tr = 1f32;
        let mut c = [0f32; 3];
        for (p, &k) in planes.iter().zip(ks) {
            let (qx, qy) = (sx + k * ax, sy + k * ay);
            let q = p.sample(qx, qy, s.footprint);
            for ch in 0..3 {
                c[ch] += tr * q[ch];
            }
            tr *= 1.0 - q[3];
            if tr <= 1e-7 {
                break;
            }
        }
        for ch in 0..3 {
            acc[ch] += (wt * c[ch]) as f64;
        }
    }
    let (inv, inv_half) = (1.0 / wsum.max(1e-12), 1.0 / whalf.max(1e-12));
    [
        (acc[0] * inv) as f32,
        (acc[1] * inv) as f32,
        (acc[2] * inv) as f32,
        (half[0] * inv_half) as f32,
        (half[1] * inv_half) as f32,
        (half[2] * inv_half) as f32,
    ]
}

/// The first two dimensions of the Sobol' sequence: a (0,2)-sequence in base 2, as 32-bit
/// fixed-point fractions.
#[inline(always)]
fn sobol02(mut i: u32) -> (u32, u32) {
    let x = i.reverse_bits();
    let mut y = 0u32;
    let mut v = 1u32 << 31;
    while i != 0 {
        if i & 1 == 1 {
            y ^= v;
        }
        i >>= 1;
        v ^= v >> 1;
    }
    (x, y)
}

/// 32-bit fixed point to [0, 1).
#[inline(always)]
fn unit(v: u32) -> f32 {
    // 24 bits: every value is exact in f32 and strictly below 1.
    (v >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Shirley–Chiu concentric map from the unit square to the unit disk.
#[inline(always)]
pub fn concentric_disk(u: f32, v: f32) -> (f32, f32) {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    use std::f32::consts::FRAC_PI_4;
    let (r, phi) = if a.abs() > b.abs() { (a, FRAC_PI_4 * (b / a)) } else { (b, 2.0 * FRAC_PI_4 - FRAC_PI_4 * (a / b)) };
    (r * phi.cos(), r * phi.sin())
}

#[inline(always)]
pub(crate) fn splitmix(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sobol_prefixes_are_stratified() {
        // Every 2^m prefix has one point in each 1/2^m × 1 ... 1 × 1/2^m elementary box.
        let m = 6;
        let n = 1u32 << m;
        for split in 0..=m {
            let mut seen = std::collections::HashSet::new();
            for i in 0..n {
                let (x, y) = sobol02(i);
                let top = |v: u32, bits: u32| if bits == 0 { 0 } else { v >> (32 - bits) };
                seen.insert((top(x, split), top(y, m - split)));
            }
            assert_eq!(seen.len(), n as usize, "split {split}");
        }
    }

    #[test]
    fn concentric_map_stays_in_disk_and_preserves_area() {
        let mut inside = 0;
        let n = 200;
        for i in 0..n {
            for j in 0..n {
                let (x, y) = concentric_disk((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32);
                assert!(x * x + y * y <= 1.0 + 1e-5);
                if x * x + y * y <= 0.25 {
                    inside += 1;
                }
            }
        }
        // Area preserving: a quarter of the samples land within radius 1/2.
        assert!((inside as f64 / (n * n) as f64 - 0.25).abs() < 0.01);
    }

    #[test]
    fn mixed_disparity_layer_is_refused_with_its_name() {
        let mut data = vec![0.5f32; 4 * 5];
        data[4] = 0.2;
        data[9] = 0.9;
        let l = Layer::new(Image::from_vec(2, 2, 5, data).unwrap(), "x").unwrap();
        let e = Plane::from_layer(&l, "fg.exr").unwrap_err().to_string();
        assert!(e.contains("fg.exr") && e.contains("one layer per depth"), "{e}");
    }
}
