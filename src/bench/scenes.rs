//! Random layered scenes for the benchmark, and the per-plane split of the shared ground-truth
//! scenes.
//!
//! A generated scene is a stack of 2–5 fronto-parallel planes (front first): 1–4 foreground
//! planes (soft-edged blobs, rotated cards, stars, or bundles of thin bars 1–4 px wide, often
//! crossing the frame border) in front of an opaque background (one plane, or two with a step).
//! Textures are procedural (noise, stripes, checks, bricks, rings) or crops of the user's photos.
//! Bright HDR highlights (radius 1.5–3 px, radiance 5–50) sit on the background, many of them
//! right behind foreground edges. The planes are `margin` px larger than the frame on every
//! side, so the traced ground truth sees real off-frame content; the methods get the frame only.
//!
//! Every plane is stored as pixel values (box-filtered: shapes are antialiased by 4×4
//! supersampling of their coverage), as the tracer assumes
//! (see [`super::trace`], "Pixel footprint").

use super::groundtruth::GtScene;
use super::trace::{Plane, splitmix};
use crate::error::Result;
use crate::image::Image;
use crate::render::Layer;
use crate::stages::inpaint::{TeleaOptions, inpaint_telea};

/// Small deterministic PRNG (SplitMix64).
#[derive(Clone, Debug)]
pub struct Rng(u64);

impl Rng {
    /// A generator seeded with `seed` (equal seeds give equal sequences).
    pub fn new(seed: u64) -> Self {
        Rng(splitmix(seed))
    }
    /// The next 64 uniformly distributed bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        splitmix(self.0)
    }
    /// Uniform in [0, 1).
    pub fn f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }
    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f32()
    }
    /// Uniform integer in `lo..=hi`.
    pub fn int(&mut self, lo: usize, hi: usize) -> usize {
        lo + (self.next_u64() % (hi - lo + 1) as u64) as usize
    }
    /// True with probability `p` (0 never, 1 always).
    pub fn chance(&mut self, p: f32) -> bool {
        self.f32() < p
    }
}

/// Where the focal plane is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FocusKind {
    /// On the front-most foreground plane (disparity 1).
    Foreground,
    /// On the background (disparity 0).
    Background,
    /// On the second-nearest foreground plane if there is one, else at disparity 0.5.
    Between,
}

impl FocusKind {
    /// The name used in reports and scene names: "focus_fg", "focus_bg", "focus_mid".
    pub fn name(self) -> &'static str {
        match self {
            FocusKind::Foreground => "focus_fg",
            FocusKind::Background => "focus_bg",
            FocusKind::Between => "focus_mid",
        }
    }
}

/// One plane of a generated scene (padded size).
#[derive(Clone, Debug)]
pub struct SynthPlane {
    /// The plane's name in reports ("bg" for the background).
    pub name: String,
    /// True for foreground planes, false for the opaque background plane(s).
    pub foreground: bool,
    /// Straight linear RGB.
    pub rgb: Image,
    /// Coverage in [0, 1] (one channel); all 1 for the background.
    pub alpha: Image,
    /// Normalized disparity of the plane, constant over it (0 far … 1 near).
    pub disparity: f32,
}

/// A generated scene with its lens setting.
#[derive(Clone, Debug)]
pub struct SynthScene {
    /// Scene name, "sNNN" by generation index.
    pub name: String,
    /// Output width, pixels (the planes are `2·margin` wider).
    pub width: usize,
    /// Output height, pixels (the planes are `2·margin` taller).
    pub height: usize,
    /// Off-frame content on each side of the planes, px.
    pub margin: usize,
    /// Front first.
    pub planes: Vec<SynthPlane>,
    /// Blur strength K (pixels of CoC radius per unit of disparity), chosen to give `max_coc`.
    pub blur: f32,
    /// Focal plane, normalized disparity.
    pub focus: f32,
    /// Which plane the focus is on.
    pub focus_kind: FocusKind,
    /// Largest CoC radius in the scene, px.
    pub max_coc: f32,
    /// True when a foreground plane is a bundle of thin bars (1–4 px wide).
    pub thin: bool,
    /// True when the background carries small HDR highlights (radiance 5–50, radius 1.5–3 px).
    pub highlights: bool,
    /// The far background plane's texture before its highlights (padded size).
    pub bg_texture: Image,
    /// The far background's highlights, in painting order.
    pub bg_highlights: Vec<Highlight>,
}

