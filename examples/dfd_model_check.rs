//! Which model of the photo as one opaque surface explains the traced targets of
//! `drbokeh bench --dfd` (issue 13's diagnosis). For each case, the true disparity, the
//! default estimate (`drbokeh dfd`'s defaults: physical profile, span render) and the
//! optimiser's constant start are rendered at
//! the target's focus and at the other focus by
//! - the renderer, the photo as one opaque layer over the disparity (what `dfd` fits and what
//!   the bench re-renders with),
//! - a plain gather in the same spirit ([`gather`], written here), with and without one
//!   geometric visibility test for the sources behind a target's surface, and
//! - the thin-lens tracer (`bench::trace`) over the photo cut into `BINS` depth slices, every
//!   pixel an opaque billboard at its disparity (replicate-padded beyond the frame): a ray is
//!   stopped by the first slice it meets, the geometric visibility of a 2.5D surface that the
//!   layered model approximates by coverage,
//!
//! and scored against the traced truth there: L1 (mean |Δ| of linear RGB, what the loss sees
//! first) and PSNR linear / sRGB, inside the bench's border. The slices hold no hidden content:
//! a ray that passes a depth edge behind a nearer slice finds nothing (black), so the traced
//! model also penalizes every depth edge a map puts where the photo shows none.
//!
//! With `PROBE=ITERS` it fits a map through the gather with the ray test instead ([`probe`])
//! and prints the disparity error and the re-render at the other focus of the truth, `dfd`'s
//! estimate and the fit (about 4 minutes a held-out scene at 200 iterations).
//!
//! With `RAY=1` it compares instead, per case, the true disparity, the span render's estimate
//! and the ray test's (`dfd --kernel ray`; with `AUTO=1` the default plan, `dfd::plan`):
//! disparity error and far-focus re-render, and the ray estimate's final loss. Knobs of that
//! mode: `SIDE=N` (cases at N px instead of 64), `FINEST=L` (the ray estimate on the photos
//! box-averaged by 2^L, resized back), `ITERS`, `LEVELS`, `LR`, `SMOOTH` (λ₂), `NOSPAN=1`
//! (skip the span estimate), `DUMP=DIR` (as .npy: the ray and true maps, the photo, the traced
//! truth at the other focus and both maps' re-renders there; the case's K and foci as
//! `SCENE_meta.json`).
//!
//! `cargo run --release --example dfd_model_check -- [SCENES] [GROUNDTRUTH_DIR] [BINS] [SPP]`
//! (defaults 8 generated scenes at 64x64 seed 1, no ground-truth folder, 64 bins, 256 spp).

use drbokeh::bench::dfd_eval::{DfdBenchOptions, DfdMethod, box_down, load_case, mae, rerender};
use drbokeh::bench::run::score;
use drbokeh::bench::trace::{Plane, TraceSettings, Window, trace};
use drbokeh::diff::dfd::{self, DfdOptions};
use drbokeh::{Image, Result};
use rayon::prelude::*;
use std::path::PathBuf;

/// The photo cut into `bins` slices of its disparity, front first, padded by `m` pixels.
fn slices(aif: &Image, d: &Image, bins: usize, m: usize) -> Vec<Plane> {
    let (w, h) = (aif.width, aif.height);
    let (pw, ph) = (w + 2 * m, h + 2 * m);
    let at = |x: usize, y: usize| (y.saturating_sub(m).min(h - 1)) * w + x.saturating_sub(m).min(w - 1);
    let bin = |v: f32| ((v.clamp(0.0, 1.0) * bins as f32) as usize).min(bins - 1);
    let mut planes = Vec::new();
    for b in (0..bins).rev() {
        let (mut sum, mut n) = (0f64, 0usize);
        let mut alpha = Image::new(pw, ph, 1);
        let mut rgb = Image::new(pw, ph, 3);
        for y in 0..ph {
            for x in 0..pw {
                let i = at(x, y);
                if bin(d.data[i]) == b {
                    alpha.data[y * pw + x] = 1.0;
                    rgb.data[(y * pw + x) * 3..(y * pw + x) * 3 + 3].copy_from_slice(&aif.data[i * 3..i * 3 + 3]);
                    sum += d.data[i] as f64;
                    n += 1;
                }
            }
        }
        if n > 0 {
            planes.push(Plane::from_rgb_alpha(&rgb, &alpha, (sum / n as f64) as f32));
        }
    }
    planes
}

