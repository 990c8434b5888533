//! `drbokeh trace` and `drbokeh bench` end to end (tiny sizes), and the metrics on hand-made
//! pairs.

mod common;

use drbokeh::Image;
use drbokeh::bench::metrics::{psnr, rmse, si_rmse, ssim, zncc};
use drbokeh::bench::run::Method;
use drbokeh::io::{self, ReadLimits};
use std::path::{Path, PathBuf};
use std::process::Output;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("drbokeh-bench-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn drbokeh(dir: &Path, args: &[&str]) -> Output {
    let mut c = common::drbokeh_bin();
    c.current_dir(dir).args(args);
    common::run(c)
}

use common::stderr;

/// A W x H layer: colour `rgb`, alpha from `alpha(x, y)`, disparity from `d(x, y)`.
fn layer(w: usize, h: usize, rgb: [f32; 3], alpha: impl Fn(usize, usize) -> f32, d: impl Fn(usize, usize) -> f32) -> Image {
    let mut img = Image::new(w, h, 5);
    for y in 0..h {
        for x in 0..w {
            img.pixel_mut(x, y).copy_from_slice(&[rgb[0], rgb[1], rgb[2], alpha(x, y), d(x, y)]);
        }
    }
    img
}

#[test]
fn trace_writes_a_thin_lens_image() {
    let dir = tmp("trace");
    let (w, h) = (32, 24);
    let fg = layer(w, h, [1.0, 0.2, 0.1], |x, y| ((x as f32 - 16.0).hypot(y as f32 - 12.0) < 6.0) as u8 as f32, |_, _| 1.0);
    let bg = layer(w, h, [0.1, 0.3, 0.9], |_, _| 1.0, |_, _| 0.0);
    io::write_exr(&dir.join("fg.exr"), &fg, &["R", "G", "B", "A", "D"]).unwrap();
    io::write_exr(&dir.join("bg.exr"), &bg, &["R", "G", "B", "A", "D"]).unwrap();
    // Focus on the foreground: the disk is sharp, the background (flat) stays flat.
    let o = drbokeh(
        &dir,
        &["trace", "--layer", "fg.exr", "--layer", "bg.exr", "--focus", "1", "--blur", "8", "--spp", "64", "-o", "gt.exr", "-v"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("estimated noise"), "{}", stderr(&o));
    let img = io::read_photo(&dir.join("gt.exr"), drbokeh::color::Transfer::Linear, &ReadLimits::default()).unwrap();
    assert_eq!((img.width, img.height, img.channels), (w, h, 3));
    assert!(img.all_finite());
    assert!((img.pixel(16, 12)[0] - 1.0).abs() < 1e-5, "in-focus centre: {:?}", img.pixel(16, 12));
    assert!((img.pixel(1, 1)[2] - 0.9).abs() < 1e-5, "flat background: {:?}", img.pixel(1, 1));
    // Focus on the background: the disk's edge turns soft and reveals the background.
    let o =
        drbokeh(&dir, &["trace", "--layer", "fg.exr", "--layer", "bg.exr", "--focus", "0", "--blur", "4", "--spp", "256", "-o", "bgf.png"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.join("bgf.png").is_file());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn trace_refuses_a_layer_that_is_not_one_plane() {
    let dir = tmp("trace-bad");
    let tilted = layer(16, 16, [0.5, 0.5, 0.5], |_, _| 1.0, |x, _| x as f32 / 15.0);
    io::write_exr(&dir.join("tilted.exr"), &tilted, &["R", "G", "B", "A", "D"]).unwrap();
    let o = drbokeh(&dir, &["trace", "--layer", "tilted.exr", "--focus", "0.5", "--blur", "5", "-o", "out.exr"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("tilted.exr") && e.contains("one layer per depth"), "{e}");
    assert!(!dir.join("out.exr").exists());
    // Layers of different sizes, and an output that is an input.
    let small = layer(8, 8, [0.5, 0.5, 0.5], |_, _| 1.0, |_, _| 0.2);
    io::write_exr(&dir.join("small.exr"), &small, &["R", "G", "B", "A", "D"]).unwrap();
    let flat = layer(16, 16, [0.5, 0.5, 0.5], |_, _| 1.0, |_, _| 0.2);
    io::write_exr(&dir.join("flat.exr"), &flat, &["R", "G", "B", "A", "D"]).unwrap();
    let o = drbokeh(&dir, &["trace", "--layer", "small.exr", "--layer", "flat.exr", "--focus", "0", "--blur", "5", "-o", "out.exr"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("same size"), "{}", stderr(&o));
    let o = drbokeh(&dir, &["trace", "--layer", "flat.exr", "--focus", "0", "--blur", "5", "-o", "flat.exr"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn tiny_bench_run_writes_the_report() {
    let dir = tmp("bench");
    let o = drbokeh(&dir, &["bench", "--scenes", "2", "--size", "64x64", "--seed", "3", "--spp", "64", "--repeats", "1", "--out", "rep"]);
    assert!(o.status.success(), "{}", stderr(&o));
    let rep = dir.join("rep");
    let csv = std::fs::read_to_string(rep.join("report.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    // 2 scenes x (7 + 4 + 8 + 5 + 2) method settings (physical-exact and physical-fast-q2 for
    // every profile-aware method, realistic-depth for the three that read the depth map, and
    // the pipeline's options: layers-auto with both depth maps, patchmatch).
    assert_eq!(lines.len(), 1 + 2 * 26, "{csv}");
    assert_eq!(lines.iter().filter(|l| l.contains(",realistic-depth,")).count(), 2 * 3);
    for option in [",layers-auto,", ",realistic-depth-layers-auto,", ",patchmatch,"] {
        assert_eq!(lines.iter().filter(|l| l.contains(option)).count(), 2, "{option}");
    }
    assert_eq!(lines.iter().filter(|l| l.contains(",physical-exact,")).count(), 2 * 4);
    assert!(lines[0].starts_with("scene,setting,categories,method,variant,width,height,threads"));
    for l in &lines[1..] {
        let cols: Vec<&str> = l.split(',').collect();
        assert_eq!(cols.len(), 22, "{l}");
        assert_eq!((cols[5], cols[6]), ("64", "64"));
        for v in &cols[13..] {
            let x: f64 = v.parse().unwrap();
            assert!(x.is_finite() || *v == "inf", "{l}");
        }
    }
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    for needle in ["## Summary", "drbokeh-layers", "scatter-no-occlusion", "gather", "Per category", "vs **gather**", "error_vs_time.png"] {
        assert!(md.contains(needle), "report.md lacks {needle}:\n{md}");
    }
    let png = std::fs::read(rep.join("error_vs_time.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert!(std::fs::read_dir(rep.join("crops")).unwrap().count() >= 1);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bench_on_the_shared_groundtruth_folders_and_bad_flags() {
    let dir = tmp("bench-gt");
    let gt = common::shared_dir().join("groundtruth");
    let o = drbokeh(
        &dir,
        &["bench", "--groundtruth", gt.to_str().unwrap(), "--methods", "gather", "--repeats", "1", "--crops", "0", "--out", "rep"],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(dir.join("rep/report.csv")).unwrap();
    assert!(csv.contains("portrait,focus_fg") && csv.contains("thin_bars,focus_bg,bg_in_focus;thin"), "{csv}");
    for (name, method) in [
        ("layers", Method::Layers),
        ("scatter", Method::Scatter),
        ("no-occlusion", Method::Scatter),
        ("drbokeh-sliced", Method::Sliced),
        ("pipeline", Method::Pipeline),
        ("gather", Method::Gather),
    ] {
        assert_eq!(Method::parse(name), Some(method), "{name}");
    }
    let o = drbokeh(&dir, &["bench", "--methods", "nope", "--out", "x"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("nope"));
    let o = drbokeh(&dir, &["bench", "--size", "64", "--out", "x"]);
    assert_eq!(o.status.code(), Some(2));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn metrics_on_hand_made_pairs() {
    let a = Image::from_vec(16, 16, 3, (0..16 * 16 * 3).map(|i| ((i * 37) % 101) as f32 / 100.0).collect()).unwrap();
    // Identical: SSIM 1, PSNR inf, ZNCC 1.
    assert!((ssim(&a, &a, 1.0, 0) - 1.0).abs() < 1e-12);
    assert_eq!(psnr(&a, &a, 1.0, 0), f64::INFINITY);
    // A scaled copy: scale-invariant RMSE 0, plain RMSE not.
    let mut b = a.clone();
    b.map_inplace(|v| 2.5 * v);
    assert!(si_rmse(&a, &b, 0) < 1e-5 && rmse(&a, &b, 0) > 0.1);
    assert!((zncc(&a, &b, 0) - 1.0).abs() < 1e-9);
    // Two flat images 0.5 and 0.4: PSNR = 20 dB; SSIM = (2·μa·μb + C1) / (μa² + μb² + C1)
    // (the contrast/structure factor is C2/C2 = 1).
    let (p, q) = (Image::filled(16, 16, 3, 0.5), Image::filled(16, 16, 3, 0.4));
    assert!((psnr(&p, &q, 1.0, 0) - 20.0).abs() < 1e-4);
    let c1 = 0.0001f64;
    let want = (2.0 * 0.5 * 0.4 + c1) / (0.25 + 0.16 + c1);
    assert!((ssim(&p, &q, 1.0, 0) - want).abs() < 1e-6, "{} vs {want}", ssim(&p, &q, 1.0, 0));
    // Negated structure: ZNCC -1.
    let mut n = a.clone();
    n.map_inplace(|v| 1.0 - v);
    assert!((zncc(&a, &n, 0) + 1.0).abs() < 1e-9);
}