/// Signed distance (px, negative inside) of a shape at a point.
#[derive(Clone, Debug)]
enum Shape {
    Ellipse { cx: f32, cy: f32, rx: f32, ry: f32, rot: f32 },
    Card { cx: f32, cy: f32, hx: f32, hy: f32, rot: f32, round: f32 },
    Star { cx: f32, cy: f32, r: f32, harmonics: Vec<(f32, f32, f32)> },
    Bar { x0: f32, y0: f32, x1: f32, y1: f32, half_width: f32 },
}

impl Shape {
    fn sdf(&self, x: f32, y: f32) -> f32 {
        match self {
            Shape::Ellipse { cx, cy, rx, ry, rot } => {
                let (u, v) = rotate(x - cx, y - cy, -rot);
                let k = ((u / rx).powi(2) + (v / ry).powi(2)).sqrt();
                // First-order distance: (k - 1) / |∇k|.
                let g = ((u / (rx * rx)).powi(2) + (v / (ry * ry)).powi(2)).sqrt() / k.max(1e-6);
                (k - 1.0) / g.max(1e-6)
            }
            Shape::Card { cx, cy, hx, hy, rot, round } => {
                let (u, v) = rotate(x - cx, y - cy, -rot);
                let (qx, qy) = (u.abs() - (hx - round), v.abs() - (hy - round));
                let outside = (qx.max(0.0).powi(2) + qy.max(0.0).powi(2)).sqrt();
                outside + qx.max(qy).min(0.0) - round
            }
            Shape::Star { cx, cy, r, harmonics } => {
                let (u, v) = (x - cx, y - cy);
                let theta = v.atan2(u);
                let rr = r * (1.0 + harmonics.iter().map(|&(k, a, p)| a * (k * theta + p).sin()).sum::<f32>());
                ((u * u + v * v).sqrt() - rr) * 0.8
            }
            Shape::Bar { x0, y0, x1, y1, half_width } => {
                let (dx, dy) = (x1 - x0, y1 - y0);
                let t = (((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy).max(1e-9)).clamp(0.0, 1.0);
                let (px, py) = (x0 + t * dx - x, y0 + t * dy - y);
                (px * px + py * py).sqrt() - half_width
            }
        }
    }
}

fn rotate(x: f32, y: f32, a: f32) -> (f32, f32) {
    let (s, c) = a.sin_cos();
    (c * x - s * y, s * x + c * y)
}

/// Coverage of the union of `shapes` per pixel, 4×4 supersampled; `soft` > 0 feathers the
/// edge over that many px (a semi-transparent rim).
fn coverage(w: usize, h: usize, shapes: &[Shape], soft: f32) -> Image {
    let mut a = Image::new(w, h, 1);
    const S: usize = 4;
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0f32;
            for sy in 0..S {
                for sx in 0..S {
                    let (px, py) = (x as f32 + (sx as f32 + 0.5) / S as f32, y as f32 + (sy as f32 + 0.5) / S as f32);
                    let d = shapes.iter().map(|s| s.sdf(px, py)).fold(f32::INFINITY, f32::min);
                    acc += if soft > 0.0 {
                        let t = (0.5 - d / soft).clamp(0.0, 1.0);
                        t * t * (3.0 - 2.0 * t)
                    } else if d <= 0.0 {
                        1.0
                    } else {
                        0.0
                    };
                }
            }
            a.data[y * w + x] = acc / (S * S) as f32;
        }
    }
    a
}

/// Smooth value noise in [0, 1] with `octaves` octaves, base cell `cell` px.
fn value_noise(rng: &mut Rng, w: usize, h: usize, cell: f32, octaves: usize) -> Vec<f32> {
    let mut out = vec![0f32; w * h];
    let mut amp_total = 0.0;
    let mut amp = 1.0;
    let mut cell = cell.max(2.0);
    for _ in 0..octaves {
        let gw = (w as f32 / cell).ceil() as usize + 2;
        let gh = (h as f32 / cell).ceil() as usize + 2;
        let grid: Vec<f32> = (0..gw * gh).map(|_| rng.f32()).collect();
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 / cell, y as f32 / cell);
                let (ix, iy) = (fx as usize, fy as usize);
                let (tx, ty) = (fx - ix as f32, fy - iy as f32);
                let (tx, ty) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
                let g = |i: usize, j: usize| grid[j * gw + i];
                let top = g(ix, iy) + (g(ix + 1, iy) - g(ix, iy)) * tx;
                let bot = g(ix, iy + 1) + (g(ix + 1, iy + 1) - g(ix, iy + 1)) * tx;
                out[y * w + x] += amp * (top + (bot - top) * ty);
            }
        }
        amp_total += amp;
        amp *= 0.5;
        cell *= 0.5;
        if cell < 1.5 {
            break;
        }
    }
    out.iter_mut().for_each(|v| *v /= amp_total);
    out
}

