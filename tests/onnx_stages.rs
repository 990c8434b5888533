//! ONNX stages against the stub models in models-stub/: every preset's stub runs through the
//! real pre-processing, session and post-processing, and the result must equal a Rust-side
//! computation of the stub's known function within 1e-5. Then every model error.
//!
//! ONNX Runtime comes from the test environment (`scripts/setup-test-env.sh` installs the
//! onnxruntime wheel into .venv; the library finds it there) or ORT_DYLIB_PATH.

use drbokeh::bench::metrics::srgb;
use drbokeh::color::{PhotoEncoding, Transfer, linear_to_srgb, srgb_to_linear};
use drbokeh::onnx::binding;
use drbokeh::onnx::contract::{self, ColorOrder, Layout, ModelKind, ResizeMode, SizeSpec};
use drbokeh::onnx::prep::{self, Geometry};
use drbokeh::onnx::{DepthFill, ModelSpec, OnnxConfig};
use drbokeh::stages::background::{BandReach, InpaintOptions, Reach};
use drbokeh::stages::inpaint::{TeleaOptions, inpaint_telea};
use drbokeh::stages::inpaint_onnx::{self, region, seam_weight};
use drbokeh::stages::light_recovery::{self, HighlightMode, HighlightsOptions, Recovered};
use drbokeh::stages::mask::distance_to;
use drbokeh::stages::{depth_onnx, segment_onnx};
use drbokeh::{Error, Image};
use std::path::{Path, PathBuf};

/// The stubs' function (see models-stub/generate.py).
const W: [f32; 3] = [0.8, -0.5, 0.3];
const B: f32 = 0.1;
const TOL: f32 = 1e-5;

fn stub(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("models-stub").join(name)
}

fn spec(model: &str, preset: &str) -> ModelSpec {
    ModelSpec { model: Some(stub(model)), preset: Some(preset.into()), ..ModelSpec::default() }
}

fn cfg() -> OnnxConfig {
    OnnxConfig { threads: 1, ..OnnxConfig::default() }
}

/// A small linear-RGB test photo: gradients plus a bright disk.
fn photo(w: usize, h: usize) -> Image {
    let mut img = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let disk = ((x as f32 - w as f32 * 0.6).powi(2) + (y as f32 - h as f32 * 0.4).powi(2)).sqrt() < h as f32 * 0.25;
            let p = img.pixel_mut(x, y);
            p[0] = if disk { 0.9 } else { x as f32 / w as f32 * 0.7 };
            p[1] = if disk { 0.6 } else { y as f32 / h as f32 * 0.5 + 0.05 };
            p[2] = ((x * 7 + y * 3) % 11) as f32 / 11.0 * 0.8;
        }
    }
    img
}

fn sigmoid(v: f32) -> f32 {
    1.0 / (1.0 + (-v).exp())
}

fn minmax(v: &mut [f32]) {
    let (lo, hi) = v.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
    v.iter_mut().for_each(|x| *x = if hi > lo { (*x - lo) / (hi - lo) } else { 0.0 });
}

fn max_diff(a: &Image, b: &Image) -> f32 {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels));
    a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Rust-side expected output of a 1x1-conv stub for a preset: sRGB-encode, resize into the
/// model canvas, normalize with the preset's mean/std in the contract's colour order, apply
/// W·x + B (+ sigmoid), min-max over the content when the preset says so, resize back.
fn expected_conv(rgb: &Image, c: &contract::Contract, g: &Geometry, sigmoid_out: bool) -> Image {
    let r = srgb(rgb).resized(g.w, g.h);
    let k = match c.scale {
        contract::ValueScale::Unit => 1.0,
        contract::ValueScale::Byte => 255.0,
    };
    let order = match c.color {
        ColorOrder::Rgb => [0, 1, 2],
        ColorOrder::Bgr => [2, 1, 0],
    };
    let mut y: Vec<f32> = r
        .data
        .chunks_exact(3)
        .map(|p| {
            let x: Vec<f32> = order.iter().map(|&col| (p[col] * k - c.mean[col]) / c.std[col]).collect();
            let v = W[0] * x[0] + W[1] * x[1] + W[2] * x[2] + B;
            if sigmoid_out { sigmoid(v) } else { v }
        })
        .collect();
    if c.minmax {
        minmax(&mut y);
    }

    Image::from_vec(g.w, g.h, 1, y).unwrap().resized(rgb.width, rgb.height)
}

