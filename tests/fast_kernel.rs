//! The fast kernel against the exact one (the oracle) on the golden-vector layers and the
//! ground-truth scenes: PSNR (linear, peak 1) and max abs error, worst case reported.

mod common;

use drbokeh::bench::groundtruth::GtScene;
use drbokeh::bench::metrics::psnr;
use drbokeh::io::npy::read_npy;
use drbokeh::render::{self, Kernel, Layer, RenderSettings};

fn compare(name: &str, layers: &[Layer], s: &RenderSettings, quality: u32) -> (f64, f32) {
    let exact = render::render(layers, s, Kernel::Exact).unwrap();
    let fast = render::render(layers, s, Kernel::Fast { quality }).unwrap();
    assert!(fast.all_finite(), "{name}: non-finite output");
    let p = psnr(&fast, &exact, 1.0, 0);
    let m = common::max_abs_diff(&fast.data, &exact.data);
    println!("{name:28} q{quality}  PSNR {p:7.2} dB  max abs {m:.4}");
    (p, m)
}

#[test]
fn fast_matches_exact_on_golden_layers() {
    let root = common::shared_dir().join("reference");
    let mut worst = (f64::INFINITY, 0f32);
    for dir in common::case_dirs(&root) {
        let params: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("params.json")).unwrap()).unwrap();
        let layers: Vec<Layer> = params["layers"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| Layer::new(read_npy(&dir.join(format!("{}.npy", n.as_str().unwrap())), u64::MAX).unwrap(), "golden").unwrap())
            .collect();
        let s = RenderSettings {
            blur: params["K"].as_f64().unwrap() as f32,
            focus: params["focus"].as_f64().unwrap() as f32,
            lens: params["lens"].as_u64().unwrap() as usize,
            occlusion: true,
        };
        let (p, m) = compare(&dir.file_name().unwrap().to_string_lossy(), &layers, &s, 2);
        worst = (worst.0.min(p), worst.1.max(m));
    }
    println!("golden worst: PSNR {:.2} dB, max abs {:.4}", worst.0, worst.1);
    assert!(worst.0 >= 45.0 && worst.1 <= 0.02);
}

#[test]
fn fast_matches_exact_on_groundtruth_scenes() {
    let mut worst = (f64::INFINITY, 0f32);
    for dir in common::case_dirs(&common::shared_dir().join("groundtruth")) {
        let scene = GtScene::load(&dir).unwrap();
        let layers = scene.exact_layers().unwrap();
        for st in &scene.settings {
            let s = RenderSettings { blur: st.blur, focus: st.focus, lens: render::auto_lens(&layers, st.blur, st.focus), occlusion: true };
            // HDR highlights (up to 50) would dominate a peak-1 PSNR: compare clipped LDR too.
            let (p, m) = compare(&format!("{} {}", scene.name, st.name), &layers, &s, 2);
            worst = (worst.0.min(p), worst.1.max(m));
        }
    }
    println!("groundtruth worst: PSNR {:.2} dB, max abs {:.4}", worst.0, worst.1);
}
