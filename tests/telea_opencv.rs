//! Telea inpainting checked against OpenCV (`cv2.inpaint(..., INPAINT_TELEA)`), the oracle.
//!
//! Needs the test Python environment (`scripts/setup-test-env.sh` creates `.venv` with numpy and
//! OpenCV). Each test writes its cases (image, mask, radius, dtype) to a temporary folder, runs
//! `tests/oracle/telea.py` once on a manifest of all of them, and compares per pixel over the
//! filled pixels, in levels (1/255 of the value range): mean <= 1 and 99th percentile <= 4.
//! Run with `--nocapture` to see the figures.

use drbokeh::image::Image;
use drbokeh::io::npy::{read_npy, save_npy};
use drbokeh::stages::inpaint::{OpenCvCompat, TeleaOptions, inpaint_telea};
use std::path::{Path, PathBuf};
use std::process::Command;

/// Tiny deterministic generator (64-bit LCG, Knuth's constants), so no extra crate is needed.
struct Lcg(u64);

impl Lcg {
    /// Uniform in [0, 1).
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 40) as f32 / (1u64 << 24) as f32
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Kind {
    /// 3-channel 8-bit colour; the library sees it normalized to 0..1.
    Rgb8,
    /// 1-channel 16-bit codes, as they are.
    Gray16,
    /// 1-channel float disparity in 0..1.
    Float,
}

impl Kind {
    fn dtype(self) -> &'static str {
        match self {
            Kind::Rgb8 => "uint8",
            Kind::Gray16 => "uint16",
            Kind::Float => "float32",
        }
    }
    fn channels(self) -> usize {
        if self == Kind::Rgb8 { 3 } else { 1 }
    }
    /// One level (1/255 of the value range) in the oracle's units.
    fn level(self) -> f32 {
        match self {
            Kind::Rgb8 => 1.0,
            Kind::Gray16 => 65535.0 / 255.0,
            Kind::Float => 1.0 / 255.0,
        }
    }
    /// Oracle units -> what the library is given (8-bit colour is normalized, as in the pipeline).
    fn to_lib(self) -> f32 {
        if self == Kind::Rgb8 { 1.0 / 255.0 } else { 1.0 }
    }
    fn compat(self) -> OpenCvCompat {
        match self {
            Kind::Rgb8 => OpenCvCompat::u8(1.0 / 255.0),
            Kind::Gray16 => OpenCvCompat::u16(1.0),
            Kind::Float => OpenCvCompat::f32(),
        }
    }
}

/// Smooth gradients + a hard-edged texture + noise, in the oracle's units for `kind`.
fn test_image(kind: Kind, w: usize, h: usize, seed: u64) -> Image {
    let mut rng = Lcg(seed);
    let mut img = Image::new(w, h, kind.channels());
    for y in 0..h {
        for x in 0..w {
            let (xf, yf) = (x as f32, y as f32);
            let checker = if ((x / 7) + (y / 5)) % 2 == 0 { 1.0 } else { -1.0 };
            let stripe = ((xf * 0.7 + yf * 0.35).sin()).signum();
            for c in 0..kind.channels() {
                let n = rng.next() - 0.5;
                let v = match kind {
                    Kind::Rgb8 => {
                        let v = 110.0
                            + 70.0 * (0.09 * xf + 0.05 * yf + 1.3 * c as f32).sin()
                            + 40.0 * (yf / h as f32 - 0.5)
                            + 18.0 * checker
                            + 8.0 * stripe
                            + 16.0 * n;
                        v.round().clamp(0.0, 255.0)
                    }
                    Kind::Gray16 => {
                        let v = 30000.0
                            + 20000.0 * (0.07 * xf).sin() * (0.11 * yf).cos()
                            + 8000.0 * xf / w as f32
                            + 3000.0 * checker
                            + 1500.0 * n;
                        v.round().clamp(0.0, 65535.0)
                    }
                    Kind::Float => {
                        let v = 0.5 + 0.3 * (0.08 * xf + 0.03 * yf).sin() + 0.1 * yf / h as f32 + 0.04 * stripe + 0.02 * n;
                        v.clamp(0.0, 1.0)
                    }
                };
                img.pixel_mut(x, y)[c] = v;
            }
        }
    }
    img
}

#[derive(Clone, Copy, Debug)]
enum MaskKind {
    /// Ellipses of several sizes, inside the image.
    Blobs,
    /// Straight and diagonal lines 1 to 3 px wide.
    Lines,
    /// Shapes cut by the image edges, plus full edge rows/columns.
    Border,
    /// A rectangle covering ~80% of the image, known pixels only in a frame around it.
    Most,
    /// Scattered single pixels and 2x2 dots.
    Speckle,
}

fn ellipse(m: &mut [bool], w: usize, h: usize, cx: f32, cy: f32, rx: f32, ry: f32) {
    for y in 0..h {
        for x in 0..w {
            let (dx, dy) = ((x as f32 - cx) / rx, (y as f32 - cy) / ry);
            if dx * dx + dy * dy <= 1.0 {
                m[y * w + x] = true;
            }
        }
    }
}