fn contract_of(model: &str, preset: &str) -> contract::Contract {
    binding::resolve(&spec(model, preset), kind_of(preset), &cfg()).unwrap().1
}

fn kind_of(preset: &str) -> ModelKind {
    match preset {
        "lama" | "lama-dynamic" => ModelKind::Inpaint,
        "midas-small" | "depth-anything-v2" => ModelKind::Depth,
        _ => ModelKind::Matte,
    }
}

#[test]
fn geometry_plans() {
    let fixed = prep::plan(SizeSpec::Fixed { h: 320, w: 320 }, ResizeMode::Stretch, 40, 30);
    assert_eq!((fixed.model_w, fixed.model_h, fixed.x0, fixed.y0, fixed.w, fixed.h), (320, 320, 0, 0, 320, 320));
    let lb = prep::plan(SizeSpec::Fixed { h: 320, w: 320 }, ResizeMode::Letterbox, 40, 30);
    assert_eq!((lb.x0, lb.y0, lb.w, lb.h), (0, 40, 320, 240));
    let dy = prep::plan(SizeSpec::Dynamic { multiple: 32, max_side: Some(512) }, ResizeMode::Stretch, 1000, 600);
    assert_eq!((dy.model_w, dy.model_h), (512, 320), "{dy:?}");
    let d14 = prep::plan(SizeSpec::Dynamic { multiple: 14, max_side: Some(518) }, ResizeMode::Stretch, 48, 36);
    assert_eq!((d14.model_w, d14.model_h), (42, 42));
    let dlb = prep::plan(SizeSpec::Dynamic { multiple: 8, max_side: None }, ResizeMode::Letterbox, 41, 30);
    assert_eq!((dlb.model_w, dlb.model_h, dlb.w, dlb.h, dlb.x0, dlb.y0), (48, 32, 41, 30, 3, 1));
    // Resizing to the same size is an exact copy; a constant image stays constant.
    let img = photo(13, 9);
    assert_eq!(img.resized(13, 9), img);
    let flat = Image::filled(7, 5, 2, 0.25);
    assert!(flat.resized(31, 2).data.iter().all(|&v| (v - 0.25).abs() < 1e-6));
}