fn random_color(rng: &mut Rng) -> [f32; 3] {
    let base = rng.range(0.05, 0.8);
    [0, 1, 2].map(|_| (base * rng.range(0.3, 1.3)).clamp(0.01, 0.95))
}

/// A procedural texture (linear RGB) of `w × h`, or a crop of one of `photos`.
fn texture(rng: &mut Rng, w: usize, h: usize, photos: &[Image]) -> Image {
    if !photos.is_empty() && rng.chance(0.8) {
        let k = rng.int(0, photos.len() - 1);
        return photo_crop(rng, w, h, &photos[k]);
    }
    let (c0, c1) = (random_color(rng), random_color(rng));
    let kind = rng.int(0, 4);
    let mut img = Image::new(w, h, 3);
    let scale = (w.min(h) as f32 / 256.0).max(0.25);
    let mix = |t: f32| [0, 1, 2].map(|c| c0[c] + (c1[c] - c0[c]) * t);
    let cell = rng.range(6.0, 40.0) * scale;
    let noise = value_noise(rng, w, h, cell, 5);
    let period = rng.range(4.0, 24.0) * scale.max(0.5);
    let (s, c) = rng.range(0.0, std::f32::consts::PI).sin_cos();
    let (bw, bh) = (rng.range(10.0, 30.0) * scale.max(0.5), rng.range(5.0, 14.0) * scale.max(0.5));
    let (ox, oy) = (rng.range(0.0, w as f32), rng.range(0.0, h as f32));
    for y in 0..h {
        for x in 0..w {
            let (xf, yf) = (x as f32 + 0.5, y as f32 + 0.5);
            let n = noise[y * w + x];
            let t = match kind {
                0 => n,
                1 => {
                    // Antialiased stripes with noise modulation.
                    let u = (c * xf + s * yf) / period;
                    let tri = 2.0 * (u - (u + 0.5).floor()).abs();
                    (0.5 + (tri - 0.5) * 4.0).clamp(0.0, 1.0) * 0.8 + 0.2 * n
                }
                2 => {
                    let (u, v) = ((c * xf + s * yf) / period, (-s * xf + c * yf) / period);
                    let chk = ((u.floor() + v.floor()) as i64).rem_euclid(2) as f32;
                    0.75 * chk + 0.25 * n
                }
                3 => {
                    let row = (yf / bh).floor();
                    let shift = if row as i64 % 2 == 0 { 0.0 } else { bw * 0.5 };
                    let (u, v) = (((xf + shift) / bw).fract() * bw, (yf / bh).fract() * bh);
                    let mortar = u < 1.5 * scale.max(0.6) || v < 1.5 * scale.max(0.6);
                    if mortar { 0.05 } else { 0.5 + 0.5 * n }
                }
                _ => {
                    let r = ((xf - ox).powi(2) + (yf - oy).powi(2)).sqrt() / period;
                    0.5 + 0.35 * (r * std::f32::consts::TAU).sin() + 0.15 * (n - 0.5)
                }
            };
            let col = mix(t.clamp(0.0, 1.0));
            img.pixel_mut(x, y).copy_from_slice(&col);
        }
    }
    img
}

/// A random crop of `photo` resampled (box filter) to `w × h`.
fn photo_crop(rng: &mut Rng, w: usize, h: usize, photo: &Image) -> Image {
    let scale = (photo.width as f32 / w as f32).min(photo.height as f32 / h as f32) * rng.range(0.4, 1.0);
    let (cw, ch) = (w as f32 * scale, h as f32 * scale);
    let (x0, y0) = (rng.range(0.0, (photo.width as f32 - cw).max(0.0)), rng.range(0.0, (photo.height as f32 - ch).max(0.0)));
    let mut img = Image::new(w, h, 3);
    let taps = scale.ceil().clamp(1.0, 4.0) as usize;
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0f32; 3];
            for sy in 0..taps {
                for sx in 0..taps {
                    let px = (x0 + (x as f32 + (sx as f32 + 0.5) / taps as f32) * scale) as usize;
                    let py = (y0 + (y as f32 + (sy as f32 + 0.5) / taps as f32) * scale) as usize;
                    let p = photo.pixel(px.min(photo.width - 1), py.min(photo.height - 1));
                    for c in 0..3 {
                        acc[c] += p[c.min(photo.channels - 1)];
                    }
                }
            }
            let n = (taps * taps) as f32;
            img.pixel_mut(x, y).copy_from_slice(&acc.map(|v| (v / n).clamp(0.0, 1.0)));
        }
    }
    img
}