/// A gather of the photo as one opaque layer in the physical profile's spirit, kept simple
/// for this check: each source `s` spreads over a uniform disk of radius `K·|d_s − f|` (a
/// one-pixel ramp edge, unit flux; in focus below half a pixel), the sources reaching target
/// `p` are grouped by depth against `d_p` (in front, same surface, behind: margin 0.1) and the
/// groups fill the pixel's coverage front to back, any deficit filled by normalizing. With
/// `geometric`, a source behind `p`'s surface counts only where the ray from `p` to it passes
/// that surface: the ray crosses depth `d_p` at `q = p + t·(s − p)`, `t = (d_p − f)/(d_s − f)`,
/// and is stopped when the map there is at least `d_p − 0.1` (bilinear, a 0.05 soft edge).
/// `soft` > 0 makes the group tests logistic of that width (for the probe's differences).
struct Gather<'a> {
    aif: &'a Image,
    blur: f32,
    focus: f32,
    geometric: bool,
    soft: f32,
}

impl Gather<'_> {
    fn radius(&self, v: f32) -> f32 {
        self.blur * (v - self.focus).abs()
    }

    fn cov(r: f32, rho: f32) -> f32 {
        if r < 0.5 { if rho < 0.5 { 1.0 } else { 0.0 } } else { (r + 0.5 - rho).clamp(0.0, 1.0) }
    }

    /// The window half-size that holds every source's disk.
    fn reach(&self, d: &Image) -> i64 {
        d.data.iter().map(|&v| self.radius(v)).fold(0.0f32, f32::max).ceil() as i64 + 1
    }

    /// The lattice sum of a disk of radius `r` (its flux).
    fn norm(r: f32, reach: i64) -> f32 {
        let mut n = 0.0;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                n += Self::cov(r, ((dx * dx + dy * dy) as f32).sqrt());
            }
        }
        n
    }

    fn norms(&self, d: &Image, reach: i64) -> Vec<f32> {
        d.data.iter().map(|&v| Self::norm(self.radius(v), reach)).collect()
    }

    /// 1 above 0 (a step, or a logistic of width `soft`).
    fn step(&self, x: f32) -> f32 {
        if self.soft > 0.0 { 1.0 / (1.0 + (-x / self.soft).exp()) } else { f32::from(x > 0.0) }
    }

    /// Target pixel `(px, py)` of the map `d` (sources' fluxes `norm`, window `reach`).
    fn pixel(&self, d: &Image, norm: &[f32], reach: i64, px: i64, py: i64) -> [f32; 3] {
        let (w, h) = (d.width, d.height);
        let at = |x: f32, y: f32| {
            let (x, y) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (fx, fy) = (x - x0 as f32, y - y0 as f32);
            let v = |xx: usize, yy: usize| d.data[yy * w + xx];
            (v(x0, y0) * (1.0 - fx) + v(x1, y0) * fx) * (1.0 - fy) + (v(x0, y1) * (1.0 - fx) + v(x1, y1) * fx) * fy
        };
        let dp = d.data[py as usize * w + px as usize];
        // Per group (in front, same surface, behind): coverage and colour.
        let mut g = [[0f64; 4]; 3];
        for sy in (py - reach).max(0)..=(py + reach).min(h as i64 - 1) {
            for sx in (px - reach).max(0)..=(px + reach).min(w as i64 - 1) {
                let j = sy as usize * w + sx as usize;
                let ds = d.data[j];
                let rho = (((sx - px) * (sx - px) + (sy - py) * (sy - py)) as f32).sqrt();
                let wgt = Self::cov(self.radius(ds), rho) / norm[j];
                if wgt <= 0.0 {
                    continue;
                }
                let front = self.step(ds - dp - 0.1);
                let mut behind = self.step(dp - ds - 0.1);
                let same = (1.0 - front - behind).max(0.0);
                if self.geometric && behind > 0.0 && (ds - self.focus).abs() > 1e-6 {
                    let t = (dp - self.focus) / (ds - self.focus);
                    let dq = at(px as f32 + t * (sx - px) as f32, py as f32 + t * (sy - py) as f32);
                    behind *= ((dp - 0.1 - dq) / 0.05 + 0.5).clamp(0.0, 1.0);
                }
                let c = &self.aif.data[j * 3..j * 3 + 3];
                for (gk, share) in g.iter_mut().zip([front, same, behind]) {
                    let v = (wgt * share) as f64;
                    gk[0] += v;
                    for (acc, &ch) in gk[1..].iter_mut().zip(c) {
                        *acc += v * ch as f64;
                    }
                }
            }
        }
        let (mut left, mut sum, mut took) = (1f64, [0f64; 3], 0f64);
        for gk in &g {
            if gk[0] <= 0.0 {
                continue;
            }
            let a = gk[0].min(left);
            for (sc, &c) in sum.iter_mut().zip(&gk[1..]) {
                *sc += c * a / gk[0];
            }
            took += a;
            left -= a;
        }
        sum.map(|v| if took > 0.0 { (v / took) as f32 } else { 0.0 })
    }

    fn render(&self, d: &Image) -> Image {
        let reach = self.reach(d);
        let norm = self.norms(d, reach);
        let (w, h) = (d.width, d.height);
        let px: Vec<[f32; 3]> = (0..w * h).into_par_iter().map(|i| self.pixel(d, &norm, reach, (i % w) as i64, (i / w) as i64)).collect();
        Image::from_vec(w, h, 3, px.into_iter().flatten().collect()).expect("render size")
    }
}