#[test]
fn every_matte_preset_matches_its_function() {
    let rgb = photo(40, 30);
    // (stub, preset, does the stub end in a sigmoid or does the contract apply one)
    for (model, preset) in [
        ("u2net.onnx", "u2net"),
        ("isnet.onnx", "isnet"),
        ("birefnet.onnx", "birefnet"),
        ("modnet.onnx", "modnet"),
        ("mediapipe_selfie.onnx", "mediapipe-selfie"),
    ] {
        let (matte, report) = segment_onnx::predict_matte(&rgb, &spec(model, preset), &cfg()).unwrap_or_else(|e| panic!("{preset}: {e}"));
        let c = contract_of(model, preset);
        let g = prep::plan(c.size, c.resize, 40, 30);
        assert_eq!(report.model_size, [g.model_h, g.model_w], "{preset}");
        let mut want = expected_conv(&rgb, &c, &g, true);
        want.map_inplace(|a| a.clamp(0.0, 1.0));
        let d = max_diff(&matte, &want);
        assert!(d <= TOL, "{preset}: max |matte - expected| = {d}");
        // The function is not trivial: the matte varies across the image.
        let (lo, hi) = matte.data.iter().fold((1f32, 0f32), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(hi - lo > 0.05, "{preset}: matte range {lo}..{hi}");
        eprintln!("{preset:>17}: max error {d:.2e}, model input {}x{}", g.model_h, g.model_w);
    }
}

#[test]
fn overrides_bgr_letterbox_and_byte_scaling() {
    let rgb = photo(40, 30);
    // BGR + letterbox + 0-255 scaling with mean/std in those units, on the dynamic MODNet stub.
    let s = ModelSpec {
        color: Some(ColorOrder::Bgr),
        resize: Some(ResizeMode::Letterbox),
        scale: Some(contract::ValueScale::Byte),
        mean: Some([120.0, 110.0, 100.0]),
        std: Some([60.0, 58.0, 57.0]),
        ..spec("modnet.onnx", "modnet")
    };
    let (matte, _) = segment_onnx::predict_matte(&rgb, &s, &cfg()).unwrap();
    let (_, c) = binding::resolve(&s, ModelKind::Matte, &cfg()).unwrap();
    let g = prep::plan(c.size, c.resize, 40, 30);
    assert!(g.w < g.model_w || g.h < g.model_h, "letterbox pads: {g:?}");
    let want = expected_conv(&rgb, &c, &g, true);
    let d = max_diff(&matte, &want);
    assert!(d <= TOL, "bgr/letterbox/0-255: {d}");
    // The same stub read as RGB gives a different matte: the colour order matters.
    let (rgb_matte, _) = segment_onnx::predict_matte(&rgb, &ModelSpec { color: Some(ColorOrder::Rgb), ..s.clone() }, &cfg()).unwrap();
    assert!(max_diff(&matte, &rgb_matte) > 1e-3);
}

#[test]
fn depth_presets_match_their_function() {
    let rgb = photo(48, 36);
    for (model, preset) in [("midas_small.onnx", "midas-small"), ("depth_anything_v2.onnx", "depth-anything-v2")] {
        let (disp, report) = depth_onnx::estimate_disparity(&rgb, &spec(model, preset), &cfg()).unwrap_or_else(|e| panic!("{preset}: {e}"));
        let c = contract_of(model, preset);
        let g = prep::plan(c.size, c.resize, 48, 36);
        let mut want = expected_conv(&rgb, &c, &g, false);
        minmax(&mut want.data);
        let d = max_diff(&disp.map, &want);
        assert!(d <= TOL, "{preset}: max |disparity - expected| = {d}");
        assert!(disp.z_range.is_none());
        eprintln!("{preset:>17}: max error {d:.2e}, model input {:?}", report.model_size);
    }
    // The export guide.md documents (fabio-sim/Depth-Anything-ONNX, fixed 518x518): the preset
    // alone names the size to set; with `size = [518, 518]` the map is the stub's function.
    let export = "depth_anything_v2_vits_18.onnx";
    let e = match depth_onnx::estimate_disparity(&rgb, &spec(export, "depth-anything-v2"), &cfg()) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("a fixed-size export without `size` must be refused"),
    };
    assert!(e.contains(export) && e.contains("size = [518, 518]"), "{e}");
    let sized = ModelSpec { size: Some([518, 518]), ..spec(export, "depth-anything-v2") };
    let (disp, report) = depth_onnx::estimate_disparity(&rgb, &sized, &cfg()).unwrap();
    let c = binding::resolve(&sized, ModelKind::Depth, &cfg()).unwrap().1;
    let mut want = expected_conv(&rgb, &c, &prep::plan(c.size, c.resize, 48, 36), false);
    minmax(&mut want.data);
    assert!(max_diff(&disp.map, &want) <= TOL && report.model_size == [518, 518], "{:?}", report.model_size);
}

fn disk_alpha(w: usize, h: usize, cx: f32, cy: f32, r: f32) -> Image {
    Image::from_vec(
        w,
        h,
        1,
        (0..w * h).map(|i| (r - (((i % w) as f32 - cx).powi(2) + ((i / w) as f32 - cy).powi(2)).sqrt()).clamp(0.0, 1.0)).collect(),
    )
    .unwrap()
}

/// The inpainting stub's function on a model-sized image and binary mask: masked pixels take
/// the mean of the unmasked ones.
fn mean_fill(img: &Image, mask: &[bool]) -> Image {
    let c = img.channels;
    let mut sum = vec![0f64; c];
    let n = mask.iter().filter(|m| !**m).count().max(1) as f64;
    for (p, m) in img.data.chunks_exact(c).zip(mask) {
        if !m {
            for k in 0..c {
                sum[k] += p[k] as f64;
            }
        }
    }
    let mut out = img.clone();
    for (p, m) in out.data.chunks_exact_mut(c).zip(mask) {
        if *m {
            for k in 0..c {
                p[k] = (sum[k] / n) as f32;
            }
        }
    }
    out
}

