//! `drbokeh bench --dfd` end to end on a tiny configuration: one generated scene and the
//! shared Mitsuba scenes at 32 px, few Adam steps. Checks the report's files and that its
//! numbers are sane (the true disparity re-renders well, every estimate beats the start).

use crate::common;

use common::{assert_usage_error, drbokeh, run, shared_dir, stderr};
use std::collections::BTreeMap;

/// report.csv as (scene, method) → column → value.
fn read_csv(text: &str) -> BTreeMap<(String, String), BTreeMap<String, String>> {
    let mut lines = text.lines();
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    lines
        .map(|l| {
            let row: BTreeMap<String, String> = head.iter().zip(l.split(',')).map(|(k, v)| (k.to_string(), v.to_string())).collect();
            ((row["scene"].clone(), row["method"].clone()), row)
        })
        .collect()
}

/// `bench --dfd` on one generated scene of `size`, 5 steps at one level, 16 rays a pixel,
/// with `more` flags, its report in `dir/rep`; asserts exit 0.
fn tiny_bench(dir: &std::path::Path, size: &str, more: &[&str]) {
    let out = run({
        let mut c = drbokeh(dir);
        c.args(["bench", "--dfd", "--scenes", "1", "--size", size, "--iters", "5", "--levels", "1", "--spp", "16", "--out", "rep"]);
        c.args(more);
        c
    });
    assert!(out.status.success(), "bench --dfd failed: {}", stderr(&out));
}

#[test]
fn dfd_bench_writes_a_sane_report() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let gt = shared_dir().join("groundtruth");
    let out = run({
        let mut c = drbokeh(dir);
        c.args(["bench", "--dfd", "--scenes", "1", "--size", "32x32", "--iters", "25", "--levels", "2", "--spp", "64", "--out", "rep"])
            .arg("--groundtruth")
            .arg(&gt);
        c
    });
    assert!(out.status.success(), "bench --dfd failed: {}", stderr(&out));
    let rep = dir.join("rep");
    for f in ["report.csv", "report.md", "figures/s000.png", "figures/portrait.png", "figures/thin_bars.png"] {
        assert!(rep.join(f).is_file(), "{f} missing");
    }
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    assert!(md.contains("## Acceptance") && md.contains("gauss-psf") && md.contains("true-disparity"), "{md}");
    let rows = read_csv(&std::fs::read_to_string(rep.join("report.csv")).unwrap());
    let num = |scene: &str, m: &str, col: &str| -> f64 {
        let r = rows.get(&(scene.to_string(), m.to_string())).unwrap_or_else(|| panic!("no row {scene} {m}"));
        r[col].parse().unwrap_or_else(|_| panic!("{scene} {m} {col}: {}", r[col]))
    };
    let methods = ["drbokeh-physical", "drbokeh-official", "drbokeh-no-occlusion", "gauss-psf", "drbokeh-l1-grad", "drbokeh-l1-grad-ssim"];
    for scene in ["s000", "portrait", "thin_bars"] {
        assert_eq!(num(scene, "true-disparity", "disparity_mae"), 0.0);
        let psnr = num(scene, "true-disparity", "rerender_psnr_srgb");
        assert!(psnr > 20.0 && psnr.is_finite(), "{scene}: true-disparity re-render PSNR {psnr}");
        let init = num(scene, "init", "disparity_mae");
        for m in methods {
            let mae = num(scene, m, "disparity_mae");
            assert!(mae.is_finite() && mae < init, "{scene} {m}: disparity MAE {mae}, start {init}");
            assert!(num(scene, m, "rerender_ssim_srgb") > 0.0 && num(scene, m, "time_ms") > 0.0);
        }
    }
    // The literature's measures where the scene states its depth range (the shared scenes),
    // empty cells where it does not (the generated ones).
    assert!(md.contains("## Depth and inverse depth") && md.contains("depth AbsRel"), "{md}");
    let cols = ["depth_abs_rel", "depth_rmse", "depth_delta1", "inverse_depth_abs_rel", "inverse_depth_rmse", "inverse_depth_delta1"];
    for scene in ["portrait", "thin_bars"] {
        for c in cols {
            let exact = num(scene, "true-disparity", c);
            assert_eq!(exact, if c.ends_with("delta1") { 1.0 } else { 0.0 }, "{scene} {c}");
            for m in methods.iter().chain(&["init"]) {
                let v = num(scene, m, c);
                assert!(v.is_finite() && v >= 0.0 && (!c.ends_with("delta1") || v <= 1.0), "{scene} {m} {c}: {v}");
            }
        }
        // The constant start is far from a two-depth scene: some error on every measure.
        assert!(num(scene, "init", "depth_abs_rel") > 0.05 && num(scene, "init", "depth_delta1") < 1.0);
    }
    for c in cols {
        assert_eq!(rows[&("s000".to_string(), "drbokeh-physical".to_string())][c], "", "s000 {c}");
    }
    // --scenes 0 without ground truth: a usage error naming the flag.
    assert_usage_error(dir, "bench --dfd --scenes 0", &["--scenes"], || {
        let mut c = drbokeh(dir);
        c.args(["bench", "--dfd", "--scenes", "0", "--out", "none"]);
        run(c)
    });
}