/// With `PROBE=ITERS`: fits the map to the target through [`Gather`] with the ray test (soft
/// group tests of width 0.03), by Adam from the constant start 0.5, at full size or coarse to
/// fine over `PROBE_LEVELS` levels (box-averaged by 2 each, K halved; ITERS steps each), the loss of
/// `dfd` (L1 + 0.01 · gradient smoothness + hierarchical SSIM), each pixel's gradient by
/// central differences of the pixels it can reach (the model is local): a probe of whether
/// the geometric model can be optimised, not a method.
fn probe(case: &drbokeh::bench::dfd_eval::DfdCase, iters: usize) -> Image {
    let levels: u32 = std::env::var("PROBE_LEVELS").ok().and_then(|v| v.parse().ok()).unwrap_or(1);
    let mut d: Option<Image> = None;
    for l in (0..levels).rev() {
        let f = 1usize << l;
        let (aif, target) = (box_down(&case.aif, f), box_down(&case.target, f));
        let init = match d.take() {
            None => Image::filled(aif.width, aif.height, 1, 0.5),
            Some(c) => Image::from_vec(
                aif.width,
                aif.height,
                1,
                (0..aif.width * aif.height)
                    .map(|i| c.data[((i / aif.width) / 2).min(c.height - 1) * c.width + ((i % aif.width) / 2).min(c.width - 1)])
                    .collect(),
            )
            .expect("level size"),
        };
        d = Some(fit(&case.scene, &aif, &target, case.blur / f as f32, case.focus, init, iters));
    }
    d.expect("at least one level")
}

/// One level of [`probe`]: Adam on `d` against `target` through the gather with the ray test.
fn fit(scene: &str, aif: &Image, target: &Image, blur: f32, focus: f32, mut d: Image, iters: usize) -> Image {
    use drbokeh::diff::loss::{HSSIM_WINDOWS, gradient_smoothness, hssim, l1 as l1_loss};
    let g = Gather { aif, blur, focus, geometric: true, soft: 0.03 };
    let (w, h) = (aif.width, aif.height);
    let (mut m, mut v) = (vec![0f64; w * h], vec![0f64; w * h]);
    let (lr, b1, b2, eps, fd) = (0.02f64, 0.9f64, 0.999f64, 1e-8f64, 1e-3f32);
    for it in 0..iters {
        let img = g.render(&d);
        let (a, b, c) = (l1_loss(&img, target), hssim(&img, target, &HSSIM_WINDOWS), gradient_smoothness(&d));
        let gi: Vec<f32> = a.grad.data.iter().zip(&b.grad.data).map(|(x, y)| x + y).collect();
        let reach = g.reach(&d);
        let norm = g.norms(&d, reach);
        let grad: Vec<f64> = (0..w * h)
            .into_par_iter()
            .map(|j| {
                let (jx, jy) = ((j % w) as i64, (j / w) as i64);
                let mut dd = d.clone();
                let mut nn = norm.clone();
                let mut side = |sign: f32| {
                    dd.data[j] = d.data[j] + sign * fd;
                    nn[j] = Gather::norm(g.radius(dd.data[j]), reach);
                    let mut s = 0f64;
                    for py in (jy - reach - 1).max(0)..=(jy + reach + 1).min(h as i64 - 1) {
                        for px in (jx - reach - 1).max(0)..=(jx + reach + 1).min(w as i64 - 1) {
                            let p = g.pixel(&dd, &nn, reach, px, py);
                            let o = (py as usize * w + px as usize) * 3;
                            s += p.iter().zip(&gi[o..o + 3]).map(|(&x, &y)| (x * y) as f64).sum::<f64>();
                        }
                    }
                    s
                };
                (side(1.0) - side(-1.0)) / (2.0 * fd as f64) + 0.01 * c.grad.data[j] as f64
            })
            .collect();
        for (i, &gr) in grad.iter().enumerate() {
            m[i] = b1 * m[i] + (1.0 - b1) * gr;
            v[i] = b2 * v[i] + (1.0 - b2) * gr * gr;
            let (mh, vh) = (m[i] / (1.0 - b1.powi(it as i32 + 1)), v[i] / (1.0 - b2.powi(it as i32 + 1)));
            d.data[i] = (d.data[i] as f64 - lr * mh / (vh.sqrt() + eps)).clamp(0.0, 1.0) as f32;
        }
        if it % 50 == 0 {
            eprintln!("{scene} probe {w}x{h} step {it}: loss {:.5}", a.value + b.value + 0.01 * c.value);
        }
    }
    d
}