fn paste(dst: &mut Image, src: &Image, x0: usize, y0: usize, dist: &[f32], feather: f32) {
    let c = dst.channels;
    for y in 0..src.height {
        for x in 0..src.width {
            let wgt = seam_weight(dist[(y0 + y) * dst.width + x0 + x], feather);
            let i = dst.index(x0 + x, y0 + y);
            for k in 0..c {
                dst.data[i + k] = dst.data[i + k] * (1.0 - wgt) + src.data[(y * src.width + x) * c + k] * wgt;
            }
        }
    }
}

/// The pixels the stage gives the model as holes: the background fill's region (its mask
/// logic is tested in the library); these smooth test photos have no highlights to keep.
fn model_mask(rgb: &Image, alpha: &Image, opts: &InpaintOptions) -> Vec<bool> {
    let fill = drbokeh::stages::background::fill_region(rgb, alpha, opts, 0.0, BandReach::Any);
    assert_eq!(fill.highlights_kept, 0);
    fill.mask
}

#[test]
fn lama_fixed_size_crops_resizes_and_pastes() {
    let (w, h) = (64, 48);
    let rgb = photo(w, h);
    let disp = Image::from_vec(w, h, 1, (0..w * h).map(|i| 0.2 + 0.5 * (i % w) as f32 / w as f32).collect()).unwrap();
    let alpha = disk_alpha(w, h, 20.0, 20.0, 6.0);
    let opts = InpaintOptions { method: inpaint_onnx::InpaintMethod::Onnx, onnx: spec("lama.onnx", "lama"), ..InpaintOptions::default() };
    let (bg, report) =
        inpaint_onnx::inpaint_background(&rgb, &disp, &alpha, &opts, Reach::Pixels(40.0), (0.0, BandReach::Any), &cfg()).unwrap();
    assert_eq!(report.model_size, [512, 512]);

    // Rust side: the same region, the stub's function at 512x512, back, pasted.
    let mask = model_mask(&rgb, &alpha, &opts);
    let (x0, y0, cw, ch) = region(&mask, w, h, true, 0.5).unwrap();
    assert_eq!((x0, y0), (0, 0), "context 16 px reaches the border");
    assert!(cw < w && ch < h, "a crop, not the whole image: {cw}x{ch}");
    let mask_img = Image::from_vec(w, h, 1, mask.iter().map(|&m| m as u8 as f32).collect()).unwrap();
    let crop_rgb = srgb(&rgb.crop(x0, y0, cw, ch));
    let m512: Vec<bool> = mask_img.crop(x0, y0, cw, ch).resized(512, 512).data.iter().map(|&v| v > 1e-3).collect();
    let filled = mean_fill(&crop_rgb.resized(512, 512), &m512);
    let mut back = filled.resized(cw, ch);
    back.map_inplace(|v| srgb_to_linear(v.clamp(0.0, 1.0)));
    let mut want = rgb.clone();
    paste(&mut want, &back, x0, y0, &distance_to(&mask, w, h), 2.0);
    let d = max_diff(&bg.rgb, &want);
    assert!(d <= TOL, "lama: max |rgb - expected| = {d}");
    eprintln!("lama: max error {d:.2e}, region {cw}x{ch} at ({x0},{y0})");
    // Far from the mask nothing changed.
    assert_eq!(bg.rgb.pixel(w - 1, h - 1), rgb.pixel(w - 1, h - 1));
    // Disparity: Telea (the default `depth`).
    let mut want_d = disp.clone();
    inpaint_telea(&mut want_d, &mask, TeleaOptions { max_distance: Some(40.0), ..TeleaOptions::new(opts.radius) }).unwrap();
    assert!(max_diff(&bg.disparity, &want_d) <= TOL);
}