/// A line from (x0, y0) to (x1, y1) of the given width (pixels within width/2 of the segment).
fn line(m: &mut [bool], w: usize, h: usize, (x0, y0): (f32, f32), (x1, y1): (f32, f32), width: f32) {
    let (dx, dy) = (x1 - x0, y1 - y0);
    let len2 = dx * dx + dy * dy;
    for y in 0..h {
        for x in 0..w {
            let (px, py) = (x as f32 - x0, y as f32 - y0);
            let t = ((px * dx + py * dy) / len2).clamp(0.0, 1.0);
            let (ex, ey) = (px - t * dx, py - t * dy);
            if (ex * ex + ey * ey).sqrt() <= width * 0.5 {
                m[y * w + x] = true;
            }
        }
    }
}

fn test_mask(kind: MaskKind, w: usize, h: usize) -> Vec<bool> {
    let mut m = vec![false; w * h];
    let (wf, hf) = (w as f32, h as f32);
    match kind {
        MaskKind::Blobs => {
            ellipse(&mut m, w, h, wf * 0.3, hf * 0.35, wf * 0.12, hf * 0.18);
            ellipse(&mut m, w, h, wf * 0.7, hf * 0.6, wf * 0.08, hf * 0.08);
            ellipse(&mut m, w, h, wf * 0.45, hf * 0.75, wf * 0.2, hf * 0.06);
            ellipse(&mut m, w, h, wf * 0.8, hf * 0.2, 2.0, 1.5);
        }
        MaskKind::Lines => {
            line(&mut m, w, h, (3.0, hf * 0.2), (wf - 4.0, hf * 0.2), 1.0);
            line(&mut m, w, h, (wf * 0.3, 2.0), (wf * 0.3, hf - 3.0), 2.0);
            line(&mut m, w, h, (5.0, 5.0), (wf - 6.0, hf - 6.0), 3.0);
            line(&mut m, w, h, (wf * 0.9, 4.0), (wf * 0.55, hf - 5.0), 1.5);
        }
        MaskKind::Border => {
            ellipse(&mut m, w, h, 0.0, hf * 0.4, wf * 0.15, hf * 0.2);
            ellipse(&mut m, w, h, wf * 0.6, 0.0, wf * 0.1, hf * 0.15);
            ellipse(&mut m, w, h, wf - 1.0, hf - 1.0, wf * 0.12, hf * 0.15);
            for x in 0..w / 2 {
                m[(h - 1) * w + x] = true;
                m[(h - 2) * w + x] = true;
            }
            for y in h / 3..h / 2 {
                m[y * w + w - 1] = true;
            }
        }
        MaskKind::Most => {
            let (x0, x1) = ((wf * 0.05) as usize, (wf * 0.95) as usize);
            let (y0, y1) = ((hf * 0.05) as usize, (hf * 0.95) as usize);
            for y in y0..y1 {
                for x in x0..x1 {
                    m[y * w + x] = true;
                }
            }
        }
        MaskKind::Speckle => {
            let mut rng = Lcg(99);
            for _ in 0..(w * h / 40) {
                let x = (rng.next() * (w - 1) as f32) as usize;
                let y = (rng.next() * (h - 1) as f32) as usize;
                m[y * w + x] = true;
                if rng.next() < 0.3 {
                    m[y * w + x + 1] = true;
                    m[(y + 1) * w + x] = true;
                    m[(y + 1) * w + x + 1] = true;
                }
            }
        }
    }
    m
}

struct Case {
    name: String,
    kind: Kind,
    image: Image,
    mask: Vec<bool>,
    radius: f32,
}

fn python() -> PathBuf {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    assert!(
        py.exists(),
        "{} is missing: run scripts/setup-test-env.sh to create the test Python environment (numpy, OpenCV)",
        py.display()
    );
    py
}

