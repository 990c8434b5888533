//! The fast kernel against the exact one (the oracle) on the golden-vector layers and the
//! ground-truth scenes: PSNR (linear, peak 1) and max abs error, worst case reported.

mod common;

use drbokeh::bench::groundtruth::GtScene;
use drbokeh::bench::metrics::psnr;
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
        // Gamma only changes the colours fed in; the kernels see the same layers.
        let (layers, s, _, _) = common::golden_case(&dir);
        let (p, m) = compare(&dir.file_name().unwrap().to_string_lossy(), &layers, &s, 2);
        worst = (worst.0.min(p), worst.1.max(m));
    }
    println!("golden worst: PSNR {:.2} dB, max abs {:.4}", worst.0, worst.1);
    assert!(worst.0 >= 45.0 && worst.1 <= 0.02);
}

#[test]
fn fast_matches_exact_on_groundtruth_scenes() {
    // These scenes hold HDR highlights (up to 50): the bounds are checked on the linear
    // output and on the displayable range (both renders clipped to [0, 1], as an LDR output
    // would be).
    let (mut worst, mut worst_ldr) = ((f64::INFINITY, 0f32), (f64::INFINITY, 0f32));
    for dir in common::case_dirs(&common::shared_dir().join("groundtruth")) {
        let scene = GtScene::load(&dir).unwrap();
        let layers = scene.exact_layers().unwrap();
        for st in &scene.settings {
            let s = RenderSettings {
                blur: st.blur,
                focus: st.focus,
                lens: render::auto_lens(&layers, st.blur, st.focus),
                occlusion: true,
                profile: drbokeh::render::Profile::Official,
            };
            let name = format!("{} {}", scene.name, st.name);
            let (p, m) = compare(&name, &layers, &s, 2);
            worst = (worst.0.min(p), worst.1.max(m));
            let clip = |k| {
                let mut img = render::render(&layers, &s, k).unwrap();
                img.map_inplace(|v| v.clamp(0.0, 1.0));
                img
            };
            let (e, f) = (clip(Kernel::Exact), clip(Kernel::Fast { quality: 2 }));
            let (p, m) = (psnr(&f, &e, 1.0, 0), common::max_abs_diff(&f.data, &e.data));
            println!("{:28} q2  clipped to [0, 1]: PSNR {p:7.2} dB  max abs {m:.4}", name);
            worst_ldr = (worst_ldr.0.min(p), worst_ldr.1.max(m));
        }
    }
    println!("groundtruth worst: PSNR {:.2} dB, max abs {:.4} (HDR); clipped: {:.2} dB, {:.4}", worst.0, worst.1, worst_ldr.0, worst_ldr.1);
    // Bright sources are drawn exactly (fast::rim_disk), so the LDR bars hold even unclipped.
    assert!(worst.0 >= 45.0 && worst.1 <= 0.02, "{worst:?}");
    assert!(worst_ldr.0 >= 45.0 && worst_ldr.1 <= 0.02, "clipped: {worst_ldr:?}");
}

#[test]
fn fast_matches_exact_on_stress_scenes() {
    use drbokeh::bench::stress::two_layer_scene;
    let mut worst = (f64::INFINITY, 0f32);
    for (focus_fg, coc) in [(true, 6.0), (true, 20.0), (false, 12.0)] {
        let (layers, s) = two_layer_scene(96, 80, coc, focus_fg);
        let (p, m) = compare(&format!("stress fg={focus_fg} coc={coc}"), &layers, &s, 2);
        worst = (worst.0.min(p), worst.1.max(m));
        // Focus between the layers.
        let s_mid = RenderSettings { focus: 0.75, ..s };
        let (p, m) = compare(&format!("stress between coc={coc}"), &layers, &s_mid, 2);
        worst = (worst.0.min(p), worst.1.max(m));
    }
    println!("stress worst: PSNR {:.2} dB, max abs {:.4}", worst.0, worst.1);
    assert!(worst.0 >= 45.0 && worst.1 <= 0.02);
}

#[test]
fn fast_kernel_converges_with_quality() {
    use drbokeh::bench::stress::two_layer_scene;
    let (layers, s) = two_layer_scene(64, 48, 10.0, true);
    let (p1, _) = compare("converge q1", &layers, &s, 1);
    let (p8, m8) = compare("converge q8", &layers, &s, 8);
    assert!(p8 > p1 && p8 > 70.0 && m8 < 1e-3, "q8: {p8} dB, {m8}");
}