/// One small HDR highlight painted onto the background: an antialiased disc.
#[derive(Clone, Copy, Debug)]
pub struct Highlight {
    /// Centre in padded-plane pixels.
    pub cx: f32,
    /// Centre in padded-plane pixels.
    pub cy: f32,
    /// Radius, px.
    pub r: f32,
    /// Linear radiance of the disc (times `tint`).
    pub radiance: f32,
    /// Per-channel factor in [0.7, 1].
    pub tint: [f32; 3],
}

/// Draws one highlight per centre (radius, radiance, tint).
fn draw_highlights(rng: &mut Rng, centres: &[(f32, f32)]) -> Vec<Highlight> {
    centres
        .iter()
        .map(|&(cx, cy)| {
            let r = rng.range(1.5, 3.0);
            let radiance = rng.range(5.0, 50.0);
            let tint = [rng.range(0.7, 1.0), rng.range(0.7, 1.0), rng.range(0.7, 1.0)];
            Highlight { cx, cy, r, radiance, tint }
        })
        .collect()
}

/// Paints `highlights` onto `rgb` in order, each over what is there.
fn paint_highlights(rgb: &mut Image, highlights: &[Highlight]) {
    for h in highlights {
        for (x, y, a) in coverage_disk(h.cx, h.cy, h.r) {
            if x < rgb.width && y < rgb.height {
                let p = rgb.pixel_mut(x, y);
                for (v, t) in p.iter_mut().zip(h.tint) {
                    *v = *v * (1.0 - a) + h.radiance * t * a;
                }
            }
        }
    }
}

fn coverage_disk(cx: f32, cy: f32, r: f32) -> Vec<(usize, usize, f32)> {
    let mut v = Vec::new();
    let (x0, x1) = ((cx - r - 1.0).floor().max(0.0) as usize, (cx + r + 1.0).ceil().max(0.0) as usize);
    let (y0, y1) = ((cy - r - 1.0).floor().max(0.0) as usize, (cy + r + 1.0).ceil().max(0.0) as usize);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let mut n = 0;
            for s in 0..16 {
                let (px, py) = (x as f32 + ((s % 4) as f32 + 0.5) / 4.0, y as f32 + ((s / 4) as f32 + 0.5) / 4.0);
                if (px - cx).powi(2) + (py - cy).powi(2) <= r * r {
                    n += 1;
                }
            }
            if n > 0 {
                v.push((x, y, n as f32 / 16.0));
            }
        }
    }
    v
}

/// Random foreground shapes for one plane, centred inside the frame `[m, m+w) × [m, m+h)`.
fn fg_shapes(rng: &mut Rng, w: usize, h: usize, m: usize, bars: bool) -> Vec<Shape> {
    let (fw, fh) = (w as f32, h as f32);
    let size = fw.min(fh);
    let m = m as f32;
    let mut v = Vec::new();
    if bars {
        for _ in 0..rng.int(2, 5) {
            let (cx, cy) = (m + rng.range(0.0, fw), m + rng.range(0.0, fh));
            let ang = rng.range(0.0, std::f32::consts::PI);
            let len = rng.range(0.4, 1.4) * size;
            let (dx, dy) = (ang.cos() * len * 0.5, ang.sin() * len * 0.5);
            let width = rng.range(1.0, 4.0);
            v.push(Shape::Bar { x0: cx - dx, y0: cy - dy, x1: cx + dx, y1: cy + dy, half_width: width * 0.5 });
        }
        return v;
    }
    for _ in 0..rng.int(1, 2) {
        let (cx, cy) = (m + rng.range(0.1, 0.9) * fw, m + rng.range(0.1, 0.9) * fh);
        let r = rng.range(0.12, 0.35) * size;
        let rot = rng.range(0.0, std::f32::consts::PI);
        v.push(match rng.int(0, 2) {
            0 => Shape::Ellipse { cx, cy, rx: r, ry: r * rng.range(0.5, 1.0), rot },
            1 => Shape::Card { cx, cy, hx: r, hy: r * rng.range(0.3, 1.0), rot, round: rng.range(0.0, 0.3) * r },
            _ => Shape::Star {
                cx,
                cy,
                r,
                harmonics: (0..rng.int(1, 3)).map(|_| (rng.int(2, 7) as f32, rng.range(0.05, 0.25), rng.range(0.0, 6.3))).collect(),
            },
        });
    }
    v
}

