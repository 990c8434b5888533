//! `drbokeh trace` and `drbokeh bench` end to end (tiny sizes), and the metrics on hand-made
//! pairs.

use crate::common;

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

/// report.csv's columns: the header's names, in order.
const CSV_HEADER: &str = "scene,setting,categories,method,variant,input,width,height,threads,blur,focus,max_coc_px,border_px,runs,\
                          time_ms,rmse,si_rmse,psnr_linear,ssim_linear,zncc,psnr_srgb,ssim_srgb,psnr_srgb_full_frame,light_missing,\
                          light_recovered,outline_violations,alpha_mae";
/// Index of the `input` column, of the first score column, and of the two light columns.
const INPUT_COL: usize = 5;
const FIRST_SCORE_COL: usize = 14;
const LIGHT_MISSING_COL: usize = 23;
const LIGHT_RECOVERED_COL: usize = 24;
/// Index of the outline scores (`bench::outline`): range violations and alpha error.
const VIOLATIONS_COL: usize = 25;
const ALPHA_MAE_COL: usize = 26;

/// report.csv's rows (header checked), each split into its columns, with a 64x64 frame and a
/// finite (or inf) number in every score column.
fn csv_rows(csv: &str) -> Vec<Vec<&str>> {
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(CSV_HEADER), "{csv}");
    let n = CSV_HEADER.split(',').count();
    lines
        .map(|l| {
            let cols: Vec<&str> = l.split(',').collect();
            assert_eq!(cols.len(), n, "{l}");
            assert_eq!((cols[INPUT_COL + 1], cols[INPUT_COL + 2]), ("64", "64"), "{l}");
            for v in &cols[FIRST_SCORE_COL..LIGHT_MISSING_COL] {
                let x: f64 = v.parse().unwrap();
                assert!(x.is_finite() || *v == "inf", "{l}");
            }
            cols
        })
        .collect()
}