#[test]
fn fast_kernel_is_deterministic_across_thread_counts() {
    use drbokeh::bench::stress::two_layer_scene;
    let (layers, s) = two_layer_scene(120, 90, 24.0, false);
    let run = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| render::render(&layers, &s, Kernel::Fast { quality: 2 }).unwrap())
    };
    assert_eq!(run(1).data, run(2).data);
    assert_eq!(run(3).data, run(2).data);
}

#[test]
fn fast_kernel_keeps_uniform_colour_and_hdr_finite() {
    use drbokeh::Image;
    let (w, h) = (40, 30);
    let mut fg = Vec::new();
    let mut bg = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let a = if (x as i32 - 20).abs() < 8 && (y as i32 - 15).abs() < 6 { 1.0 } else { 0.0 };
            fg.extend_from_slice(&[0.3, 0.6, 0.9, a, 0.9]);
            bg.extend_from_slice(&[0.3, 0.6, 0.9, 1.0, (x as f32 / w as f32) * 0.5]);
        }
    }
    let layers = vec![
        Layer::new(Image::from_vec(w, h, 5, fg).unwrap(), "fg").unwrap(),
        Layer::new(Image::from_vec(w, h, 5, bg.clone()).unwrap(), "bg").unwrap(),
    ];
    for (k, f) in [(0.0, 0.5), (5.0, 0.9), (30.0, 0.0), (60.0, 0.4)] {
        let s = RenderSettings {
            blur: k,
            focus: f,
            lens: render::auto_lens(&layers, k, f),
            occlusion: true,
            profile: drbokeh::render::Profile::Official,
        };
        let out = render::render(&layers, &s, Kernel::Fast { quality: 2 }).unwrap();
        for px in out.data.chunks_exact(3) {
            assert!((px[0] - 0.3).abs() < 1e-5 && (px[1] - 0.6).abs() < 1e-5 && (px[2] - 0.9).abs() < 1e-5, "K={k} f={f}: {px:?}");
        }
    }
    // HDR highlights (1e4) stay finite.
    for (i, px) in bg.chunks_exact_mut(5).enumerate() {
        if i % 37 == 0 {
            px[0] = 1e4;
        }
    }
    let layers = vec![Layer::new(Image::from_vec(w, h, 5, bg).unwrap(), "bg").unwrap()];
    let s = RenderSettings {
        blur: 40.0,
        focus: 1.0,
        lens: render::auto_lens(&layers, 40.0, 1.0),
        occlusion: true,
        profile: drbokeh::render::Profile::Official,
    };
    assert!(render::render(&layers, &s, Kernel::Fast { quality: 2 }).unwrap().all_finite());
}

/// Sources above 1.25 (bright) get their exact footprint at any radius, but at most ~1% of them (the
/// brightest), so a photo with a large bright area keeps its near-constant cost; a few
/// highlights in an LDR scene are all drawn exactly.
#[test]
fn bright_sources_are_exact_and_capped() {
    use drbokeh::bench::stress::two_layer_scene;
    use drbokeh::render::fast::{FastParams, scatter_layer};
    let (layers, s) = two_layer_scene(120, 90, 24.0, true);
    // Most of the background bright (a bright sky), with a few far brighter points.
    let mut bg = layers[1].image().clone();
    for (i, px) in bg.data.chunks_exact_mut(5).enumerate() {
        let k = if i % 997 == 500 { 40.0 } else { 2.0 };
        px[0] *= k;
        px[1] = px[1] * k + 0.01;
        px[2] *= k;
    }
    let bg = Layer::new(bg, "bright bg").unwrap();
    let (_, st) = scatter_layer(&bg, &s, FastParams::from_quality(2));
    let visible = 120 * 90;
    assert!(st.bright_sources > 0 && st.bright_sources <= visible / 100 + 1, "{} bright sources of {visible}", st.bright_sources);
    let fast = render::render(&[layers[0].clone(), bg.clone()], &s, Kernel::Fast { quality: 2 }).unwrap();
    assert!(fast.all_finite());
    // With only the few highlights bright, every one is drawn exactly. (Off the corners:
    // a corner highlight is replicated by the border padding into a block of copies whose
    // colour magnifies the coarse grids' small weight error there.)
    let mut few = layers[1].image().clone();
    for (i, px) in few.data.chunks_exact_mut(5).enumerate() {
        if i % 997 == 500 {
            px[0] = 40.0;
        }
    }
    let few = Layer::new(few, "highlights").unwrap();
    let (_, st) = scatter_layer(&few, &s, FastParams::from_quality(2));
    assert_eq!(st.bright_sources, (0..visible).filter(|i| i % 997 == 500).count());
    let (p, m) = compare("bright highlights", &[layers[0].clone(), few], &s, 2);
    assert!(p >= 45.0 && m <= 0.02, "{p} dB, {m}");
}