/// Generates scene `index` of a benchmark run with `seed`: `width × height` frame, textures
/// from `photos` (linear RGB) when given, else procedural.
pub fn generate(seed: u64, index: usize, width: usize, height: usize, photos: &[Image]) -> SynthScene {
    let mut rng = Rng::new(seed.wrapping_mul(0x1000_0000_01B3) ^ (index as u64).wrapping_mul(0x9E37_79B9));
    let scale = width.min(height) as f32 / 256.0;
    // Largest CoC: log-uniform over small to large blur, in px at this size.
    let max_coc = (rng.range(2.0f32.ln(), 24.0f32.ln()).exp() * scale).max(1.0);
    let margin = max_coc.ceil() as usize + 3;
    let (pw, ph) = (width + 2 * margin, height + 2 * margin);
    let focus_kind = [FocusKind::Foreground, FocusKind::Background, FocusKind::Between][index % 3];
    let total = rng.int(2, 5);
    let bg_step = total >= 3 && rng.chance(0.25);
    let n_fg = total - 1 - bg_step as usize;
    let thin = rng.chance(0.5);
    let highlights = rng.chance(0.7);

    // Disparities: front plane 1, others spread in (0.35, 0.9), background 0 (and a step).
    let mut fg_d = vec![1.0f32];
    while fg_d.len() < n_fg {
        let d = rng.range(0.35, 0.9);
        if fg_d.iter().all(|&o| (o - d).abs() > 0.08) {
            fg_d.push(d);
        }
    }
    fg_d.sort_by(|a, b| b.total_cmp(a));

    let mut planes = Vec::new();
    let thin_plane = if thin { rng.int(0, n_fg - 1) } else { usize::MAX };
    for (k, &d) in fg_d.iter().enumerate() {
        let bars = k == thin_plane || (thin && rng.chance(0.2));
        let shapes = fg_shapes(&mut rng, width, height, margin, bars);
        let soft = if !bars && rng.chance(0.4) { rng.range(2.0, 6.0) * scale.max(0.5) } else { 0.0 };
        let alpha = coverage(pw, ph, &shapes, soft);
        let rgb = texture(&mut rng, pw, ph, photos);
        planes.push(SynthPlane { name: format!("fg{k}{}", if bars { "_bars" } else { "" }), foreground: true, rgb, alpha, disparity: d });
    }

    // Background: far plane everywhere, optionally a nearer step plane over one side.
    let bg_texture = texture(&mut rng, pw, ph, photos);
    let mut bg = bg_texture.clone();
    let mut bg_highlights = Vec::new();
    if highlights {
        // Foreground edges in the frame: pixels of partial combined coverage.
        let mut edge = Vec::new();
        for y in margin..margin + height {
            for x in margin..margin + width {
                let t: f32 = planes.iter().map(|p| 1.0 - p.alpha.data[y * pw + x]).product();
                if t > 0.05 && t < 0.95 {
                    edge.push((x as f32 + 0.5, y as f32 + 0.5));
                }
            }
        }
        let n = rng.int(6, 14);
        let mut centres = Vec::new();
        for i in 0..n {
            if i % 3 != 2 && !edge.is_empty() {
                let (x, y) = edge[rng.int(0, edge.len() - 1)];
                centres.push((x + rng.range(-3.0, 3.0) * scale.max(0.5), y + rng.range(-3.0, 3.0) * scale.max(0.5)));
            } else {
                centres.push((rng.range(0.0, pw as f32), rng.range(0.0, ph as f32)));
            }
        }
        bg_highlights = draw_highlights(&mut rng, &centres);
        paint_highlights(&mut bg, &bg_highlights);
    }
    if bg_step {
        let shape = Shape::Card {
            cx: margin as f32 + rng.range(0.0, 1.0) * width as f32,
            cy: -(ph as f32),
            hx: width as f32 * rng.range(0.2, 0.5),
            hy: 3.0 * ph as f32,
            rot: rng.range(-0.3, 0.3),
            round: 0.0,
        };
        let alpha = coverage(pw, ph, &[shape], 0.0);
        let rgb = texture(&mut rng, pw, ph, photos);
        planes.push(SynthPlane { name: "bg_step".into(), foreground: false, rgb, alpha, disparity: rng.range(0.12, 0.28) });
    }
    planes.push(SynthPlane { name: "bg".into(), foreground: false, rgb: bg, alpha: Image::filled(pw, ph, 1, 1.0), disparity: 0.0 });

    let ds: Vec<f32> = planes.iter().map(|p| p.disparity).collect();
    let focus = match focus_kind {
        FocusKind::Foreground => 1.0,
        FocusKind::Background => 0.0,
        FocusKind::Between => {
            if fg_d.len() >= 2 {
                fg_d[1]
            } else {
                0.5
            }
        }
    };
    let dmax = ds.iter().map(|d| (d - focus).abs()).fold(0.0, f32::max);
    let blur = max_coc / dmax.max(1e-3);
    SynthScene {
        name: format!("s{index:03}"),
        width,
        height,
        margin,
        planes,
        blur,
        focus,
        focus_kind,
        max_coc: crate::render::lens::coc_radius(dmax, blur),
        thin,
        highlights,
        bg_texture,
        bg_highlights,
    }
}