#[test]
fn tiny_bench_run_writes_the_report() {
    let dir = tmp("bench");
    let o = drbokeh(
        &dir,
        &[
            "bench",
            "--scenes",
            "2",
            "--size",
            "64x64",
            "--seed",
            "3",
            "--spp",
            "64",
            "--repeats",
            "1",
            "--inputs",
            "linear",
            "--out",
            "rep",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let rep = dir.join("rep");
    let csv = std::fs::read_to_string(rep.join("report.csv")).unwrap();
    let rows = csv_rows(&csv);
    // 2 scenes x (7 + 4 + 10 + 5 + 2) method settings (physical-exact and physical-fast-q2 for
    // every profile-aware method, realistic-depth for the three that read the depth map, and
    // the pipeline's options: realistic depth without matte with and without matting,
    // layers-auto with both depth maps, patchmatch).
    assert_eq!(rows.len(), 2 * 28, "{csv}");
    let count = |variant: &str| rows.iter().filter(|c| c[4] == variant).count();
    assert_eq!(count("realistic-depth"), 2 * 3);
    for option in
        ["layers-auto", "realistic-depth-layers-auto", "patchmatch", "realistic-depth-no-matte", "realistic-depth-no-matte-refine-off"]
    {
        assert_eq!(count(option), 2, "{option}");
    }
    // Outline scores: a share for every row, an alpha error on the pipeline's rows only (zero
    // where it was given the exact matte).
    for c in &rows {
        let v: f64 = c[VIOLATIONS_COL].parse().unwrap();
        assert!((0.0..=1.0).contains(&v), "{c:?}");
        let pipeline = c[3] == "drbokeh-pipeline";
        assert_eq!(c[ALPHA_MAE_COL].is_empty(), !pipeline, "{c:?}");
        if pipeline && !c[4].contains("no-matte") {
            assert_eq!(c[ALPHA_MAE_COL].parse::<f64>().unwrap(), 0.0, "{c:?}");
        }
    }
    let report = std::fs::read_to_string(rep.join("report.md")).unwrap();
    assert!(report.contains("### Edges without a matte (issue 42)"), "{report}");
    assert_eq!(count("physical-exact"), 2 * 4);
    assert_eq!(count("highlights-off"), 0, "the stage does nothing on linear input: not run");
    for c in &rows {
        assert_eq!(c[INPUT_COL], "linear");
        assert_eq!((c[LIGHT_MISSING_COL], c[LIGHT_RECOVERED_COL]), ("", ""), "no light columns on linear input: {c:?}");
    }
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    for needle in ["## Summary", "drbokeh-layers", "scatter-no-occlusion", "gather", "Per category", "vs **gather**", "error_vs_time.png"] {
        assert!(md.contains(needle), "report.md lacks {needle}:\n{md}");
    }
    assert!(!md.contains("## Inputs compared"), "one linear input: nothing to compare\n{md}");
    let png = std::fs::read(rep.join("error_vs_time.png")).unwrap();
    assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
    assert!(std::fs::read_dir(rep.join("crops")).unwrap().count() >= 1);
    std::fs::remove_dir_all(&dir).ok();
}

/// The 8-bit inputs (issue 35): the reference, default and realistic-depth settings of every
/// method plus the pipeline's highlights-off; the pipeline's highlights stage runs on them
/// (light recovered > 0 with `auto`, 0 with `off`); report.md compares the inputs.
#[test]
fn bench_on_8bit_inputs_compares_them() {
    let dir = tmp("bench-8bit");
    let o = drbokeh(
        &dir,
        &[
            "bench",
            "--scenes",
            "1",
            "--size",
            "64x64",
            "--seed",
            "3",
            "--spp",
            "64",
            "--repeats",
            "1",
            "--crops",
            "0",
            "--inputs",
            "srgb8-psf,srgb8",
            "--out",
            "rep",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let rep = dir.join("rep");
    let csv = std::fs::read_to_string(rep.join("report.csv")).unwrap();
    let rows = csv_rows(&csv);
    // Per input: layers and sliced 2 settings each, the pipeline 6, the scatter 3, the gather 2.
    assert_eq!(rows.len(), 2 * 15, "{csv}");
    for input in ["srgb8", "srgb8-psf"] {
        let of = |method: &str, variant: &str| {
            let r: Vec<&Vec<&str>> = rows.iter().filter(|c| c[INPUT_COL] == input && c[3] == method && c[4] == variant).collect();
            assert_eq!(r.len(), 1, "{input} {method} {variant}\n{csv}");
            r[0].clone()
        };
        for (m, v) in [("drbokeh-layers", "exact"), ("drbokeh-sliced", "physical-fast-q2"), ("scatter-no-occlusion", "realistic-depth")] {
            assert_eq!((of(m, v)[LIGHT_MISSING_COL], of(m, v)[LIGHT_RECOVERED_COL]), ("", ""), "{m} {v}");
        }
        of("gather", "realistic-depth");
        let auto = of("drbokeh-pipeline", "physical-fast-q2");
        let off = of("drbokeh-pipeline", "highlights-off");
        let no_matte = of("drbokeh-pipeline", "realistic-depth-no-matte");
        let missing: f64 = auto[LIGHT_MISSING_COL].parse().unwrap();
        assert!(missing > 1.0, "the scene's lights are clipped: {auto:?}");
        assert_eq!(off[LIGHT_MISSING_COL], auto[LIGHT_MISSING_COL]);
        assert_eq!(off[LIGHT_RECOVERED_COL].parse::<f64>().unwrap(), 0.0);
        assert!(no_matte[LIGHT_RECOVERED_COL].parse::<f64>().unwrap().is_finite());
        if input == "srgb8" {
            let recovered: f64 = auto[LIGHT_RECOVERED_COL].parse().unwrap();
            assert!(recovered > 0.0, "the highlights stage ran on the 8-bit photo: {auto:?}");
        }
    }
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    for needle in [
        "on the **srgb8** input",
        "## Inputs compared",
        "| method | setting | cases | srgb8 | srgb8-psf |",
        "| drbokeh-pipeline | highlights-off | 1 |",
        "`auto` (defaults) against `off`",
        "| srgb8-psf | all cases | 1 |",
        "Estimator-like depth, no matte",
        "Light recovered by the highlights stage",
        "(error_vs_time.png)",
        "(error_vs_time_srgb8-psf.png)",
    ] {
        assert!(md.contains(needle), "report.md lacks {needle}:\n{md}");
    }
    for png in ["error_vs_time.png", "error_vs_time_srgb8-psf.png"] {
        assert_eq!(&std::fs::read(rep.join(png)).unwrap()[..8], b"\x89PNG\r\n\x1a\n", "{png}");
    }
    assert!(!rep.join("error_vs_time_srgb8.png").exists(), "the primary input's plot is error_vs_time.png");
    // --inputs names what it does not know (with --dfd too, which takes it since 2026-11-28:
    // tests/dfd_bench.rs); --methods is still not for --dfd.
    for dfd in [&[][..], &["--dfd"][..]] {
        let o = drbokeh(&dir, &[&["bench"][..], dfd, &["--inputs", "srgb16", "--out", "x"]].concat());
        assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
        assert!(stderr(&o).contains("srgb16"), "{}", stderr(&o));
    }
    let o = drbokeh(&dir, &["bench", "--dfd", "--methods", "gather", "--out", "x"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--methods"), "{}", stderr(&o));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bench_on_the_shared_groundtruth_folders_and_bad_flags() {
    let dir = tmp("bench-gt");
    let gt = common::shared_dir().join("groundtruth");
    let o = drbokeh(
        &dir,
        &[
            "bench",
            "--groundtruth",
            gt.to_str().unwrap(),
            "--methods",
            "gather",
            "--inputs",
            "linear,srgb8",
            "--repeats",
            "1",
            "--crops",
            "0",
            "--out",
            "rep",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(dir.join("rep/report.csv")).unwrap();
    assert!(csv.contains("portrait,focus_fg") && csv.contains("thin_bars,focus_bg,bg_in_focus;thin"), "{csv}");
    for input in ["linear", "srgb8"] {
        let row = format!(",gather,default,{input},256,256,");
        assert!(csv.lines().any(|l| l.starts_with("portrait,focus_fg,") && l.contains(&row)), "{input}:\n{csv}");
    }
    let md = std::fs::read_to_string(dir.join("rep/report.md")).unwrap();
    assert!(md.contains("| gather | default |") && md.contains("## Inputs compared"), "{md}");
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