#[test]
fn lama_dynamic_fills_with_the_unmasked_mean_and_model_depth() {
    // 40x32: multiples of 8, so the dynamic model sees the image as it is.
    let (w, h) = (40, 32);
    let rgb = photo(w, h);
    let disp = Image::from_vec(w, h, 1, (0..w * h).map(|i| 0.1 + 0.8 * (i / w) as f32 / h as f32).collect()).unwrap();
    let alpha = disk_alpha(w, h, 25.0, 14.0, 5.0);
    let onnx = ModelSpec { depth: Some(DepthFill::Model), feather: Some(0.0), ..spec("lama_dynamic.onnx", "lama-dynamic") };
    let opts = InpaintOptions { method: inpaint_onnx::InpaintMethod::Onnx, onnx, ..InpaintOptions::default() };
    let (bg, report) =
        inpaint_onnx::inpaint_background(&rgb, &disp, &alpha, &opts, Reach::Pixels(40.0), (0.0, BandReach::Any), &cfg()).unwrap();
    assert_eq!(report.model_size, [h, w]);
    assert_eq!(report.runs, 2, "colour and disparity");
    let mask = model_mask(&rgb, &alpha, &opts);
    assert_eq!(bg.filled, mask.iter().filter(|&&m| m).count());
    // Colour: masked = mean of unmasked (in sRGB, as the model sees it); unmasked untouched.
    let mut want = mean_fill(&srgb(&rgb), &mask);
    want.map_inplace(|v| srgb_to_linear(v.clamp(0.0, 1.0)));
    for (i, m) in mask.iter().enumerate() {
        if !m {
            want.data[i * 3..i * 3 + 3].copy_from_slice(&rgb.data[i * 3..i * 3 + 3]);
        }
    }
    let d = max_diff(&bg.rgb, &want);
    assert!(d <= TOL, "lama-dynamic colour: {d}");
    // Disparity through the model: replicated to 3 channels, same mean fill.
    let want_d = mean_fill(&disp, &mask);
    let dd = max_diff(&bg.disparity, &want_d);
    assert!(dd <= TOL, "lama-dynamic disparity: {dd}");
}

#[test]
fn sessions_are_created_once_and_reused() {
    // A private copy so no other test shares (or pre-creates) this session.
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("mine.onnx");
    std::fs::copy(stub("u2net.onnx"), &model).unwrap();
    let s = ModelSpec { model: Some(model), preset: Some("u2net".into()), ..ModelSpec::default() };
    let (_, first) = segment_onnx::predict_matte(&photo(20, 10), &s, &cfg()).unwrap();
    let (_, second) = segment_onnx::predict_matte(&photo(30, 30), &s, &cfg()).unwrap();
    let (_, third) = segment_onnx::predict_matte(&photo(8, 50), &s, &cfg()).unwrap();
    assert!(!first.session_cached && first.session_ms > 0.0);
    assert!(second.session_cached && third.session_cached);
    assert_eq!((second.session_ms, third.session_ms), (0.0, 0.0));
    assert!(drbokeh::onnx::runtime::is_loaded());
}

/// Runs a matte model and returns its error message (asserting it is a user error).
fn matte_err(s: &ModelSpec) -> String {
    let e = segment_onnx::predict_matte(&photo(16, 12), s, &cfg()).expect_err("must fail");
    assert!(e.is_user_error(), "exit 2 expected: {e}");
    assert!(matches!(e, Error::Input { .. } | Error::Usage(_)), "{e:?}");
    e.to_string()
}

#[test]
fn wrong_names_list_what_the_model_has() {
    let e = matte_err(&spec("bad_names.onnx", "modnet"));
    assert!(e.contains("bad_names.onnx") && e.contains("no input named \"input\""), "{e}");
    assert!(e.contains("\"x\" f32[1, 3, ?, ?]"), "lists the actual inputs: {e}");
    // Right input name, wrong output name.
    let e = matte_err(&ModelSpec { input: Some("x".into()), ..spec("bad_names.onnx", "modnet") });
    assert!(e.contains("no output named \"output\"") && e.contains("\"y\" f32[1, 1, ?, ?]"), "{e}");
    // Output index out of range.
    let e = matte_err(&ModelSpec { output: Some(contract::OutputRef::Index(5)), ..spec("u2net.onnx", "u2net") });
    assert!(e.contains("no output #5") && e.contains("\"d0\"") && e.contains("\"d1\""), "{e}");
    // Inpainting stub used with swapped names.
    let opts = InpaintOptions { onnx: ModelSpec { input: Some("img".into()), ..spec("lama.onnx", "lama") }, ..InpaintOptions::default() };
    let alpha = disk_alpha(16, 12, 8.0, 6.0, 3.0);
    let e = inpaint_onnx::inpaint_background(
        &photo(16, 12),
        &Image::filled(16, 12, 1, 0.5),
        &alpha,
        &opts,
        Reach::Pixels(10.0),
        (0.0, BandReach::Any),
        &cfg(),
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        e.contains("lama.onnx") && e.contains("\"img\"") && e.contains("\"image\" f32[1, 3, 512, 512]") && e.contains("\"mask\""),
        "{e}"
    );
}

