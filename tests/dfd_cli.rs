//! `drbokeh dfd`: recovery of a synthetic two-plane scene through the binary (files in, disparity
//! map out), the loss log and plot, the ablation, and the usage-error contract.

mod common;

use common::{Rng, assert_usage_error, drbokeh, run, stderr};
use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{self, ReadLimits};
use drbokeh::render::{Kernel, Layer, Profile, RenderSettings, render};
use std::path::Path;

const W: usize = 32;
const H: usize = 32;
const FOCUS: f32 = 1.0;
const BLUR: f32 = 4.0;

/// The true disparity: the left half on the focal plane (1.0), the right half at 0.4.
fn truth() -> Image {
    Image::from_vec(W, H, 1, (0..W * H).map(|i| if i % W < W / 2 { 1.0 } else { 0.4 }).collect()).unwrap()
}

/// Writes the scene into `dir`: `aif.png` (16-bit sRGB noise texture, seeded) and `bokeh.exr`,
/// the exact render at `FOCUS`, `BLUR` of the AIF as the binary will read it (decoded back
/// from the PNG) over the true disparity.
fn write_scene(dir: &Path) {
    let mut rng = Rng::new(9);
    let aif = Image::from_vec(W, H, 3, (0..W * H * 3).map(|_| rng.next_f32()).collect()).unwrap();
    io::write_png(&dir.join("aif.png"), &aif, 16, Transfer::Srgb).unwrap();
    let aif = io::read_photo(&dir.join("aif.png"), Transfer::Srgb, &ReadLimits::default()).unwrap();
    let s =
        RenderSettings { blur: BLUR, focus: FOCUS, lens: 2 * (BLUR.ceil() as usize + 3) + 1, occlusion: true, profile: Profile::Physical };
    let layer = Layer::from_parts(&aif, &Image::filled(W, H, 1, 1.0), &truth(), "truth").unwrap();
    let bokeh = render(&[layer], &s, Kernel::Exact).unwrap();
    io::write_output(&dir.join("bokeh.exr"), &bokeh, 8, Transfer::Linear).unwrap();
}

fn dfd(dir: &Path, extra: &[&str]) -> std::process::Command {
    let mut c = drbokeh(dir);
    c.args(["dfd", "aif.png", "bokeh.exr", "--focus", "1", "--blur", "4"]).args(extra);
    c
}

