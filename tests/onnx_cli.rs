//! `drbokeh render` with ONNX stages on the stub models: the model-based run equals the
//! classical run given the model's matte; classical runs never need ONNX Runtime; runtime and
//! model errors exit 2 naming the file and write nothing; the committed stubs are up to date.

use crate::common;

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io;
use drbokeh::onnx::{ModelSpec, OnnxConfig};
use drbokeh::stages::segment_onnx;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const W: usize = 48;
const H: usize = 36;

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn stubs() -> PathBuf {
    root().join("models-stub")
}

/// A scene folder: image.png (sRGB), depth.exr (near disk on a far plane).
fn scene() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let mut rgb = Image::new(W, H, 3);
    let mut z = Image::new(W, H, 1);
    for y in 0..H {
        for x in 0..W {
            let near = ((x as f32 - 30.0).powi(2) + (y as f32 - 16.0).powi(2)).sqrt() < 9.0;
            let p = rgb.pixel_mut(x, y);
            if near {
                p.copy_from_slice(&[0.8, 0.55, 0.1]);
            } else {
                p.copy_from_slice(&[0.1 + 0.5 * x as f32 / W as f32, 0.2, 0.15 + 0.6 * ((x / 4 + y / 4) % 2) as f32]);
            }
            z.data[y * W + x] = if near { 1.0 } else { 4.0 };
        }
    }
    io::write_png(&dir.path().join("image.png"), &rgb, 8, Transfer::Srgb).unwrap();
    io::write_exr(&dir.path().join("depth.exr"), &z, &["Z"]).unwrap();
    dir
}

fn drbokeh(dir: &Path, args: &[&str], envs: &[(&str, &str)]) -> Output {
    let mut c = common::drbokeh(dir);
    c.arg("render").args(args);
    for (k, v) in envs {
        c.env(k, v);
    }
    c.output().expect("run drbokeh")
}

