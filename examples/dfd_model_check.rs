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
//! `cargo run --release --example dfd_model_check -- [SCENES] [GROUNDTRUTH_DIR] [BINS] [SPP]`
//! (defaults 8 generated scenes at 64x64 seed 1, no ground-truth folder, 64 bins, 256 spp).

use drbokeh::bench::dfd_eval::{DfdBenchOptions, DfdMethod, load_case, rerender};
use drbokeh::bench::run::score;
use drbokeh::bench::trace::{Plane, TraceSettings, Window, trace};
use drbokeh::diff::dfd::{self, DfdOptions};
use drbokeh::{Image, Result};
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
fn gather(aif: &Image, d: &Image, blur: f32, focus: f32, geometric: bool) -> Image {
    let (w, h) = (aif.width, aif.height);
    let radius = |v: f32| blur * (v - focus).abs();
    let cov = |r: f32, rho: f32| if r < 0.5 { if rho < 0.5 { 1.0 } else { 0.0 } } else { (r + 0.5 - rho).clamp(0.0, 1.0) };
    let reach = d.data.iter().map(|&v| radius(v)).fold(0.0f32, f32::max).ceil() as i64 + 1;
    let norm: Vec<f32> = d
        .data
        .iter()
        .map(|&v| {
            let r = radius(v);
            let mut n = 0.0;
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    n += cov(r, ((dx * dx + dy * dy) as f32).sqrt());
                }
            }
            n
        })
        .collect();
    let at = |x: f32, y: f32| {
        let (x, y) = (x.clamp(0.0, (w - 1) as f32), y.clamp(0.0, (h - 1) as f32));
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let v = |xx: usize, yy: usize| d.data[yy * w + xx];
        (v(x0, y0) * (1.0 - fx) + v(x1, y0) * fx) * (1.0 - fy) + (v(x0, y1) * (1.0 - fx) + v(x1, y1) * fx) * fy
    };
    let mut out = Image::new(w, h, 3);
    for py in 0..h as i64 {
        for px in 0..w as i64 {
            let dp = d.data[py as usize * w + px as usize];
            // Per group: coverage and colour.
            let mut g = [[0f64; 4]; 3];
            for sy in (py - reach).max(0)..=(py + reach).min(h as i64 - 1) {
                for sx in (px - reach).max(0)..=(px + reach).min(w as i64 - 1) {
                    let j = sy as usize * w + sx as usize;
                    let ds = d.data[j];
                    let rho = (((sx - px) * (sx - px) + (sy - py) * (sy - py)) as f32).sqrt();
                    let mut wgt = cov(radius(ds), rho) / norm[j];
                    if wgt <= 0.0 {
                        continue;
                    }
                    let k = if ds > dp + 0.1 {
                        0
                    } else if ds < dp - 0.1 {
                        2
                    } else {
                        1
                    };
                    if k == 2 && geometric && (ds - focus).abs() > 1e-6 {
                        let t = (dp - focus) / (ds - focus);
                        let dq = at(px as f32 + t * (sx - px) as f32, py as f32 + t * (sy - py) as f32);
                        wgt *= ((dp - 0.1 - dq) / 0.05 + 0.5).clamp(0.0, 1.0);
                    }
                    let c = &aif.data[j * 3..j * 3 + 3];
                    g[k][0] += wgt as f64;
                    for ch in 0..3 {
                        g[k][ch + 1] += (wgt * c[ch]) as f64;
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
            let o = (py as usize * w + px as usize) * 3;
            for (v, &sc) in out.data[o..o + 3].iter_mut().zip(&sum) {
                *v = if took > 0.0 { (sc / took) as f32 } else { 0.0 };
            }
        }
    }
    out
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
    let opts = DfdBenchOptions { scenes, groundtruth: gt.clone(), spp, ..DfdBenchOptions::default() };
    let dirs = match &gt {
        Some(d) => drbokeh::bench::groundtruth::scene_dirs(d)?,
        None => Vec::new(),
    };
    println!("case            map    model    | target focus: L1      lin dB  sRGB dB | other focus: L1      lin dB  sRGB dB");
    for i in 0..scenes + dirs.len() {
        let case = load_case(&opts, &dirs, i, &mut |_| {})?;
        let (s, loss, renderer) = DfdMethod::Physical.setup(case.blur, case.focus);
        let o = DfdOptions { weights: loss.weights(), renderer, ..DfdOptions::default() };
        let est = dfd::estimate(&case.aif, &case.target, &s, &o, |_| {})?;
        let m = (case.blur.ceil() as usize) + 3;
        let win = Window { x0: m, y0: m, width: case.aif.width, height: case.aif.height };
        let init = Image::filled(case.aif.width, case.aif.height, 1, DfdOptions::default().init);
        for (name, map) in [("truth", &case.truth), ("estimate", &est), ("init", &init)] {
            let planes = slices(&case.aif, map, bins, m);
            let rows: [(&str, Image, Image); 4] = [
                (
                    "gathered",
                    gather(&case.aif, map, case.blur, case.focus, false),
                    gather(&case.aif, map, case.blur, case.other_focus, false),
                ),
                (
                    "geometric",
                    gather(&case.aif, map, case.blur, case.focus, true),
                    gather(&case.aif, map, case.blur, case.other_focus, true),
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