fn mean_abs_error(d: &Image) -> f64 {
    d.data.iter().zip(&truth().data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / (W * H) as f64
}

/// 2 levels × 40 steps from 0.5 everywhere (mean error 0.30): the estimate must come within
/// a fifth of that (the library's test of the same scene reaches ~0.02).
#[test]
fn recovers_two_planes_and_writes_log_and_plot() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let out = run(dfd(dir, &["--iters", "40", "--levels", "2", "-o", "disp.npy", "--log", "loss.csv", "--plot", "loss.png"]));
    assert!(out.status.success(), "dfd failed: {}", stderr(&out));

    let d = io::read_npy(&dir.join("disp.npy"), u64::MAX).unwrap();
    assert_eq!((d.width, d.height, d.channels), (W, H, 1));
    let start = mean_abs_error(&Image::filled(W, H, 1, 0.5));
    let err = mean_abs_error(&d);
    eprintln!("mean disparity error {err:.4} (start {start:.4}); {}", stderr(&out).trim());
    assert!(err < 0.2 * start, "mean disparity error {err:.4} (start {start:.4})");

    let csv = std::fs::read_to_string(dir.join("loss.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(drbokeh::diff::dfd_job::LOG_HEADER));
    assert_eq!(drbokeh::diff::dfd_job::LOG_HEADER, "level,width,height,iter,loss,l1,smoothness,ssim");
    let rows: Vec<Vec<f64>> = lines.map(|l| l.split(',').map(|v| v.parse::<f64>().unwrap()).collect()).collect();
    assert_eq!(rows.len(), 80, "one row per step");
    assert!(rows.iter().all(|r| r.len() == 8 && r.iter().all(|v| v.is_finite())));
    assert_eq!((rows[0][0], rows[0][1], rows[0][3]), (1.0, 16.0, 0.0), "coarse level first, at half size");
    assert_eq!((rows[79][0], rows[79][1], rows[79][3]), (0.0, 32.0, 39.0));
    let full: Vec<&Vec<f64>> = rows.iter().filter(|r| r[0] == 0.0).collect();
    assert!(full[39][4] < full[0][4], "the full-size loss must drop: {} -> {}", full[0][4], full[39][4]);

    let png = image::open(dir.join("loss.png")).expect("the plot is a readable PNG");
    assert_eq!((png.width(), png.height()), (1100, 640));
}

/// The ablation runs, writes EXR, and says so in the JSON report.
#[test]
fn no_occlusion_runs_and_writes_exr() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let out = run(dfd(dir, &["--iters", "5", "--levels", "1", "--no-occlusion", "--loss", "l1-grad", "-o", "disp.exr", "--json"]));
    assert!(out.status.success(), "dfd failed: {}", stderr(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["occlusion"], false);
    assert_eq!(report["steps"], 5);
    assert_eq!(report["options"]["weights"]["ssim"], 0.0);
    // Without occlusion the ray test has nothing to test: `auto` is the span render.
    assert_eq!(report["options"]["kernel"], "auto");
    assert_eq!((report["plan"]["kernel"].as_str(), report["plan"]["finest_level"].as_u64()), (Some("fast"), Some(0)));
    let d = io::read_depth(&dir.join("disp.exr"), &ReadLimits::default()).unwrap();
    assert_eq!((d.width, d.height, d.channels), (W, H, 1));
    assert!(d.data.iter().all(|v| (0.0..=1.0).contains(v)));
    // With occlusion, this small view gets the ray test at full size.
    let out = run(dfd(dir, &["--iters", "2", "--levels", "1", "-o", "disp2.exr", "--json"]));
    assert!(out.status.success(), "dfd failed: {}", stderr(&out));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(report["plan"]["kernel"], "ray");
    assert_eq!((report["plan"]["width"].as_u64(), report["plan"]["height"].as_u64()), (Some(W as u64), Some(H as u64)));
}

#[test]
fn usage_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    io::write_output(&dir.join("small.exr"), &Image::filled(16, 8, 3, 0.5), 8, Transfer::Linear).unwrap();
    let bad = |what: &str, needles: &[&str], args: &[&str]| {
        let err = assert_usage_error(dir, what, needles, || {
            let mut c = drbokeh(dir);
            c.arg("dfd").args(args);
            run(c)
        });
        eprintln!("{what}: {}", err.trim());
    };
    let base = ["aif.png", "bokeh.exr", "--focus", "1", "--blur", "4", "--iters", "2"];
    let with = |extra: &[&'static str]| base.iter().copied().chain(extra.iter().copied()).collect::<Vec<&str>>();
    bad(
        "size mismatch",
        &["aif.png", "small.exr", "32x32", "16x8"],
        &["aif.png", "small.exr", "--focus", "1", "--blur", "4", "-o", "d.npy"],
    );
    bad("output over an input", &["bokeh.exr", "input"], &with(&["-o", "bokeh.exr"]));
    bad("log over an input", &["--log", "aif.png"], &with(&["-o", "d.npy", "--log", "aif.png"]));
    bad("PNG output", &["d.png", ".npy"], &with(&["-o", "d.png"]));
    bad("missing file", &["nothere.png"], &["nothere.png", "bokeh.exr", "--focus", "1", "--blur", "4", "-o", "d.npy"]);
    bad("NaN focus", &["--focus", "NaN"], &["aif.png", "bokeh.exr", "--focus", "NaN", "--blur", "4", "-o", "d.npy"]);
    bad("negative blur", &["--blur"], &["aif.png", "bokeh.exr", "--focus", "1", "--blur", "-1", "-o", "d.npy"]);
    bad("zero iterations", &["--iters"], &["aif.png", "bokeh.exr", "--focus", "1", "--blur", "4", "--iters", "0", "-o", "d.npy"]);
    bad("init outside [0, 1]", &["--init"], &with(&["--init", "1.5", "-o", "d.npy"]));
    bad(
        "ray test, official profile",
        &["--kernel ray", "--profile physical"],
        &with(&["--kernel", "ray", "--profile", "official", "-o", "d.npy"]),
    );
}
