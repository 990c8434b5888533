//! The matting stage's closed-form solver (`stages::closed_form`, `[segment] refine =
//! "closed-form"`) against PyMatting's closed-form matting (Levin et al. 2008,
//! `estimate_alpha_cf`), the oracle, on the same trimaps; the default colour-line fit's error is
//! printed beside them.
//!
//! Cases: the bench's scenes (seed 4, 128x128) whose true outline is soft (a quarter or more of
//! its partly covered pixels between 2% and 98%), segmented from the realistic depth map as the
//! pipeline does without a matte, the band measured from that map. Both methods see the
//! photo's linear colours clipped to [0, 1]. Over the unknown pixels, issue 42 asks for a mean
//! alpha difference ≤ 0.05, or an alpha error against the truth no worse than the oracle's.
//! Needs the test Python environment (`scripts/setup-test-env.sh`: PyMatting). Run with
//! `--nocapture` to see the figures.

use drbokeh::bench::scenes::generate;
use drbokeh::config::Config;
use drbokeh::image::Image;
use drbokeh::io::npy::{read_npy, save_npy};
use drbokeh::stages::depth_edges;
use drbokeh::stages::fill_depth::hard_mask;
use drbokeh::stages::matting::{Solver, band_for, fit, trimap};
use drbokeh::stages::segment::{Segmentation, from_disparity};
use std::path::Path;
use std::process::Command;

struct Case {
    name: String,
    photo: Image,
    trimap: Image,
    truth: Image,
    /// `refine = "closed-form"`'s solve.
    ours: Image,
    /// The default colour-line fit's, for the printed table.
    guided: Image,
}

/// Soft-edged bench scenes and our fit on their trimaps.
fn cases() -> Vec<Case> {
    let cfg = Config::default();
    let mut out = Vec::new();
    for i in 0..20 {
        let sc = generate(4, i, 128, 128, &[]);
        let inp = sc.inputs().unwrap();
        let m = &inp.matte.data;
        let (soft, edge) = (m.iter().filter(|&&a| a > 0.02 && a < 0.98).count(), m.iter().filter(|&&a| a > 0.0 && a < 1.0).count());
        if edge == 0 || (soft as f64) < 0.25 * edge as f64 {
            continue;
        }
        let Segmentation::Foreground(coarse) = from_disparity(&inp.realistic_disparity, &cfg.segment) else { continue };
        let edges = depth_edges::measure(&inp.realistic_disparity, &hard_mask(&coarse, &cfg.fill_depth), 128, 128);
        let band = band_for(&edges);
        let Some(trimap) = trimap(&coarse, band) else { continue };
        let mut photo = inp.aif.clone();
        photo.map_inplace(|v| v.clamp(0.0, 1.0));
        let (ours, _) = fit(&photo, &coarse, band, Solver::ClosedForm);
        let (guided, _) = fit(&photo, &coarse, band, Solver::Guided);
        out.push(Case { name: format!("seed 4 s{i:03}"), photo, trimap, truth: inp.matte.clone(), ours, guided });
    }
    out
}

/// PyMatting's alpha for every case, from one Python process.
fn closed_form(cases: &[Case], dir: &Path) -> Vec<Image> {
    let py = Path::new(env!("CARGO_MANIFEST_DIR")).join(".venv/bin/python");
    assert!(py.exists(), "{} is missing: run scripts/setup-test-env.sh", py.display());
    let manifest: Vec<serde_json::Value> = cases
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let (img, tri, out) = (dir.join(format!("img{i}.npy")), dir.join(format!("tri{i}.npy")), dir.join(format!("out{i}.npy")));
            save_npy(&img, &c.photo).unwrap();
            save_npy(&tri, &c.trimap).unwrap();
            serde_json::json!({"image": img, "trimap": tri, "out": out})
        })
        .collect();
    let path = dir.join("manifest.json");
    std::fs::write(&path, serde_json::to_vec(&manifest).unwrap()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/oracle/closed_form.py");
    let out = Command::new(py).arg(script).arg(&path).output().expect("run the PyMatting oracle");
    assert!(out.status.success(), "oracle failed:\n{}", String::from_utf8_lossy(&out.stderr));
    (0..cases.len()).map(|i| read_npy(&dir.join(format!("out{i}.npy")), u64::MAX).unwrap()).collect()
}

/// Mean |a − b| over the trimap's unknown pixels.
fn mean_over_unknown(a: &Image, b: &Image, trimap: &Image) -> f64 {
    let (mut s, mut n) = (0f64, 0usize);
    for ((x, y), &t) in a.data.iter().zip(&b.data).zip(&trimap.data) {
        if t == 0.5 {
            s += (x - y).abs() as f64;
            n += 1;
        }
    }
    s / n.max(1) as f64
}

#[test]
fn closed_form_solver_against_pymatting() {
    let cases = cases();
    assert!(cases.len() >= 3, "too few soft-edged scenes: {}", cases.len());
    let dir = tempfile::tempdir().unwrap();
    let oracle = closed_form(&cases, dir.path());
    println!("case          unknown  |ours-cf|  ours-truth  cf-truth  guided-truth");
    let mut failed = Vec::new();
    for (c, cf) in cases.iter().zip(&oracle) {
        let unknown = c.trimap.data.iter().filter(|&&t| t == 0.5).count();
        let diff = mean_over_unknown(&c.ours, cf, &c.trimap);
        let (ours_err, cf_err) = (mean_over_unknown(&c.ours, &c.truth, &c.trimap), mean_over_unknown(cf, &c.truth, &c.trimap));
        let guided_err = mean_over_unknown(&c.guided, &c.truth, &c.trimap);
        println!("{}  {unknown:7}  {diff:8.4}  {ours_err:10.4}  {cf_err:8.4}  {guided_err:12.4}", c.name);
        if diff > 0.05 && ours_err > cf_err {
            failed.push(format!("{}: |ours - cf| {diff:.4}, error {ours_err:.4} against the oracle's {cf_err:.4}", c.name));
        }
    }
    assert!(failed.is_empty(), "worse than closed-form matting:\n{}", failed.join("\n"));
}