/// A non-square frame (the figure panels once assumed square ones and the report ended in an
/// internal error after report.md, leaving no figures): the whole report is written, exit 0.
/// With `--inputs linear,srgb8` every method and reference has a row per input, and the 8-bit
/// rows start from the 8-bit photo (the true map's re-render differs; its disparity error
/// stays 0) and have their own section in report.md.
#[test]
fn dfd_bench_takes_a_non_square_frame_and_8bit_photos() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    tiny_bench(dir, "40x24", &["--inputs", "srgb8,linear"]);
    let fig = image::open(dir.join("rep/figures/s000.png")).expect("the figure");
    // Panels of 40x24 at 2x zoom under an 18 px label band.
    assert_eq!(fig.height(), 24 * 2 + 18);
    let text = std::fs::read_to_string(dir.join("rep/report.csv")).unwrap();
    let head: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let rows: Vec<BTreeMap<&str, &str>> = text.lines().skip(1).map(|l| head.iter().copied().zip(l.split(',')).collect()).collect();
    let of = |input: &str, method: &str| -> BTreeMap<&str, &str> {
        let found: Vec<_> = rows.iter().filter(|r| r["input"] == input && r["method"] == method).collect();
        assert_eq!(found.len(), 1, "{input} {method}: {} rows", found.len());
        found[0].clone()
    };
    for m in ["drbokeh-physical", "drbokeh-official", "drbokeh-no-occlusion", "gauss-psf", "init", "true-disparity"] {
        for input in ["linear", "srgb8"] {
            let r = of(input, m);
            for c in ["disparity_mae", "rerender_psnr_srgb", "rerender_psnr_linear"] {
                assert!(r[c].parse::<f64>().unwrap().is_finite(), "{input} {m} {c}: {}", r[c]);
            }
        }
    }
    assert_eq!(rows.len(), 2 * (7 + 2));
    let (lin, q) = (of("linear", "true-disparity"), of("srgb8", "true-disparity"));
    assert_eq!((lin["disparity_mae"], q["disparity_mae"]), ("0.000000", "0.000000"));
    assert_ne!(lin["rerender_psnr_linear"], q["rerender_psnr_linear"], "the 8-bit row re-renders the 8-bit photo");
    let md = std::fs::read_to_string(dir.join("rep/report.md")).unwrap();
    assert!(md.contains("## Input `srgb8`") && md.contains("### Acceptance, input `srgb8`"), "{md}");
    // The linear input is the primary one whatever the order given.
    assert!(md.contains("are for `linear`"), "{md}");
}