#[test]
fn wrong_rank_layout_and_size() {
    // MiDaS's output is rank 3; U^2-Net's contract wants rank 4.
    let e = matte_err(&ModelSpec { model: Some(stub("midas_small.onnx")), size: Some([256, 256]), ..spec("u2net.onnx", "u2net") });
    assert!(
        e.contains("midas_small.onnx") && e.contains("rank 3") && e.contains("expects rank 4") && e.contains("\"depth\" f32[1, 256, 256]"),
        "{e}"
    );
    // ISNet's fixed 1024 input under the U^2-Net contract (320).
    let e = matte_err(&ModelSpec { model: Some(stub("isnet.onnx")), ..spec("u2net.onnx", "u2net") });
    assert!(e.contains("isnet.onnx") && e.contains("1024x1024") && e.contains("320x320"), "{e}");
    // A fixed model under a dynamic contract.
    let e = matte_err(&ModelSpec { input: Some("input.1".into()), ..spec("u2net.onnx", "modnet") });
    assert!(e.contains("fixed size 320x320") && e.contains("dynamic"), "{e}");
    // An NCHW model read as NHWC: the channel axis holds 320, not 3.
    let e = matte_err(&ModelSpec { layout: Some(Layout::Nhwc), ..spec("u2net.onnx", "u2net") });
    assert!(e.contains("channel") && e.contains("\"input.1\" f32[1, 3, 320, 320]"), "{e}");
}

#[test]
fn nan_output_missing_and_invalid_files() {
    let e = matte_err(&spec("bad_nan.onnx", "u2net"));
    assert!(e.contains("bad_nan.onnx") && e.contains("NaN"), "{e}");
    let e = matte_err(&spec("does_not_exist.onnx", "u2net"));
    assert!(e.contains("does_not_exist.onnx") && e.contains("not found"), "{e}");
    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, "this is not a protobuf").unwrap();
    let e = matte_err(&ModelSpec { model: Some(junk), ..spec("x", "u2net") });
    assert!(e.contains("junk.onnx") && e.contains("not a loadable ONNX model"), "{e}");
    let empty = dir.path().join("empty.onnx");
    std::fs::write(&empty, "").unwrap();
    let e = matte_err(&ModelSpec { model: Some(empty), ..spec("x", "u2net") });
    assert!(e.contains("empty.onnx") && e.contains("empty"), "{e}");
    // Usage errors: unknown preset, a preset of another kind, no model file configured.
    let e = matte_err(&spec("u2net.onnx", "u3net"));
    assert!(e.contains("u3net") && e.contains("u2net, isnet"), "{e}");
    let e = matte_err(&spec("lama.onnx", "lama"));
    assert!(e.contains("\"lama\""), "{e}");
    let e = matte_err(&ModelSpec::default());
    assert!(e.contains("onnx.model_dir") && e.contains("u2net.onnx"), "{e}");
}

#[test]
fn missing_execution_provider_falls_back_to_cpu_with_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("gpu.onnx");
    std::fs::copy(stub("u2net.onnx"), &model).unwrap();
    let cfg = OnnxConfig { providers: vec!["cuda".into(), "coreml".into(), "cpu".into()], threads: 2, ..OnnxConfig::default() };
    let s = ModelSpec { model: Some(model), ..ModelSpec::default() };
    let (matte, report) = segment_onnx::predict_matte(&photo(20, 10), &s, &cfg).unwrap();
    assert_eq!(matte.width, 20);
    // The PyPI CPU wheel has neither provider: both are skipped with a warning, CPU runs.
    if !report.providers.iter().any(|p| p == "CUDAExecutionProvider") {
        assert!(report.warnings.iter().any(|w| w.contains("CUDAExecutionProvider") && w.contains("CPU")), "{:?}", report.warnings);
    }
    assert_eq!(report.providers.last().map(String::as_str), Some("CPUExecutionProvider"));
}

