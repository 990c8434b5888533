//! ONNX stage benchmark (release build): `cargo bench --bench onnx`.
//!
//! For every stub in models-stub/ at 1 MP (1024x1024): session creation time, per-image time
//! with a warm session split into pre-processing, inference and post-processing, and a batch
//! of images with the session reused vs. created per image. Stubs compute almost nothing, so
//! inference time here is ONNX Runtime's fixed cost plus tensor traffic at the model's input
//! size; with a real model inference dominates and the pre/post figures are the overhead
//! drbokeh adds. Options: `-- --reps N` (default 5), `-- --batch N` (default 8).

use drbokeh::Image;
use drbokeh::onnx::session::clear_cache;
use drbokeh::onnx::{ModelSpec, OnnxConfig, OnnxReport, runtime};
use drbokeh::stages::background::{BandReach, InpaintOptions, Reach};
use drbokeh::stages::inpaint_onnx::{self, InpaintMethod};
use drbokeh::stages::{depth_onnx, segment_onnx};
use std::path::Path;
use std::time::Instant;

fn photo(w: usize, h: usize) -> Image {
    let mut img = Image::new(w, h, 3);
    for (i, p) in img.data.chunks_exact_mut(3).enumerate() {
        let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
        p.copy_from_slice(&[x * 0.8, y * 0.6 + 0.1, ((x * 13.0).sin() * 0.5 + 0.5) * 0.7]);
    }
    img
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

#[derive(Clone, Copy)]
enum Kind {
    Matte,
    Depth,
    Inpaint,
}

struct Case {
    file: &'static str,
    preset: &'static str,
    kind: Kind,
}

fn run_once(c: &Case, spec: &ModelSpec, cfg: &OnnxConfig, rgb: &Image, disp: &Image, alpha: &Image) -> OnnxReport {
    match c.kind {
        Kind::Matte => segment_onnx::predict_matte(rgb, spec, cfg).unwrap().1,
        Kind::Depth => depth_onnx::estimate_disparity(rgb, spec, cfg).unwrap().1,
        Kind::Inpaint => {
            let opts = InpaintOptions { method: InpaintMethod::Onnx, onnx: spec.clone(), ..InpaintOptions::default() };
            inpaint_onnx::inpaint_background(rgb, disp, alpha, &opts, Reach::Pixels(64.0), (0.0, BandReach::Any), cfg).unwrap().1
        }
    }
}

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() {
    let reps = arg("--reps", 5).max(1);
    let batch = arg("--batch", 8).max(1);
    let stubs = Path::new(env!("CARGO_MANIFEST_DIR")).join("models-stub");
    let cfg = OnnxConfig::default();
    let (w, h) = (1024, 1024);
    let rgb = photo(w, h);
    let disp = Image::from_vec(w, h, 1, (0..w * h).map(|i| (i % w) as f32 / w as f32 * 0.5).collect()).unwrap();
    let alpha = Image::from_vec(
        w,
        h,
        1,
        (0..w * h)
            .map(|i| (200.0 - (((i % w) as f32 - 500.0).powi(2) + ((i / w) as f32 - 480.0).powi(2)).sqrt()).clamp(0.0, 1.0))
            .collect(),
    )
    .unwrap();
    let cases = [
        Case { file: "u2net.onnx", preset: "u2net", kind: Kind::Matte },
        Case { file: "isnet.onnx", preset: "isnet", kind: Kind::Matte },
        Case { file: "birefnet.onnx", preset: "birefnet", kind: Kind::Matte },
        Case { file: "modnet.onnx", preset: "modnet", kind: Kind::Matte },
        Case { file: "mediapipe_selfie.onnx", preset: "mediapipe-selfie", kind: Kind::Matte },
        Case { file: "midas_small.onnx", preset: "midas-small", kind: Kind::Depth },
        Case { file: "depth_anything_v2.onnx", preset: "depth-anything-v2", kind: Kind::Depth },
        Case { file: "lama.onnx", preset: "lama", kind: Kind::Inpaint },
        Case { file: "lama_dynamic.onnx", preset: "lama-dynamic", kind: Kind::Inpaint },
    ];

    let t = Instant::now();
    let rt = runtime::runtime(&cfg).expect("ONNX Runtime (run scripts/setup-test-env.sh or set ORT_DYLIB_PATH)");
    println!(
        "ONNX Runtime {} from {}: loaded in {:.1} ms (once per process)",
        rt.version,
        rt.library.display(),
        t.elapsed().as_secs_f64() * 1e3
    );
    println!(
        "image {w}x{h} (1 MP), {reps} repetitions (medians), rayon threads {}, ORT intra-op threads default",
        rayon::current_num_threads()
    );
    println!();
    println!(
        "| stub | model input | session create ms | first infer ms (new session) | per image ms (warm) | pre ms | infer ms | post ms | (pre+post)/infer | batch {batch}: reuse ms | batch {batch}: new session per image ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for c in &cases {
        let spec = ModelSpec { model: Some(stubs.join(c.file)), preset: Some(c.preset.into()), ..ModelSpec::default() };
        // Session creation: cold each time.
        let (mut create, mut cold) = (Vec::new(), Vec::new());
        for _ in 0..reps {
            clear_cache();
            let r = run_once(c, &spec, &cfg, &rgb, &disp, &alpha);
            create.push(r.session_ms);
            cold.push(r.infer_ms);
        }
        // Warm per-image time and its split.
        let (mut total, mut pre, mut inf, mut post) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        let mut size = [0, 0];
        for _ in 0..reps {
            let t = Instant::now();
            let r = run_once(c, &spec, &cfg, &rgb, &disp, &alpha);
            total.push(t.elapsed().as_secs_f64() * 1e3);
            assert!(r.session_cached);
            pre.push(r.pre_ms);
            inf.push(r.infer_ms);
            post.push(r.post_ms);
            size = r.model_size;
        }
        // A batch: one session for all images vs. a new session for each.
        let t = Instant::now();
        for _ in 0..batch {
            run_once(c, &spec, &cfg, &rgb, &disp, &alpha);
        }
        let reuse = t.elapsed().as_secs_f64() * 1e3;
        let t = Instant::now();
        for _ in 0..batch {
            clear_cache();
            run_once(c, &spec, &cfg, &rgb, &disp, &alpha);
        }
        let fresh = t.elapsed().as_secs_f64() * 1e3;
        let (pre, inf, post) = (median(pre), median(inf), median(post));
        println!(
            "| {} | {}x{} | {:.2} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.2} | {:.0} | {:.0} |",
            c.preset,
            size[0],
            size[1],
            median(create),
            median(cold),
            median(total),
            pre,
            inf,
            post,
            (pre + post) / inf.max(1e-9),
            reuse,
            fresh
        );
    }
}