/// Front-to-back over-composite of straight-colour planes: (premultiplied colour, alpha).
fn over(planes: &[(&Image, &Image)]) -> (Image, Image) {
    let (w, h) = (planes[0].0.width, planes[0].0.height);
    let mut rgb = Image::new(w, h, 3);
    let mut alpha = Image::new(w, h, 1);
    for i in 0..w * h {
        let mut t = 1f32;
        for (c, a) in planes {
            let a = a.data[i];
            for k in 0..3 {
                rgb.data[i * 3 + k] += t * a * c.data[i * 3 + k];
            }
            t *= 1.0 - a;
        }
        alpha.data[i] = 1.0 - t;
    }
    (rgb, alpha)
}

/// Divides premultiplied colour by alpha (0 where alpha is ~0).
fn unpremultiply(rgb: &mut Image, alpha: &Image) {
    for (px, &a) in rgb.data.chunks_exact_mut(3).zip(&alpha.data) {
        for c in px {
            *c = if a > 1e-4 { *c / a } else { 0.0 };
        }
    }
}

/// Downsampling factor of [`realistic_depth`].
pub const REALISTIC_DEPTH_FACTOR: usize = 4;
/// Gaussian σ (pixels, full resolution) of [`realistic_depth`].
pub const REALISTIC_DEPTH_SIGMA: f32 = 1.5;

/// A disparity map as a depth estimator gives it (issue 12's "realistic depth"): averaged
/// over 4x4 blocks (area; partial blocks at the right and bottom borders average what they
/// hold), upsampled bilinearly back to the frame, then blurred with a Gaussian of σ = 1.5 px.
/// Its edges are no longer on the photo's. Allocates a few planes.
pub fn realistic_depth(d: &Image) -> Image {
    let f = REALISTIC_DEPTH_FACTOR;
    let (w, h) = (d.width, d.height);
    let (sw, sh) = (w.div_ceil(f), h.div_ceil(f));
    let mut small = Image::new(sw, sh, 1);
    for by in 0..sh {
        for bx in 0..sw {
            let (mut sum, mut n) = (0f64, 0usize);
            for y in by * f..((by + 1) * f).min(h) {
                for x in bx * f..((bx + 1) * f).min(w) {
                    sum += d.data[y * w + x] as f64;
                    n += 1;
                }
            }
            small.data[by * sw + bx] = (sum / n as f64) as f32;
        }
    }
    crate::stages::mask::gaussian_blur(&small.resized(w, h), REALISTIC_DEPTH_SIGMA)
}

/// The renderer's inputs for one scene, cropped to the frame.
#[derive(Clone, Debug)]
pub struct SceneInputs {
    /// All-in-focus image (linear RGB).
    pub aif: Image,
    /// Normalized disparity of the front-most surface at each pixel centre.
    pub disparity: Image,
    /// Combined foreground coverage.
    pub matte: Image,
    /// `disparity` as a depth estimator would give it ([`realistic_depth`]).
    pub realistic_disparity: Image,
    /// Exact two layers: all foreground planes composited, and the background.
    pub two_layers: Vec<Layer<'static>>,
    /// One layer per plane, each at its constant disparity.
    pub plane_layers: Vec<Layer<'static>>,
}

impl SynthScene {
    /// The planes as the tracer takes them (padded: trace with [`Self::window`]).
    pub fn trace_planes(&self) -> Vec<Plane> {
        self.planes.iter().map(|p| Plane::from_rgb_alpha(&p.rgb, &p.alpha, p.disparity)).collect()
    }