/// Runs the oracle on all cases in one Python process; returns OpenCV's results (oracle units).
fn opencv(cases: &[Case], dir: &Path) -> Vec<Image> {
    let mut manifest = Vec::new();
    for (i, case) in cases.iter().enumerate() {
        let (img, mask, out) = (dir.join(format!("img{i}.npy")), dir.join(format!("mask{i}.npy")), dir.join(format!("out{i}.npy")));
        save_npy(&img, &case.image).unwrap();
        let m = Image::from_vec(case.image.width, case.image.height, 1, case.mask.iter().map(|&b| b as u8 as f32).collect()).unwrap();
        save_npy(&mask, &m).unwrap();
        manifest.push(serde_json::json!({
            "image": img, "mask": mask, "radius": case.radius, "dtype": case.kind.dtype(), "out": out,
        }));
    }
    let manifest_path = dir.join("manifest.json");
    std::fs::write(&manifest_path, serde_json::to_vec(&manifest).unwrap()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/oracle/telea.py");
    let out = Command::new(python()).arg(&script).arg(&manifest_path).output().expect("run the OpenCV oracle");
    assert!(out.status.success(), "oracle failed:\n{}", String::from_utf8_lossy(&out.stderr));
    (0..cases.len()).map(|i| read_npy(&dir.join(format!("out{i}.npy")), u64::MAX).unwrap()).collect()
}

/// The installed OpenCV's version, for the printed tables.
fn cv_version() -> String {
    let out = Command::new(python()).args(["-c", "import cv2; print(cv2.__version__)"]).output().expect("run python");
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}

/// Our fill, returned in oracle units.
fn ours(case: &Case, compat: Option<OpenCvCompat>) -> Image {
    let k = case.kind.to_lib();
    let mut img = case.image.clone();
    img.data.iter_mut().for_each(|v| *v *= k);
    let opts = TeleaOptions { compat, ..TeleaOptions::new(case.radius) };
    let filled = inpaint_telea(&mut img, &case.mask, opts).unwrap();
    assert_eq!(filled, case.mask.iter().filter(|&&m| m).count(), "{}: not every masked pixel was filled", case.name);
    img.data.iter_mut().for_each(|v| *v /= k);
    img
}

struct Stats {
    mean: f64,
    p99: f64,
    max: f64,
    /// Values compared, and how many of them differ at all.
    n: usize,
    differ: usize,
}

/// Absolute differences over the masked pixels (all channels), in levels.
fn compare(a: &Image, b: &Image, mask: &[bool], level: f32) -> Stats {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels));
    let c = a.channels;
    let mut d: Vec<f64> = Vec::new();
    for (i, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        for k in 0..c {
            d.push(((a.data[i * c + k] - b.data[i * c + k]).abs() / level) as f64);
        }
    }
    assert!(!d.is_empty());
    d.sort_by(f64::total_cmp);
    let n = d.len();
    let p99 = d[((n as f64 * 0.99).ceil() as usize).clamp(1, n) - 1];
    let differ = d.iter().filter(|&&v| v != 0.0).count();
    Stats { mean: d.iter().sum::<f64>() / n as f64, p99, max: d[n - 1], n, differ }
}

fn cases_for(kind: Kind) -> Vec<Case> {
    let sizes = [
        (MaskKind::Blobs, 160, 120),
        (MaskKind::Lines, 97, 61),
        (MaskKind::Border, 64, 48),
        (MaskKind::Most, 120, 90),
        (MaskKind::Speckle, 80, 64),
    ];
    let mut cases = Vec::new();
    for (mi, &(mk, w, h)) in sizes.iter().enumerate() {
        let image = test_image(kind, w, h, 1000 + mi as u64);
        let mask = test_mask(mk, w, h);
        for radius in [1.0, 2.5, 3.0, 5.0, 7.0] {
            let name = format!("{:?} {mk:?} {w}x{h} r={radius}", kind);
            cases.push(Case { name, kind, image: image.clone(), mask: mask.clone(), radius });
        }
    }
    cases
}

/// Compares both modes with OpenCV; asserts the OpenCV-compatible one within tolerance and
/// reports the plain weighted mean (the library default) alongside.
fn check(kind: Kind) {
    let cases = cases_for(kind);
    let dir = tempfile::tempdir().unwrap();
    let oracle = opencv(&cases, dir.path());
    // One print per test, so that tests running in parallel do not interleave their tables.
    let mut table =
        format!("{kind:?} vs cv2.inpaint TELEA (OpenCV {}), |diff| in levels (1/255 of range) over filled values\n", cv_version());
    table += &format!(
        "{:<34} {:>6} | {:>6} {:>7} {:>7} {:>9} | {:>7} {:>7} {:>7}\n",
        "case", "values", "differ", "mean", "p99", "max", "mean*", "p99*", "max*"
    );
    let mut failures = Vec::new();
    for (case, cv) in cases.iter().zip(&oracle) {
        let compat = compare(&ours(case, Some(kind.compat())), cv, &case.mask, kind.level());
        let plain = compare(&ours(case, None), cv, &case.mask, kind.level());
        table += &format!(
            "{:<34} {:>6} | {:>6} {:>7.4} {:>7.3} {:>9.3e} | {:>7.3} {:>7.3} {:>7.3}\n",
            case.name, compat.n, compat.differ, compat.mean, compat.p99, compat.max, plain.mean, plain.p99, plain.max
        );
        if !(compat.mean <= 1.0 && compat.p99 <= 4.0) {
            failures.push(format!("{}: mean {:.3} p99 {:.3}", case.name, compat.mean, compat.p99));
        }
    }
    table += "left: TeleaOptions::compat = the dtype's OpenCvCompat (asserted: mean <= 1, p99 <= 4);\n";
    table += "right (*): the default plain weighted mean, reported only\n";
    println!("{table}");
    assert!(failures.is_empty(), "outside tolerance (mean <= 1, p99 <= 4 levels):\n{}", failures.join("\n"));
}

#[test]
fn telea_matches_opencv_rgb8() {
    check(Kind::Rgb8);
}

#[test]
fn telea_matches_opencv_gray16() {
    check(Kind::Gray16);
}

#[test]
fn telea_matches_opencv_float32() {
    check(Kind::Float);
}