fn ok(dir: &Path, args: &[&str], envs: &[(&str, &str)]) -> serde_json::Value {
    let mut a = args.to_vec();
    a.push("--json");
    let out = drbokeh(dir, &a, envs);
    assert!(out.status.success(), "drbokeh {} failed: {}", a.join(" "), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Must exit 2, name every needle, and leave the folder as it was (`common::assert_usage_error`).
fn bad(dir: &Path, args: &[&str], envs: &[(&str, &str)], needles: &[&str]) -> String {
    common::assert_usage_error(dir, &format!("drbokeh render {}", args.join(" ")), needles, || drbokeh(dir, args, envs))
}

fn stage<'a>(j: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    j["stages"].as_array().unwrap().iter().find(|s| s["name"] == name).unwrap_or_else(|| panic!("no stage {name} in {j}"))
}

fn read_png(p: &Path) -> Image {
    io::read_photo(p, Transfer::Linear, &io::ReadLimits { max_pixels: 1 << 30 }).unwrap()
}

#[test]
fn onnx_run_equals_classical_run_with_the_models_matte() {
    let dir = scene();
    let d = dir.path();
    let md = stubs();
    let md = md.to_str().unwrap();
    let common = ["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "6", "--model-dir", md];
    // A model's matte is refined on the photo by default (`[segment] refine = "auto"`); a user's
    // is not: with refinement off the two runs see the same matte.
    let auto = ok(d, &[&common[..], &["--segment", "onnx", "--inpaint", "onnx", "-o", "auto.png"]].concat(), &[]);
    assert!(stage(&auto, "segment")["detail"]["refine"]["unknown_px"].as_u64().is_some(), "{auto}");
    std::fs::write(d.join("off.toml"), "[segment]\nrefine = \"off\"\n").unwrap();
    let a = ok(d, &[&common[..], &["--segment", "onnx", "--inpaint", "onnx", "--config", "off.toml", "-o", "a.png"]].concat(), &[]);
    assert_eq!(stage(&a, "segment")["detail"]["source"], "onnx", "{a}");
    assert!(stage(&a, "segment")["detail"]["refine"].is_null(), "{a}");
    assert_eq!(stage(&a, "segment")["detail"]["model"]["preset"], "u2net");
    assert_eq!(stage(&a, "inpaint")["detail"]["method"], "onnx");
    assert_eq!(stage(&a, "inpaint")["detail"]["model"]["preset"], "lama");
    assert_eq!(stage(&a, "segment")["detail"]["layers"], 2);

    // The stub's matte, computed by the library on the decoded photo, as a 16-bit PNG.
    let rgb = io::read_photo(&d.join("image.png"), Transfer::Srgb, &io::ReadLimits { max_pixels: 1 << 30 }).unwrap();
    let spec = ModelSpec { model: Some(stubs().join("u2net.onnx")), ..ModelSpec::default() };
    let (matte, _) = segment_onnx::predict_matte(&rgb, &spec, &OnnxConfig::default()).unwrap();
    io::write_png(&d.join("matte.png"), &matte, 16, Transfer::Linear).unwrap();
    let b = ok(d, &[&common[..], &["--matte", "matte.png", "--inpaint", "onnx", "-o", "b.png"]].concat(), &[]);
    assert_eq!(stage(&b, "segment")["detail"]["source"], "matte");

    let (ia, ib) = (read_png(&d.join("a.png")), read_png(&d.join("b.png")));
    let diff = ia.data.iter().zip(&ib.data).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max);
    assert!(diff <= 1.0 / 255.0 + 1e-6, "onnx vs classical-with-matte: max diff {} levels", diff * 255.0);
    // And the ONNX inpainting really ran: Telea gives a different image.
    let c = ok(d, &[&common[..], &["--matte", "matte.png", "-o", "c.png"]].concat(), &[]);
    assert_eq!(stage(&c, "inpaint")["detail"]["method"], "telea");
    let ic = read_png(&d.join("c.png"));
    assert!(ia.data.iter().zip(&ic.data).any(|(x, y)| (x - y).abs() > 2.0 / 255.0), "stub inpainting should differ from Telea");
}

#[test]
fn classical_runs_never_load_onnx_runtime() {
    let dir = scene();
    let d = dir.path();
    let nowhere = [("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")];
    for extra in [&["--segment", "depth"][..], &["--segment", "auto", "--inpaint", "telea"][..], &["--no-occlusion"][..]] {
        let args = [&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "-o", "out.png"][..], extra].concat();
        let j = ok(d, &args, &nowhere);
        assert!(!j.to_string().contains("onnx\""), "{j}");
    }
    // A config that configures models (but does not use them) does not load the runtime either.
    std::fs::write(d.join("c.toml"), "[segment.onnx]\nmodel = \"nowhere.onnx\"\n[onnx]\nruntime = \"/nonexistent/lib.so\"\n").unwrap();
    ok(d, &["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "c.toml", "-o", "out2.png"], &nowhere);
}

#[test]
fn runtime_not_found_is_a_clear_error() {
    let dir = scene();
    let d = dir.path();
    let md = stubs();
    let args =
        ["image.png", "--depth", "depth.exr", "--focus", "1", "--segment", "onnx", "--model-dir", md.to_str().unwrap(), "-o", "o.png"];
    bad(
        d,
        &args,
        &[("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")],
        &["/nonexistent/libonnxruntime.so", "ORT_DYLIB_PATH", "onnxruntime==1.31.1"],
    );
    // `[onnx] runtime` wins over ORT_DYLIB_PATH.
    std::fs::write(d.join("c.toml"), "[onnx]\nruntime = \"/no/such/libonnxruntime.so\"\n").unwrap();
    bad(d, &[&args[..], &["--config", "c.toml"]].concat(), &[], &["/no/such/libonnxruntime.so", "[onnx] runtime"]);
    // A file that is not a shared library.
    std::fs::write(d.join("fake.so"), "not a library").unwrap();
    bad(d, &args, &[("ORT_DYLIB_PATH", d.join("fake.so").to_str().unwrap())], &["fake.so", "cannot load ONNX Runtime"]);
}

#[test]
fn model_errors_exit_2_naming_the_file() {
    let dir = scene();
    let d = dir.path();
    let base = ["image.png", "--depth", "depth.exr", "--focus", "1", "-o", "o.png"];
    // --model-dir without the preset's file.
    std::fs::create_dir(d.join("empty")).unwrap();
    bad(d, &[&base[..], &["--segment", "onnx", "--model-dir", "empty"]].concat(), &[], &["u2net.onnx", "not found"]);
    // No model configured at all.
    bad(d, &[&base[..], &["--inpaint", "onnx", "--segment", "depth"]].concat(), &[], &["inpaint.onnx", "--model-dir"]);
    // A stub that emits NaN.
    let nan = stubs().join("bad_nan.onnx");
    std::fs::write(
        d.join("nan.toml"),
        format!("[segment]\nmethod = \"onnx\"\n[segment.onnx]\nmodel = {:?}\npreset = \"u2net\"\n", nan.to_str().unwrap()),
    )
    .unwrap();
    bad(d, &[&base[..], &["--config", "nan.toml"]].concat(), &[], &["bad_nan.onnx", "NaN"]);
    // Wrong names.
    let names = stubs().join("bad_names.onnx");
    std::fs::write(d.join("names.toml"), format!("[segment.onnx]\nmodel = {:?}\npreset = \"modnet\"\n", names.to_str().unwrap())).unwrap();
    bad(d, &[&base[..], &["--segment", "onnx", "--config", "names.toml"]].concat(), &[], &["bad_names.onnx", "\"input\"", "\"x\""]);
    // Config errors are caught before anything runs.
    std::fs::write(d.join("typo.toml"), "[segment.onnx]\npreset = \"u2nett\"\n").unwrap();
    bad(d, &[&base[..], &["--config", "typo.toml"]].concat(), &[], &["typo.toml", "u2nett", "u2net"]);
    std::fs::write(d.join("prov.toml"), "[onnx]\nproviders = [\"cuda\", \"tpu\"]\n").unwrap();
    bad(d, &[&base[..], &["--config", "prov.toml"]].concat(), &[], &["tpu", "cuda, tensorrt"]);
}

#[test]
fn depth_model_when_no_depth_map() {
    let dir = scene();
    let d = dir.path();
    let midas = stubs().join("midas_small.onnx");
    std::fs::write(d.join("depth.toml"), format!("[depth.onnx]\nmodel = {:?}\npreset = \"midas-small\"\n", midas.to_str().unwrap()))
        .unwrap();
    let j = ok(d, &["image.png", "--focus", "0.5", "--blur", "4", "--config", "depth.toml", "-o", "o.png"], &[]);
    assert_eq!(stage(&j, "depth_model")["detail"]["preset"], "midas-small", "{j}");
    // --model-dir with the default depth preset's file (depth_anything_v2.onnx).
    let md = stubs();
    ok(d, &["image.png", "--focus", "0.5", "--blur", "4", "--model-dir", md.to_str().unwrap(), "-o", "o2.png"], &[]);
    // No depth, no model: names --depth.
    bad(d, &["image.png", "--focus", "0.5", "-o", "o3.png"], &[], &["--depth", "[depth.onnx]"]);
    std::fs::create_dir(d.join("models")).unwrap();
    bad(d, &["image.png", "--focus", "0.5", "--model-dir", "models", "-o", "o3.png"], &[], &["--depth", "depth_anything_v2.onnx"]);
    // --focus-depth needs metric depth, which a model does not give.
    bad(d, &["image.png", "--focus-depth", "2", "--config", "depth.toml", "-o", "o3.png"], &[], &["--focus-depth"]);
}

/// `--highlights onnx` with the ExpandNet stub: the scene with a clipped light (stored white,
/// radiance 10 behind it per the stub) renders brighter around the light than with `off`; the
/// JSON names the model and its scale; `[highlights.onnx]` in a config does the same; the
/// classical default never loads the runtime; a missing model exits 2 naming the file.
#[test]
fn highlights_model_from_the_command_line_and_the_config() {
    let dir = scene();
    let d = dir.path();
    // A clipped 3x3 light on the far plane.
    let mut rgb = read_png(&d.join("image.png"));
    for y in 6..9 {
        for x in 6..9 {
            rgb.pixel_mut(x, y).fill(1.0);
        }
    }
    io::write_png(&d.join("lit.png"), &rgb, 8, Transfer::Linear).unwrap();
    let md = stubs();
    let base = ["lit.png", "--depth", "depth.exr", "--focus", "1", "--blur", "6"];
    let onnx = ok(d, &[&base[..], &["--highlights", "onnx", "--model-dir", md.to_str().unwrap(), "-o", "onnx.png"]].concat(), &[]);
    let h = &stage(&onnx, "highlights")["detail"];
    assert_eq!(h["mode"], "onnx", "{h}");
    assert_eq!(h["model"]["preset"], "expandnet", "{h}");
    let scale = h["model_scale"].as_f64().unwrap();
    assert!((scale - 2.0).abs() < 0.01, "{h}");
    assert!(h["light_added"].as_f64().unwrap() > 9.0 * 8.0 * 3.0, "{h}");
    std::fs::write(
        d.join("h.toml"),
        format!("[highlights]\nmode = \"onnx\"\n[highlights.onnx]\nmodel = {:?}\n", md.join("expandnet.onnx")),
    )
    .unwrap();
    let cfg = ok(d, &[&base[..], &["--config", "h.toml", "-o", "cfg.png"]].concat(), &[]);
    assert_eq!(stage(&cfg, "highlights")["detail"]["light_added"], h["light_added"]);
    ok(d, &[&base[..], &["--highlights", "off", "-o", "off.png"]].concat(), &[("ORT_DYLIB_PATH", "/nonexistent/libonnxruntime.so")]);
    let (lit, off) = (read_png(&d.join("onnx.png")), read_png(&d.join("off.png")));
    assert_eq!(read_png(&d.join("cfg.png")).data, lit.data);
    let sum = |img: &Image| img.data.iter().map(|&v| v as f64).sum::<f64>();
    assert!(sum(&lit) > sum(&off) + 1.0, "the recovered light should brighten the render");
    std::fs::create_dir(d.join("empty")).unwrap();
    bad(d, &[&base[..], &["--highlights", "onnx", "--model-dir", "empty", "-o", "x.png"]].concat(), &[], &["expandnet.onnx", "not found"]);
    bad(d, &[&base[..], &["--highlights", "onnx", "-o", "x.png"]].concat(), &[], &["highlights.onnx", "model"]);
}

#[test]
fn committed_stubs_are_up_to_date() {
    let py = root().join(".venv/bin/python");
    assert!(py.exists(), "{} is missing: run scripts/setup-test-env.sh (installs onnx for the stub generator)", py.display());
    let out = tempfile::tempdir().unwrap();
    let run = Command::new(&py).arg(stubs().join("generate.py")).arg(out.path()).output().unwrap();
    assert!(run.status.success(), "generator failed: {}", String::from_utf8_lossy(&run.stderr));
    let list = |p: &Path| {
        let mut v: Vec<String> = std::fs::read_dir(p)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".onnx"))
            .collect();
        v.sort();
        v
    };
    assert_eq!(list(&stubs()), list(out.path()), "models-stub/ and the generator disagree on the file set");
    for name in list(out.path()) {
        let (a, b) = (std::fs::read(stubs().join(&name)).unwrap(), std::fs::read(out.path().join(&name)).unwrap());
        assert_eq!(a, b, "models-stub/{name} is stale: run `.venv/bin/python models-stub/generate.py`");
        assert!(a.len() < 8192, "{name} should stay KB-sized");
    }
}