    /// The output frame within the padded planes: `width × height` at (`margin`, `margin`).
    pub fn window(&self) -> super::trace::Window {
        super::trace::Window { x0: self.margin, y0: self.margin, width: self.width, height: self.height }
    }

    /// The same scene without the far background's highlights that the photo cannot show:
    /// those whose every covered pixel lies inside the frame, fully behind nearer planes.
    /// Its [`Self::inputs`] give the same photo, depth map and matte bit for bit, so no method
    /// fed those can tell the two scenes apart, while a lens sees around the cover: how far
    /// apart the two traced truths lie bounds what any single-photo method can score (issue
    /// 12's diagnosis). Returns the twin and how many highlights it lacks.
    pub fn without_hidden_highlights(&self) -> (SynthScene, usize) {
        let (m, pw) = (self.margin, self.planes[0].alpha.width);
        let nearer = &self.planes[..self.planes.len() - 1];
        let hidden = |x: usize, y: usize| {
            let inside = x >= m && y >= m && x < m + self.width && y < m + self.height;
            inside && nearer.iter().any(|p| p.alpha.data[y * pw + x] >= 1.0)
        };
        let kept: Vec<Highlight> =
            self.bg_highlights.iter().copied().filter(|h| !coverage_disk(h.cx, h.cy, h.r).iter().all(|&(x, y, _)| hidden(x, y))).collect();
        let mut twin = self.clone();
        let bg = twin.planes.last_mut().expect("background plane");
        bg.rgb = self.bg_texture.clone();
        paint_highlights(&mut bg.rgb, &kept);
        twin.bg_highlights = kept;
        let removed = self.bg_highlights.len() - twin.bg_highlights.len();
        (twin, removed)
    }

    /// Builds every method's inputs from the planes.
    #[allow(clippy::needless_range_loop)]
    pub fn inputs(&self) -> Result<SceneInputs> {
        let (w, h, m) = (self.width, self.height, self.margin);
        let cropped: Vec<(Image, Image, f32, bool)> =
            self.planes.iter().map(|p| (p.rgb.crop(m, m, w, h), p.alpha.crop(m, m, w, h), p.disparity, p.foreground)).collect();
        let refs: Vec<(&Image, &Image)> = cropped.iter().map(|(c, a, _, _)| (c, a)).collect();
        let (aif, _) = over(&refs);
        // Pixel-centre labels: the front-most plane that covers at least half the pixel.
        let mut disparity = Image::new(w, h, 1);
        for i in 0..w * h {
            let d = cropped.iter().find(|(_, a, _, _)| a.data[i] >= 0.5).map(|p| p.2).unwrap_or(cropped.last().expect("planes").2);
            disparity.data[i] = d;
        }
        let fg: Vec<&(Image, Image, f32, bool)> = cropped.iter().filter(|p| p.3).collect();
        let bgp: Vec<&(Image, Image, f32, bool)> = cropped.iter().filter(|p| !p.3).collect();
        let (mut fg_rgb, matte) = over(&fg.iter().map(|(c, a, _, _)| (c, a)).collect::<Vec<_>>());
        unpremultiply(&mut fg_rgb, &matte);
        // Foreground disparity: contribution-weighted mean of the planes that cover the pixel,
        // Telea-extended where nothing does (as `GtScene::exact_layers`).
        let mut fg_d = Image::new(w, h, 1);
        let mut unknown = vec![true; w * h];
        for i in 0..w * h {
            let (mut t, mut s, mut ws) = (1f32, 0f32, 0f32);
            for (_, a, d, _) in &fg {
                let c = t * a.data[i];
                s += c * d;
                ws += c;
                t *= 1.0 - a.data[i];
            }
            if ws > 1e-6 {
                fg_d.data[i] = s / ws;
                unknown[i] = false;
            }
        }
        if unknown.iter().any(|&u| !u) && unknown.iter().any(|&u| u) {
            inpaint_telea(&mut fg_d, &unknown, TeleaOptions::new(5.0))?;
        }
        let (bg_rgb, _) = over(&bgp.iter().map(|(c, a, _, _)| (c, a)).collect::<Vec<_>>());
        let mut bg_d = Image::new(w, h, 1);
        for i in 0..w * h {
            bg_d.data[i] = bgp.iter().find(|(_, a, _, _)| a.data[i] >= 0.5).map(|p| p.2).unwrap_or(bgp.last().expect("background").2);
        }
        let opaque = Image::filled(w, h, 1, 1.0);
        let two_layers = vec![
            Layer::from_parts(&fg_rgb, &matte, &fg_d, "synthetic foreground")?,
            Layer::from_parts(&bg_rgb, &opaque, &bg_d, "synthetic background")?,
        ];
        let plane_layers = cropped
            .iter()
            .zip(&self.planes)
            .map(|((c, a, d, _), p)| Layer::from_parts(c, a, &Image::filled(w, h, 1, *d), &p.name))
            .collect::<Result<Vec<_>>>()?;
        let realistic_disparity = realistic_depth(&disparity);
        Ok(SceneInputs { aif, disparity, matte, realistic_disparity, two_layers, plane_layers })
    }
}