/// Issue 12: an inpainting model whose output does not match its declared range gives a
/// named warning (an almost black or a blown-out fill), and a matching one gives none.
#[test]
fn an_implausible_inpainting_range_is_warned_about() {
    let (w, h) = (40, 32);
    let (rgb, disp) = (photo(w, h), Image::filled(w, h, 1, 0.3));
    let alpha = disk_alpha(w, h, 25.0, 14.0, 5.0);
    let run = |range: Option<[f32; 2]>| {
        let onnx = ModelSpec { output_range: range, ..spec("lama_dynamic.onnx", "lama-dynamic") };
        let opts = InpaintOptions { method: inpaint_onnx::InpaintMethod::Onnx, onnx, ..InpaintOptions::default() };
        inpaint_onnx::inpaint_background(&rgb, &disp, &alpha, &opts, Reach::Pixels(40.0), (0.0, BandReach::Any), &cfg()).unwrap().1.warnings
    };
    assert!(run(None).is_empty(), "the preset's range matches the stub");
    // The stub gives [0, 1]: declared [0, 255] (the mistake of the issue), the fill is almost
    // black.
    let dark = run(Some([0.0, 255.0])).join("\n");
    assert!(dark.contains("lama_dynamic.onnx") && dark.contains("never exceeds") && dark.contains("[0, 255]"), "{dark}");
    // Declared [0, 0.01]: the fill is blown out.
    let bright = run(Some([0.0, 0.01])).join("\n");
    assert!(bright.contains("far above its declared output range [0, 0.01]"), "{bright}");
}

/// An 8-bit photo (linear values quantized through sRGB): a smooth textured ground in the
/// model's anchor range, a disc of radiance 20 (clipped to white) with an anti-aliased rim,
/// and a last row whose red steps from stored 0.9 to 1 beside a green of 0.97 (a sample the
/// stub lifts, unclipped, in pixels whose red is clipped).
fn clipped_photo(w: usize, h: usize) -> Image {
    let mut img = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let d = ((x as f32 - 20.5).powi(2) + (y as f32 - 14.5).powi(2)).sqrt();
            let ground = [0.15 + 0.2 * (x as f32 * 0.3).sin().abs(), 0.1 + 0.15 * (y as f32 * 0.2).cos().abs(), 0.2];
            let cover = (4.0 - d).clamp(0.0, 1.0);
            let mut v: [f32; 3] = std::array::from_fn(|c| ground[c] * (1.0 - cover) + 20.0 * cover);
            if y == h - 1 {
                v = [0.9 + 0.1 * x as f32 / (w - 1) as f32, 0.97, 0.5].map(srgb_to_linear);
            }
            img.pixel_mut(x, y).copy_from_slice(&v.map(|v| srgb_to_linear((linear_to_srgb(v.clamp(0.0, 1.0)) * 255.0).round() / 255.0)));
        }
    }
    img
}

fn highlights(opts_model: ModelSpec) -> HighlightsOptions {
    HighlightsOptions { mode: HighlightMode::Onnx, onnx: opts_model, ..HighlightsOptions::default() }
}

const SRGB8: PhotoEncoding = PhotoEncoding::Integer { bits: 8, transfer: Transfer::Srgb };