/// One line per named map: its disparity error against the case's truth and its re-render at
/// the other focus (linear and sRGB PSNR), then `suffix`.
fn compare_maps(case: &drbokeh::bench::dfd_eval::DfdCase, maps: &[(&str, &Image)], suffix: &str) -> Result<()> {
    for (name, map) in maps {
        let r = score(&rerender(&case.aif, map, case.blur, case.other_focus)?, &case.other, case.border);
        println!(
            "{:15} {:8} disparity MAE {:.4}  re-render at the other focus: {:6.2} dB linear {:6.2} dB sRGB{suffix}",
            case.scene,
            name,
            mae(map, &case.truth, case.border, |_| true),
            r.psnr,
            r.psnr_srgb
        );
    }
    Ok(())
}

fn l1(a: &Image, b: &Image, border: usize) -> f64 {
    let (w, h) = (a.width, a.height);
    let (mut s, mut n) = (0f64, 0usize);
    for y in border..h - border {
        for x in border..w - border {
            for k in 0..3 {
                let i = (y * w + x) * 3 + k;
                s += (a.data[i] - b.data[i]).abs() as f64;
                n += 1;
            }
        }
    }
    s / n.max(1) as f64
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let scenes: usize = args.first().map_or(8, |v| v.parse().expect("SCENES"));
    let gt = args.get(1).filter(|v| *v != "-").map(PathBuf::from);
    let bins: usize = args.get(2).map_or(64, |v| v.parse().expect("BINS"));
    let spp: u32 = args.get(3).map_or(256, |v| v.parse().expect("SPP"));
    let side: usize = std::env::var("SIDE").ok().and_then(|v| v.parse().ok()).unwrap_or(64);
    let opts = DfdBenchOptions { scenes, groundtruth: gt.clone(), spp, width: side, height: side, ..DfdBenchOptions::default() };
    let dirs = match &gt {
        Some(d) => drbokeh::bench::groundtruth::scene_dirs(d)?,
        None => Vec::new(),
    };
    println!("case            map    model    | target focus: L1      lin dB  sRGB dB | other focus: L1      lin dB  sRGB dB");
    for i in 0..scenes + dirs.len() {
        let case = load_case(&opts, &dirs, i, &mut |_| {})?;
        let (s, loss, renderer) = DfdMethod::Physical.setup(case.blur, case.focus);
        // The span render: the layered model this check was written to test (the default
        // kernel is now the ray test at these sizes; `RAY=1` compares the two).
        let o = DfdOptions { weights: loss.weights(), renderer, kernel: dfd::DfdKernel::Fast, ..DfdOptions::default() };
        let est = if std::env::var_os("NOSPAN").is_some() {
            Image::filled(case.aif.width, case.aif.height, 1, o.init)
        } else {
            dfd::estimate(&case.aif, &case.target, &s, &o, |_| {})?
        };
        if std::env::var_os("RAY").is_some() {
            let t = std::time::Instant::now();
            let env = |k: &str| std::env::var(k).ok().and_then(|v| v.parse::<f32>().ok());
            // `AUTO=1`: the default plan (the ray test at the finest level that fits).
            let kernel = if std::env::var_os("AUTO").is_some() { dfd::DfdKernel::Auto } else { dfd::DfdKernel::Ray };
            let mut ro = DfdOptions { kernel, ..o };
            if let Some(v) = env("ITERS") {
                ro.iters = v as usize;
            }
            if let Some(v) = env("LR") {
                ro.learning_rate = v;
            }
            if let Some(v) = env("LEVELS") {
                ro.levels = v as usize;
            }
            if let Some(v) = env("SMOOTH") {
                ro.weights.smoothness = v;
            }
            let mut last = 0.0;
            let finest: u32 = std::env::var("FINEST").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
            let ray = if finest == 0 {
                dfd::estimate(&case.aif, &case.target, &s, &ro, |st| last = st.loss)?
            } else {
                let f = 1usize << finest;
                let (a, b) = (box_down(&case.aif, f), box_down(&case.target, f));
                let mut sd = s;
                sd.blur = s.blur * a.width as f32 / case.aif.width as f32;
                dfd::estimate(&a, &b, &sd, &ro, |st| last = st.loss)?.resized(case.aif.width, case.aif.height)
            };
            println!("{:15} ray final loss {last:.5}", case.scene);
            if let Ok(dir) = std::env::var("DUMP") {
                drbokeh::io::write_output(
                    &PathBuf::from(format!("{dir}/{}_ray.npy", case.scene)),
                    &ray,
                    8,
                    drbokeh::color::Transfer::Linear,
                )?;
                drbokeh::io::write_output(
                    &PathBuf::from(format!("{dir}/{}_truth.npy", case.scene)),
                    &case.truth,
                    8,
                    drbokeh::color::Transfer::Linear,
                )?;
                for (name, img) in [
                    ("far_ray", rerender(&case.aif, &ray, case.blur, case.other_focus)?),
                    ("far_truthmap", rerender(&case.aif, &case.truth, case.blur, case.other_focus)?),
                    ("far_traced", case.other.clone()),
                    ("aif", case.aif.clone()),
                ] {
                    let path = PathBuf::from(format!("{dir}/{}_{name}.npy", case.scene));
                    drbokeh::io::write_output(&path, &img, 8, drbokeh::color::Transfer::Linear)?;
                }
                let meta = serde_json::json!({
                    "blur": case.blur, "focus": case.focus, "other_focus": case.other_focus, "border": case.border
                });
                std::fs::write(format!("{dir}/{}_meta.json", case.scene), meta.to_string()).expect("meta");
            }
            let secs = t.elapsed().as_secs_f64();
            compare_maps(&case, &[("truth", &case.truth), ("span", &est), ("ray", &ray)], &format!("  ({secs:.1} s)"))?;
            continue;
        }
        if let Some(iters) = std::env::var("PROBE").ok().and_then(|v| v.parse().ok()) {
            let fit = probe(&case, iters);
            compare_maps(&case, &[("truth", &case.truth), ("estimate", &est), ("probe", &fit)], "")?;
            continue;
        }
        let m = (case.blur.ceil() as usize) + 3;
        let win = Window { x0: m, y0: m, width: case.aif.width, height: case.aif.height };
        let init = Image::filled(case.aif.width, case.aif.height, 1, DfdOptions::default().init);
        for (name, map) in [("truth", &case.truth), ("estimate", &est), ("init", &init)] {
            let planes = slices(&case.aif, map, bins, m);
            let rows: [(&str, Image, Image); 4] = [
                (
                    "gathered",
                    Gather { aif: &case.aif, blur: case.blur, focus: case.focus, geometric: false, soft: 0.0 }.render(map),
                    Gather { aif: &case.aif, blur: case.blur, focus: case.other_focus, geometric: false, soft: 0.0 }.render(map),
                ),
                (
                    "geometric",
                    Gather { aif: &case.aif, blur: case.blur, focus: case.focus, geometric: true, soft: 0.0 }.render(map),
                    Gather { aif: &case.aif, blur: case.blur, focus: case.other_focus, geometric: true, soft: 0.0 }.render(map),
                ),
                ("layered", rerender(&case.aif, map, case.blur, case.focus)?, rerender(&case.aif, map, case.blur, case.other_focus)?),
                (
                    "traced",
                    trace(&planes, &TraceSettings::new(case.blur, case.focus, spp, 7), win, &|_| {})?,
                    trace(&planes, &TraceSettings::new(case.blur, case.other_focus, spp, 9), win, &|_| {})?,
                ),
            ];
            for (model, at_target, at_other) in rows {
                let a = score(&at_target, &case.target, case.border);
                let b = score(&at_other, &case.other, case.border);
                println!(
                    "{:15} {:8} {:8} | {:.5} {:7.2} {:7.2} | {:.5} {:7.2} {:7.2}",
                    case.scene,
                    name,
                    model,
                    l1(&at_target, &case.target, case.border),
                    a.psnr,
                    a.psnr_srgb,
                    l1(&at_other, &case.other, case.border),
                    b.psnr,
                    b.psnr_srgb
                );
            }
        }
    }
    Ok(())
}