/// `--dfd-methods` runs only the methods named (in report order, whatever the order given);
/// the acceptance checks compare with the ablations that ran. A name it does not know, or the
/// flag without `--dfd`, is a usage error naming it.
#[test]
fn dfd_bench_runs_the_methods_asked_for() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    tiny_bench(dir, "24x24", &["--dfd-methods", "drbokeh-no-occlusion,drbokeh-physical"]);
    let text = std::fs::read_to_string(dir.join("rep/report.csv")).unwrap();
    let methods: Vec<&str> = text.lines().skip(1).map(|l| l.split(',').nth(2).unwrap()).collect();
    assert_eq!(methods, ["true-disparity", "init", "drbokeh-physical", "drbokeh-no-occlusion"], "{text}");
    let md = std::fs::read_to_string(dir.join("rep/report.md")).unwrap();
    assert!(md.contains("**drbokeh-physical** vs **drbokeh-no-occlusion**") && !md.contains("gauss-psf"), "{md}");
    assert_usage_error(dir, "an unknown method", &["--dfd-methods", "gauss"], || {
        let mut c = drbokeh(dir);
        c.args(["bench", "--dfd", "--dfd-methods", "gauss", "--out", "x"]);
        run(c)
    });
    assert_usage_error(dir, "without --dfd", &["--dfd-methods", "--dfd"], || {
        let mut c = drbokeh(dir);
        c.args(["bench", "--dfd-methods", "drbokeh-physical", "--out", "x"]);
        run(c)
    });
}

/// The ray test (the default plan at this size) fixes the span render's worst failure: on the
/// shared Mitsuba portrait at 64 px, whose HDR highlights sit in a textureless sky, the span
/// render's estimate re-renders the far focus at 19.8 dB linear, the ray test's at 35.5 (the
/// true map's: 31.2; README, seed 1's report). (Before the coarse levels kept HDR values, the
/// span render's was 11.4 dB.) Asserted with margins: the ray estimate at least 10 dB above
/// the span one and within 5 dB of the true map's or above it.
#[test]
fn ray_test_fixes_the_portrait_highlights() {
    use drbokeh::bench::dfd_eval::{DfdBenchOptions, DfdMethod, load_case, rerender};
    use drbokeh::bench::run::score;
    use drbokeh::diff::dfd::{self, DfdKernel, DfdOptions};
    let gt = shared_dir().join("groundtruth");
    let dirs = drbokeh::bench::groundtruth::scene_dirs(&gt).unwrap();
    let portrait = dirs.iter().position(|d| d.ends_with("portrait")).expect("the shared portrait");
    let opts = DfdBenchOptions { scenes: 0, groundtruth: Some(gt), ..DfdBenchOptions::default() };
    let case = load_case(&opts, &dirs, portrait, &mut |_| {}).unwrap();
    let (s, loss, renderer) = DfdMethod::Physical.setup(case.blur, case.focus);
    let linear = |kernel| {
        let o = DfdOptions { weights: loss.weights(), renderer, kernel, ..DfdOptions::default() };
        assert_eq!(dfd::plan(case.aif.width, case.aif.height, &s, &o).finest_level, 0);
        let d = dfd::estimate(&case.aif, &case.target, &s, &o, |_| {}).unwrap();
        score(&rerender(&case.aif, &d, case.blur, case.other_focus).unwrap(), &case.other, case.border).psnr
    };
    let truth = score(&rerender(&case.aif, &case.truth, case.blur, case.other_focus).unwrap(), &case.other, case.border).psnr;
    let (span, ray) = (linear(DfdKernel::Fast), linear(DfdKernel::Auto));
    eprintln!("portrait far-focus re-render, linear: span {span:.2} dB, ray test {ray:.2} dB, true map {truth:.2} dB");
    assert!(ray >= span + 10.0 && ray >= truth - 5.0, "span {span:.2}, ray {ray:.2}, truth {truth:.2}");
}