/// `[highlights.onnx]` through the ExpandNet stub (half the photo's linear light, a ramp to a
/// light of 10 at white): the scale to the photo is 2, clipped samples at white come back as
/// 10, samples between the threshold and white on the ramp, every unclipped sample unchanged
/// bit for bit; a BGR contract gives the same picture (the output is put back in RGB order).
#[test]
fn highlights_model_lifts_only_clipped_samples() {
    let photo = clipped_photo(48, 32);
    let opts = highlights(spec("expandnet.onnx", "expandnet"));
    let (out, report) = match light_recovery::recover(&photo, SRGB8, &opts, &cfg(), None).unwrap() {
        Recovered::Changed(out, r) => (out, r),
        _ => panic!("the model added no light"),
    };
    let scale = report.model_scale.unwrap();
    assert!((scale - 2.0).abs() < 1e-3, "scale {scale}");
    let clip = srgb_to_linear(opts.threshold);
    let (mut lifted, mut white) = (0, 0);
    for (i, (o, p)) in out.data.iter().zip(&photo.data).enumerate() {
        if *p < clip {
            assert_eq!(o.to_bits(), p.to_bits(), "unclipped sample {i} changed");
            continue;
        }
        let x = linear_to_srgb(*p);
        let want = (scale * (0.5 * p + 4.5 * (x - 0.96).max(0.0) / 0.04)).max(*p);
        assert!((o - want).abs() < 1e-3 * want, "sample {i}: {o}, expected {want}");
        lifted += (*o > *p) as usize;
        white += (*p == 1.0) as usize;
        if *p == 1.0 {
            assert!((o - 10.0).abs() < 0.02, "a white sample came back as {o}, not 10");
        }
    }
    assert!(white >= 30 && lifted >= white, "{white} white samples, {lifted} lifted");
    assert_eq!(report.clipped_pixels, photo.data.chunks(3).filter(|p| p.iter().any(|&v| v >= clip)).count());
    let added: f64 = out.data.iter().zip(&photo.data).map(|(o, p)| (o - p) as f64).sum();
    assert!((report.light_added - added).abs() < 1e-3 * added, "reported {} added, {added} measured", report.light_added);
    let m = report.model.as_ref().unwrap();
    assert!(m.model.ends_with("expandnet.onnx") && m.runs == 1 && m.model_size == [32, 48], "{m:?}");

    let bgr = highlights(ModelSpec { color: Some(ColorOrder::Bgr), ..spec("expandnet.onnx", "expandnet") });
    let Recovered::Changed(out_bgr, _) = light_recovery::recover(&photo, SRGB8, &bgr, &cfg(), None).unwrap() else {
        panic!("bgr: no light")
    };
    assert!(max_diff(&out, &out_bgr) < 1e-5, "bgr differs by {}", max_diff(&out, &out_bgr));
}

/// Nothing clipped, a linear photo, `off`: the model is not even loaded (its file need not
/// exist) and the photo is left as it is. Bad models and photos the model cannot be scaled to
/// are errors naming the file.
#[test]
fn highlights_model_runs_only_when_needed_and_fails_clearly() {
    let missing = highlights(spec("does_not_exist.onnx", "expandnet"));
    let dim = Image::filled(40, 30, 3, 0.3);
    assert!(matches!(light_recovery::recover(&dim, SRGB8, &missing, &cfg(), None).unwrap(), Recovered::Unchanged(_)));
    let photo = clipped_photo(48, 32);
    assert!(matches!(light_recovery::recover(&photo, PhotoEncoding::Linear, &missing, &cfg(), None).unwrap(), Recovered::Unchanged(_)));
    let err = |o: &HighlightsOptions, img: &Image| match light_recovery::recover(img, SRGB8, o, &cfg(), None) {
        Err(e) => e.to_string(),
        Ok(_) => panic!("no error"),
    };
    let e = err(&missing, &photo);
    assert!(e.contains("does_not_exist.onnx") && e.contains("not found"), "{e}");
    // A one-channel model (the MODNet stub: dynamic size, one output channel).
    let e = err(&highlights(ModelSpec { input: Some("input".into()), ..spec("modnet.onnx", "expandnet") }), &photo);
    assert!(e.contains("modnet.onnx") && e.contains("1 channel"), "{e}");
    // A matting preset in the highlights slot.
    let e = err(&highlights(spec("u2net.onnx", "u2net")), &photo);
    assert!(e.contains("highlights.onnx.preset") && e.contains("u2net"), "{e}");
    // All white but one dark corner: nothing to scale the model's light by.
    let mut white = Image::filled(40, 30, 3, 1.0);
    white.pixel_mut(0, 0).fill(0.01);
    let e = err(&highlights(spec("expandnet.onnx", "expandnet")), &white);
    assert!(e.contains("expandnet.onnx") && e.contains("well-exposed"), "{e}");
}