/// Splits a shared ground-truth scene into one renderer layer per depth (front first), each
/// with a constant disparity: what the tracer takes, and the "depth-sliced" exact layers.
///
/// Foreground pixels are assigned to the depth labelled at their centre; antialiased edge
/// pixels whose centre is on the background go to the nearest labelled foreground pixel's
/// depth (within 3 px). Background depths (one, or two for a step) become opaque planes; a
/// farther background plane is filled with `bg.exr` where a nearer one hides it.
#[allow(clippy::needless_range_loop)]
pub fn gt_plane_layers(scene: &GtScene) -> Result<Vec<Layer<'static>>> {
    let (w, h) = (scene.bg.width, scene.bg.height);
    let n = w * h;
    let distinct = |vals: &mut Vec<f32>| {
        vals.sort_by(|a, b| b.total_cmp(a));
        vals.dedup_by(|a, b| (*a - *b).abs() < 1e-5);
    };
    let is_fg: Vec<bool> = (0..n).map(|i| scene.disparity.data[i] > scene.bg_disparity.data[i] + 1e-5).collect();
    let mut fg_levels: Vec<f32> = (0..n).filter(|&i| is_fg[i]).map(|i| scene.disparity.data[i]).collect();
    distinct(&mut fg_levels);
    let level_of = |d: f32, levels: &[f32]| levels.iter().position(|&l| (l - d).abs() < 1e-5).unwrap_or(0);
    let mut assign = vec![usize::MAX; n];
    for i in 0..n {
        if scene.alpha.data[i] <= 0.0 || fg_levels.is_empty() {
            continue;
        }
        if is_fg[i] {
            assign[i] = level_of(scene.disparity.data[i], &fg_levels);
            continue;
        }
        let (x, y) = ((i % w) as isize, (i / w) as isize);
        let mut best = (f32::INFINITY, 0usize);
        for dy in -3isize..=3 {
            for dx in -3isize..=3 {
                let (xx, yy) = (x + dx, y + dy);
                if xx < 0 || yy < 0 || xx >= w as isize || yy >= h as isize {
                    continue;
                }
                let j = yy as usize * w + xx as usize;
                let dist = (dx * dx + dy * dy) as f32;
                if is_fg[j] && dist < best.0 {
                    best = (dist, level_of(scene.disparity.data[j], &fg_levels));
                }
            }
        }
        assign[i] = best.1;
    }
    let mut layers = Vec::new();
    for (k, &d) in fg_levels.iter().enumerate() {
        let mut rgb = Image::new(w, h, 3);
        let mut a = Image::new(w, h, 1);
        for i in 0..n {
            if assign[i] == k {
                let al = scene.alpha.data[i];
                a.data[i] = al;
                for c in 0..3 {
                    rgb.data[i * 3 + c] = if al > 1e-4 { scene.fg.data[i * 3 + c] / al } else { 0.0 };
                }
            }
        }
        layers.push(Layer::from_parts(&rgb, &a, &Image::filled(w, h, 1, d), &format!("ground-truth foreground plane {k}"))?);
    }
    let mut bg_levels: Vec<f32> = scene.bg_disparity.data.clone();
    distinct(&mut bg_levels);
    for (k, &d) in bg_levels.iter().enumerate() {
        let last = k + 1 == bg_levels.len();
        let a = Image::from_vec(
            w,
            h,
            1,
            scene.bg_disparity.data.iter().map(|&b| if last || (b - d).abs() < 1e-5 { 1.0 } else { 0.0 }).collect(),
        )
        .expect("size");
        layers.push(Layer::from_parts(&scene.bg, &a, &Image::filled(w, h, 1, d), &format!("ground-truth background plane {k}"))?);
    }
    Ok(layers)
}
