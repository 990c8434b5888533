//! End-to-end tests of the `drbokeh` binary: every flag of `drbokeh render`, every output
//! format, the "nothing to render" shortcut, and every bad input (exit code 2, a message naming
//! the file or flag, and no output file written).
//!
//! Inputs are made with the library's own writers in a fresh temporary folder per test; the
//! binary runs with that folder as its working directory. Images are tiny (32x24) so the whole
//! file runs in seconds.

use crate::common;
use common::{crc32, list_files, max_abs_diff, run_within, snapshot};

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{self, ReadLimits};
use drbokeh::render::{self, Kernel, Layer, RenderSettings};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::Duration;

const W: usize = 32;
const H: usize = 24;
/// The foreground square of the standard scene: x in FG_X, y in FG_Y.
const FG_X: std::ops::Range<usize> = 10..22;
const FG_Y: std::ops::Range<usize> = 7..17;

// ---------------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------------

use common::Rng;

fn in_fg(x: usize, y: usize) -> bool {
    FG_X.contains(&x) && FG_Y.contains(&y)
}

/// A textured colour image in [0, 1] (3 channels).
fn texture(w: usize, h: usize, seed: u64) -> Image {
    let mut rng = Rng::new(seed);
    let mut img = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let p = img.pixel_mut(x, y);
            if in_fg(x, y) {
                p.copy_from_slice(&[0.9, 0.2 + 0.3 * rng.next_f32(), 0.1]);
            } else {
                p.copy_from_slice(&[0.1 + 0.2 * rng.next_f32(), 0.3, 0.5 + 0.4 * (x as f32 / w as f32)]);
            }
        }
    }
    img
}

/// Depth (z) of the standard scene at (w, h): foreground square at z = 1, background z = 4.
fn depth_map(w: usize, h: usize) -> Image {
    let mut d = Image::filled(w, h, 1, 4.0);
    for y in 0..h {
        for x in 0..w {
            // Scale the square with the image so a half-resolution map stays aligned.
            if in_fg(x * W / w, y * H / h) {
                d.data[y * w + x] = 1.0;
            }
        }
    }
    d
}

fn matte_map(w: usize, h: usize) -> Image {
    let mut m = Image::new(w, h, 1);
    for y in 0..h {
        for x in 0..w {
            if in_fg(x * W / w, y * H / h) {
                m.data[y * w + x] = 1.0;
            }
        }
    }
    m
}

/// A temporary folder holding the standard scene: `image.png` (8-bit sRGB), `image.exr`
/// (linear), `depth.exr` (z, channel Z) and `matte.png` (8-bit grey).
struct Scene {
    dir: tempfile::TempDir,
}

impl Scene {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path();
        let rgb = texture(W, H, 1);
        io::write_png(&p.join("image.png"), &rgb, 8, Transfer::Srgb).unwrap();
        io::write_exr(&p.join("image.exr"), &rgb, &["R", "G", "B"]).unwrap();
        io::write_exr(&p.join("depth.exr"), &depth_map(W, H), &["Z"]).unwrap();
        io::write_png(&p.join("matte.png"), &matte_map(W, H), 8, Transfer::Linear).unwrap();
        Scene { dir }
    }
    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }
    /// Runs `drbokeh ARGS` in the scene folder.
    fn run(&self, args: &[&str]) -> Output {
        drbokeh_in(self.dir.path(), args)
    }
    /// Runs and asserts success; returns stdout.
    fn ok(&self, args: &[&str]) -> String {
        let out = self.run(args);
        assert!(
            out.status.success(),
            "drbokeh {} failed with {:?}\nstderr: {}",
            args.join(" "),
            out.status.code(),
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    }
    /// Runs `--json` and parses stdout.
    fn json(&self, args: &[&str]) -> serde_json::Value {
        let mut a = args.to_vec();
        a.push("--json");
        let s = self.ok(&a);
        serde_json::from_str(&s).unwrap_or_else(|e| panic!("--json output is not JSON ({e}):\n{s}"))
    }
    fn files(&self) -> BTreeSet<String> {
        list_files(self.dir.path())
    }
    /// Runs a command that must fail as bad input: exit 2, stderr naming every `needles`
    /// entry, and no file created or changed in the folder.
    fn bad(&self, args: &[&str], needles: &[&str]) -> String {
        self.bad_with(args, needles, |a| self.run(a))
    }
    /// [`Scene::bad`] for inputs that could block (a FIFO): the run is killed and the test
    /// fails after `limit`.
    fn bad_within(&self, args: &[&str], needles: &[&str], limit: Duration) -> String {
        self.bad_with(args, needles, |a| run_within(drbokeh_cmd(self.dir.path(), a), limit))
    }
    fn bad_with(&self, args: &[&str], needles: &[&str], run: impl FnOnce(&[&str]) -> Output) -> String {
        common::assert_usage_error(self.dir.path(), &format!("drbokeh render {}", args.join(" ")), needles, || run(args))
    }
}

fn drbokeh_in(dir: &Path, args: &[&str]) -> Output {
    drbokeh_cmd(dir, args).output().expect("cannot run drbokeh")
}

/// `drbokeh render ARGS` in `dir`, not started yet.
fn drbokeh_cmd(dir: &Path, args: &[&str]) -> Command {
    let mut c = common::drbokeh(dir);
    c.arg("render").args(args);
    c
}

fn read_npy(p: &Path) -> Image {
    io::read_npy(p, u64::MAX).unwrap_or_else(|e| panic!("cannot read {}: {e}", p.display()))
}

fn read_exr(p: &Path) -> Image {
    let d = io::read_decoded(p, &ReadLimits::default()).unwrap_or_else(|e| panic!("cannot read {}: {e}", p.display()));
    d.image
}

/// Two RGBAD layers of the standard scene: a front square (alpha 1 inside, 0 outside, soft
/// 0.5 ring) at disparity 1 and an opaque textured background at disparity 0.
fn scene_layers() -> (Image, Image) {
    let rgb = texture(W, H, 7);
    let mut fg = Image::new(W, H, 5);
    let mut bg = Image::new(W, H, 5);
    for y in 0..H {
        for x in 0..W {
            let c = rgb.pixel(x, y);
            let ring = (FG_X.start - 1..FG_X.end + 1).contains(&x) && (FG_Y.start - 1..FG_Y.end + 1).contains(&y);
            let a = if in_fg(x, y) {
                1.0
            } else if ring {
                0.5
            } else {
                0.0
            };
            fg.pixel_mut(x, y).copy_from_slice(&[0.9, 0.2, 0.1, a, 1.0]);
            bg.pixel_mut(x, y).copy_from_slice(&[c[0], c[1], c[2], 1.0, 0.1 * x as f32 / W as f32]);
        }
    }
    (fg, bg)
}

fn layers_of(imgs: &[&Image]) -> Vec<Layer<'static>> {
    imgs.iter().map(|i| Layer::new((*i).clone(), "test layer").unwrap()).collect()
}

/// Front-to-back "over" composite of layers, computed here independently of the library.
fn over(imgs: &[&Image]) -> Image {
    let (w, h) = (imgs[0].width, imgs[0].height);
    let mut out = Image::new(w, h, 3);
    for i in 0..w * h {
        let mut t = 1.0f32;
        for l in imgs {
            let p = &l.data[i * 5..i * 5 + 5];
            for c in 0..3 {
                out.data[i * 3 + c] += t * p[3] * p[c];
            }
            t *= 1.0 - p[3];
        }
    }
    out
}

fn stage<'a>(j: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    j["stages"]
        .as_array()
        .expect("stages is an array")
        .iter()
        .find(|s| s["name"] == name)
        .unwrap_or_else(|| panic!("no stage {name} in {j}"))
}

fn f64_of(v: &serde_json::Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

// ---------------------------------------------------------------------------------------------
// Flags
// ---------------------------------------------------------------------------------------------

#[test]
fn default_output_name_is_stem_bokeh_png_in_the_working_dir() {
    let s = Scene::new();
    let before = s.files();
    s.ok(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4"]);
    let new: Vec<String> = s.files().difference(&before).cloned().collect();
    assert_eq!(new, vec!["image_bokeh.png".to_string()], "exactly one new file");
    let img = image::open(s.path("image_bokeh.png")).unwrap();
    assert_eq!((img.width() as usize, img.height() as usize), (W, H));
    assert_eq!(img.color(), image::ColorType::Rgb8, "default PNG is 8-bit RGB");

    // With an absolute image path elsewhere, the default output still lands in the working dir.
    let other = tempfile::tempdir().unwrap();
    let out = drbokeh_in(
        other.path(),
        &[s.path("image.png").to_str().unwrap(), "--depth", s.path("depth.exr").to_str().unwrap(), "--focus", "1", "--blur", "4"],
    );
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(other.path().join("image_bokeh.png").is_file());
}

#[test]
fn default_output_never_overwrites_an_input() {
    // The depth map happens to be named like the default output of the image.
    let s = Scene::new();
    std::fs::copy(s.path("depth.exr"), s.path("image_bokeh.png")).unwrap();
    s.bad(&["image.png", "--depth", "image_bokeh.png", "--focus", "1", "--blur", "4"], &["image_bokeh.png"]);
}

#[test]
fn matte_gives_two_layers_and_focus_keeps_the_subject_sharp() {
    let s = Scene::new();
    let j = s.json(&["image.exr", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "6", "-o", "out.exr"]);
    assert_eq!(j["params"]["layers"], 2, "{j}");
    assert_eq!(stage(&j, "segment")["detail"]["source"], "matte", "{j}");
    for name in ["segment", "fill_depth", "inpaint", "render"] {
        assert_eq!(stage(&j, name)["status"], "ran", "{name}: {j}");
    }
    // The in-focus subject keeps its own colour well inside (no bleeding of the blue background).
    let out = read_exr(&s.path("out.exr"));
    let inp = read_exr(&s.path("image.exr"));
    let mut worst = 0f32;
    for y in FG_Y.start + 2..FG_Y.end - 2 {
        for x in FG_X.start + 2..FG_X.end - 2 {
            for c in 0..3 {
                worst = worst.max((out.pixel(x, y)[c] - inp.pixel(x, y)[c]).abs());
            }
        }
    }
    // The exact kernel's K = 0 softening mixes same-depth neighbours of the textured subject
    // (green varies by 0.3), so allow a fraction of that, but nowhere near the blue background.
    assert!(worst < 0.1, "in-focus subject changed by {worst}");
    // The blurred background differs from the sharp input somewhere.
    assert!(max_abs_diff(&out.data, &inp.data) > 0.01);
}

/// Without a matte the depth split's outline is refined on the photo (`[segment] refine`,
/// default "auto") and `--json` says so; a user's matte is kept as given unless "guided"; "off"
/// refines nothing.
#[test]
fn matting_refines_the_depth_split_and_json_reports_it() {
    let s = Scene::new();
    let base = ["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "-o", "out.exr"];
    let refine = |extra: &[&str], toml: Option<&str>| {
        let mut a: Vec<&str> = base.iter().chain(extra).copied().collect();
        if let Some(t) = toml {
            std::fs::write(s.path("refine.toml"), format!("[segment]\nrefine = \"{t}\"\n")).unwrap();
            a.extend(["--config", "refine.toml"]);
        }
        let j = s.json(&a);
        assert_eq!(stage(&j, "segment")["detail"]["layers"], 2, "{j}");
        stage(&j, "segment")["detail"]["refine"].clone()
    };
    let split = refine(&[], None);
    assert!(split["unknown_px"].as_u64().unwrap() > 0, "{split}");
    assert!(split["band_inside_px"].as_f64().unwrap() >= 2.0, "{split}");
    assert!(refine(&["--matte", "matte.png"], None).is_null());
    assert!(refine(&["--matte", "matte.png"], Some("guided"))["unknown_px"].as_u64().unwrap() > 0);
    assert_eq!(split["solver"], "guided", "{split}");
    assert_eq!(refine(&[], Some("closed-form"))["solver"], "closed-form");
    assert!(refine(&[], Some("off")).is_null());
}

#[test]
fn focus_at_uses_the_disparity_under_the_pixel() {
    let s = Scene::new();
    let base = ["image.png", "--depth", "depth.exr", "--blur", "3"];
    let mut a = base.to_vec();
    a.extend(["--focus-at", "15,11"]);
    let j = s.json(&a);
    assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-6, "foreground pixel: {j}");
    let mut a = base.to_vec();
    a.extend(["--focus-at", "0,0"]);
    let j = s.json(&a);
    assert!(f64_of(&j["params"]["focus"]).abs() < 1e-6, "background pixel: {j}");
    // The far corner is legal.
    let mut a = base.to_vec();
    a.extend(["--focus-at", "31,23"]);
    s.json(&a);
}

/// The guide's `--focus-at X,Y`: the focus is the median disparity of a small window around
/// the pixel, so a click on a speck of wrong depth still focuses on the surface under it (the
/// test above clicks inside uniform regions, where one pixel and the median agree).
#[test]
fn focus_at_takes_the_median_around_the_pixel() {
    let s = Scene::new();
    let mut d = depth_map(W, H);
    // One pixel of the background's depth inside the square (z = 1): the 5x5 window around
    // it holds 24 pixels of the square.
    d.data[11 * W + 15] = 4.0;
    io::write_exr(&s.path("speck.exr"), &d, &["Z"]).unwrap();
    let j = s.json(&["image.png", "--depth", "speck.exr", "--focus-at", "15,11", "--blur", "3", "-o", "o.png"]);
    assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-6, "a speck under the click took the focus: {j}");
}

/// The guide's `--focus F`: a focus outside [0, 1] is clamped, with a warning. The render
/// focuses at the end of the range (the JSON's `params.focus`, and the same picture as that
/// focus given directly), not at the value given; `bad_flag_values` checks the warning only.
#[test]
fn focus_outside_the_range_is_clamped_to_it() {
    let s = Scene::new();
    for (f, end) in [("1.5", "1"), ("-0.5", "0")] {
        let j = s.json(&["image.exr", "--depth", "depth.exr", "--focus", f, "--blur", "3", "-o", "out.npy"]);
        assert_eq!(f64_of(&j["params"]["focus"]), end.parse::<f64>().unwrap(), "--focus {f}: {j}");
        assert!(j["warnings"].to_string().contains("clamped"), "--focus {f}: {j}");
        s.ok(&["image.exr", "--depth", "depth.exr", "--focus", end, "--blur", "3", "-o", "end.npy"]);
        assert_eq!(read_npy(&s.path("out.npy")).data, read_npy(&s.path("end.npy")).data, "--focus {f} is not --focus {end}");
    }
}

#[test]
fn focus_depth_converts_metric_depth() {
    let s = Scene::new();
    for (z, want) in [("1", 1.0), ("4", 0.0), ("2", 1.0 / 3.0)] {
        let j = s.json(&["image.png", "--depth", "depth.exr", "--focus-depth", z, "--blur", "3"]);
        assert!((f64_of(&j["params"]["focus"]) - want).abs() < 1e-5, "z = {z}: {j}");
    }
}

#[test]
fn blur_flag_sets_k_and_default_scales_with_size() {
    let s = Scene::new();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "7.5"]);
    assert_eq!(f64_of(&j["params"]["blur"]), 7.5);
    assert!((f64_of(&j["params"]["max_coc_radius_px"]) - 7.5).abs() < 1e-4, "{j}");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1"]);
    let want = 30.0 * ((W * H) as f64 / 1e6).sqrt();
    assert!((f64_of(&j["params"]["blur"]) - want).abs() < 1e-4, "default K: {j}");
}

#[test]
fn lens_flag_and_auto_lens() {
    let s = Scene::new();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--lens", "7"]);
    assert_eq!(j["params"]["lens"], 7);
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4"]);
    let lens = j["params"]["lens"].as_u64().unwrap();
    assert!(lens % 2 == 1, "auto lens must be odd: {lens}");
    assert!(lens as f64 >= 2.0 * 4.0 + 1.0, "auto lens {lens} must cover the CoC of radius 4 (+1)");
    // --lens changes the picture.
    s.ok(&["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--kernel", "exact", "--lens", "3", "-o", "l3.npy"]);
    s.ok(&["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--kernel", "exact", "--lens", "15", "-o", "l15.npy"]);
    assert!(max_abs_diff(&read_npy(&s.path("l3.npy")).data, &read_npy(&s.path("l15.npy")).data) > 1e-3);
}

#[test]
fn gamma_renders_on_powered_colours() {
    // With layers and .npy output the whole gamma path can be checked number for number:
    // colours ^G, exact render, result ^(1/G).
    let s = Scene::new();
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    let j = s.json(&[
        "--layer",
        "fg.npy",
        "--layer",
        "bg.npy",
        "--focus",
        "0",
        "--blur",
        "5",
        "--gamma",
        "2.2",
        "--profile",
        "official",
        "--kernel",
        "exact",
        "-o",
        "g.npy",
    ]);
    assert!((f64_of(&j["params"]["gamma"]) - 2.2).abs() < 1e-6, "{j}");
    let got = read_npy(&s.path("g.npy"));
    let mut layers = layers_of(&[&fg, &bg]);
    for l in &mut layers {
        l.map_colors(|c| (c.max(0.0) as f64).powf(2.2) as f32);
    }
    let st = RenderSettings {
        blur: 5.0,
        focus: 0.0,
        lens: render::auto_lens(&layers, 5.0, 0.0),
        occlusion: true,
        profile: drbokeh::render::Profile::Official,
        aperture: drbokeh::render::Aperture::DISC,
    };
    let mut want = render::render(&layers, &st, Kernel::Exact).unwrap();
    want.map_inplace(|v| v.max(0.0).powf(1.0 / 2.2));
    let e = max_abs_diff(&got.data, &want.data);
    assert!(e < 1e-5, "gamma path differs from the library by {e}");
    // And it is not the same as the default (exact transfer / linear) result.
    s.ok(&["--layer", "fg.npy", "--layer", "bg.npy", "--focus", "0", "--blur", "5", "--kernel", "exact", "-o", "lin.npy"]);
    assert!(max_abs_diff(&got.data, &read_npy(&s.path("lin.npy")).data) > 1e-3);
    // A photo input also accepts --gamma.
    s.ok(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--gamma", "2.2", "-o", "g.png"]);
    assert!(s.path("g.png").is_file());
}

#[test]
fn kernel_exact_and_auto() {
    let s = Scene::new();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--kernel", "exact"]);
    assert_eq!(j["params"]["kernel"], "exact");
    assert_eq!(stage(&j, "render")["status"], "ran");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--kernel", "auto"]);
    assert_eq!(stage(&j, "render")["status"], "ran");
    // auto skips the render when nothing is out of focus; exact still runs it.
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "--kernel", "auto"]);
    assert_eq!(stage(&j, "render")["status"], "skipped", "{j}");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "--kernel", "exact"]);
    assert_eq!(stage(&j, "render")["status"], "ran", "{j}");
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--kernel", "turbo", "-o", "o.png"], &["--kernel"]);
}

#[test]
fn no_occlusion_renders_one_layer() {
    let s = Scene::new();
    let j = s.json(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "6",
        "--no-occlusion",
        "-o",
        "no.npy",
    ]);
    assert_eq!(j["params"]["occlusion"], false, "{j}");
    assert_eq!(j["params"]["layers"], 1, "{j}");
    let seg = stage(&j, "segment");
    assert_eq!(seg["status"], "skipped");
    assert!(seg["reason"].as_str().unwrap().contains("no-occlusion"), "{j}");
    s.ok(&["image.exr", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "6", "-o", "occ.npy"]);
    let (a, b) = (read_npy(&s.path("no.npy")), read_npy(&s.path("occ.npy")));
    assert!(max_abs_diff(&a.data, &b.data) > 1e-3, "--no-occlusion should differ from Dr.Bokeh");

    // With layers it keeps only the back layer, with a warning.
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    let out = s.run(&[
        "--layer",
        "fg.npy",
        "--layer",
        "bg.npy",
        "--focus",
        "0",
        "--blur",
        "3",
        "--no-occlusion",
        "--profile",
        "official",
        "--kernel",
        "exact",
        "-o",
        "nl.npy",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("warning"));
    let layers = layers_of(&[&bg]);
    let st = RenderSettings {
        blur: 3.0,
        focus: 0.0,
        lens: render::auto_lens(&layers, 3.0, 0.0),
        occlusion: false,
        profile: drbokeh::render::Profile::Official,
        aperture: drbokeh::render::Aperture::DISC,
    };
    let want = render::render(&layers, &st, Kernel::Exact).unwrap();
    assert!(max_abs_diff(&read_npy(&s.path("nl.npy")).data, &want.data) < 1e-6);
}

#[test]
fn depth_kind_disparity_flips_near_and_far() {
    let s = Scene::new();
    // depth.exr holds 1 (square) and 4 (background). Read as disparity, the background is near.
    let j = s.json(&["image.png", "--depth", "depth.exr", "--depth-kind", "disparity", "--focus-at", "0,0", "--blur", "3"]);
    assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-6, "{j}");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--depth-kind", "depth", "--focus-at", "0,0", "--blur", "3"]);
    assert!(f64_of(&j["params"]["focus"]).abs() < 1e-6, "{j}");
    // A disparity map may hold zeros and negative values.
    let mut disp = depth_map(W, H);
    disp.map_inplace(|v| if v == 1.0 { 0.5 } else { -2.0 });
    io::save_npy(&s.path("disp.npy"), &disp).unwrap();
    let j = s.json(&["image.png", "--depth", "disp.npy", "--depth-kind", "disparity", "--focus-at", "15,11", "--blur", "3"]);
    assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-6, "{j}");
    // --focus-depth makes no sense for a disparity map.
    s.bad(&["image.png", "--depth", "disp.npy", "--depth-kind", "disparity", "--focus-depth", "2", "-o", "x.png"], &["--focus-depth"]);
}

#[test]
fn bit_depth_16_writes_a_16_bit_png() {
    let s = Scene::new();
    s.ok(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "--bit-depth", "16", "-o", "o16.png"]);
    s.ok(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "--bit-depth", "8", "-o", "o8.png"]);
    let i16 = image::open(s.path("o16.png")).unwrap();
    let i8 = image::open(s.path("o8.png")).unwrap();
    assert_eq!(i16.color(), image::ColorType::Rgb16);
    assert_eq!(i8.color(), image::ColorType::Rgb8);
    // Same picture at two precisions.
    let a = i16.to_rgb16();
    let b = i8.to_rgb8();
    let worst = a.as_raw().iter().zip(b.as_raw()).map(|(&x, &y)| (x as f32 / 65535.0 - y as f32 / 255.0).abs()).fold(0.0, f32::max);
    assert!(worst <= 0.5 / 255.0 + 1e-6, "8 and 16-bit outputs differ by {worst}");
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--bit-depth", "12", "-o", "o12.png"], &["--bit-depth"]);
}

#[test]
fn save_layers_writes_exr_layers_that_feed_back() {
    let s = Scene::new();
    s.ok(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "5",
        "--kernel",
        "exact",
        "--save-layers",
        "layers",
        "-o",
        "out.npy",
    ]);
    for f in [
        "0_fg.exr",
        "1_bg.exr",
        "0_fg_color.png",
        "0_fg_alpha.png",
        "0_fg_disparity.png",
        "1_bg_color.png",
        "1_bg_alpha.png",
        "1_bg_disparity.png",
    ] {
        assert!(s.path("layers").join(f).is_file(), "missing layers/{f}; have {:?}", s.files());
    }
    // A glob of the EXR files lists them front to back.
    let mut exrs: Vec<String> = s.files().into_iter().filter(|f| f.starts_with("layers/") && f.ends_with(".exr")).collect();
    exrs.sort();
    assert_eq!(exrs, ["layers/0_fg.exr", "layers/1_bg.exr"]);
    let fg = io::read_layer(&s.path("layers/0_fg.exr"), &ReadLimits::default()).unwrap();
    assert_eq!((fg.width, fg.height, fg.channels), (W, H, 5));
    // Alpha of the foreground layer is the matte.
    assert_eq!(fg.pixel(15, 11)[3], 1.0);
    assert_eq!(fg.pixel(0, 0)[3], 0.0);
    // Feeding the saved layers back renders the same picture.
    s.ok(&[
        "--layer",
        "layers/0_fg.exr",
        "--layer",
        "layers/1_bg.exr",
        "--focus",
        "1",
        "--blur",
        "5",
        "--kernel",
        "exact",
        "-o",
        "again.npy",
    ]);
    let e = max_abs_diff(&read_npy(&s.path("out.npy")).data, &read_npy(&s.path("again.npy")).data);
    assert!(e < 1e-6, "re-rendering the saved layers differs by {e}");
}

/// Issue 10: no file the tool writes may be a file the run reads, whatever its spelling
/// (same name, another path to it, a hard or symbolic link): `-o` and every `--save-layers`
/// file; refused before anything is written, the folder unchanged.
#[test]
fn writes_never_hit_an_input() {
    let s = Scene::new();
    std::fs::create_dir(s.path("L")).unwrap();
    // Inputs living in the layer folder under layer-file names.
    std::fs::copy(s.path("depth.exr"), s.path("L/0_fg.exr")).unwrap();
    std::fs::copy(s.path("matte.png"), s.path("L/1_bg_alpha.png")).unwrap();
    let base = ["image.png", "--focus", "1", "--blur", "4"];
    let with = |extra: &[&'static str]| -> Vec<&'static str> { base.iter().copied().chain(extra.iter().copied()).collect() };
    s.bad(&with(&["--depth", "L/0_fg.exr", "--matte", "matte.png", "--save-layers", "L", "-o", "o.png"]), &["L/0_fg.exr", "--save-layers"]);
    s.bad(&with(&["--depth", "depth.exr", "--matte", "L/1_bg_alpha.png", "--save-layers", "L", "-o", "o.png"]), &["1_bg_alpha.png"]);
    // The same file through another spelling of its path.
    s.bad(&with(&["--depth", "L/0_fg.exr", "--matte", "matte.png", "--save-layers", "L/../L", "-o", "o.png"]), &["0_fg.exr"]);
    // -o onto an input, by name and through links.
    s.bad(&with(&["--depth", "depth.exr", "-o", "image.png"]), &["image.png"]);
    #[cfg(unix)]
    {
        std::fs::hard_link(s.path("image.png"), s.path("hard.png")).unwrap();
        std::os::unix::fs::symlink(s.path("image.png"), s.path("soft.png")).unwrap();
        s.bad(&with(&["--depth", "depth.exr", "-o", "hard.png"]), &["hard.png", "image.png"]);
        s.bad(&with(&["--depth", "depth.exr", "-o", "soft.png"]), &["soft.png"]);
    }
    // --layer inputs and --save-layers into their own folder.
    s.ok(&[
        "image.png",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "4",
        "--save-layers",
        "M",
        "-o",
        "m.png",
    ]);
    s.bad(
        &["--layer", "M/0_fg.exr", "--layer", "M/1_bg.exr", "--focus", "0", "--blur", "4", "--save-layers", "M", "-o", "n.png"],
        &["M/0_fg.exr"],
    );
}

/// The inputs are read side by side, but a run with several bad inputs reports the first in
/// the order they are used: the photo before the depth map and the matte, the first layer
/// before the second.
#[test]
fn the_first_bad_input_in_order_is_reported() {
    let s = Scene::new();
    for name in ["bad1.exr", "bad2.exr", "bad.png", "bad_matte.png"] {
        std::fs::write(s.path(name), b"not an image at all, just some bytes").unwrap();
    }
    let e = s.bad(&["--layer", "bad1.exr", "--layer", "bad2.exr", "--focus", "0", "--blur", "4", "-o", "o.png"], &["bad1.exr"]);
    assert!(!e.contains("bad2.exr"), "{e}");
    let e = s.bad(&["bad.png", "--depth", "bad1.exr", "--matte", "bad_matte.png", "--focus", "0", "-o", "o.png"], &["bad.png"]);
    assert!(!e.contains("bad1.exr") && !e.contains("bad_matte.png"), "{e}");
    let e = s.bad(&["image.png", "--depth", "bad1.exr", "--matte", "bad_matte.png", "--focus", "0", "-o", "o.png"], &["bad1.exr"]);
    assert!(!e.contains("bad_matte.png"), "{e}");
    s.bad(&["image.png", "--depth", "depth.exr", "--matte", "bad_matte.png", "--focus", "0", "-o", "o.png"], &["bad_matte.png"]);
}

/// A run that succeeds leaves every input byte for byte as it was (photo, depth map, matte,
/// and the saved layers when they are read back with `--layer`): only the outputs are new.
#[test]
fn a_successful_run_leaves_its_inputs_as_they_were() {
    let s = Scene::new();
    let before = common::snapshot(s.dir.path());
    s.ok(&[
        "image.png",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "4",
        "--save-layers",
        "L",
        "-o",
        "a.png",
    ]);
    let after = common::snapshot(s.dir.path());
    for (name, bytes) in &before {
        let now = after.iter().find(|(n, _)| n == name).map(|(_, b)| b);
        assert!(now == Some(bytes), "{name} changed or vanished");
    }
    let layers = common::snapshot(s.dir.path());
    s.ok(&["--layer", "L/0_fg.exr", "--layer", "L/1_bg.exr", "--focus", "0", "--blur", "4", "-o", "b.png"]);
    let again = common::snapshot(s.dir.path());
    for (name, bytes) in &layers {
        assert!(again.iter().any(|(n, b)| n == name && b == bytes), "{name} changed or vanished");
    }
    assert!(again.iter().any(|(n, _)| n == "b.png"), "the second run wrote its output");
}

#[test]
fn verbose_prints_stage_timings() {
    let s = Scene::new();
    let out = s.run(&["image.png", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "4", "-v"]);
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    for name in ["read", "segment", "fill_depth", "inpaint", "render", "write", "total"] {
        let line = err.lines().find(|l| l.trim_start().starts_with(name)).unwrap_or_else(|| panic!("no {name} line in:\n{err}"));
        assert!(line.contains("ms"), "{name} line has no timing: {line}");
    }
    let out = s.run(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "-v", "-o", "z.png"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.lines().any(|l| l.contains("render") && l.contains("skipped")), "skipped render not shown:\n{err}");
}

#[test]
fn json_summary() {
    let s = Scene::new();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "4", "-o", "o.png"]);
    assert!(j["output"].as_str().unwrap().ends_with("o.png"), "{j}");
    let stages = j["stages"].as_array().unwrap();
    assert!(stages.len() >= 6, "{j}");
    for st in stages {
        assert!(st["name"].is_string() && st["status"].is_string() && st["ms"].is_number(), "{st}");
    }
    for key in ["width", "height", "blur", "focus", "lens", "kernel", "occlusion", "layers", "threads"] {
        assert!(!j["params"][key].is_null(), "params.{key} missing: {j}");
    }
    assert_eq!((j["params"]["width"].as_u64(), j["params"]["height"].as_u64()), (Some(W as u64), Some(H as u64)));
    assert!(j["total_ms"].is_number());

    // Skipped stages say why.
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "-o", "z.png"]);
    let mut skipped = 0;
    for st in j["stages"].as_array().unwrap() {
        if st["status"] == "skipped" {
            skipped += 1;
            assert!(st["reason"].as_str().is_some_and(|r| !r.is_empty()), "skipped stage without reason: {st}");
        }
    }
    assert!(skipped >= 4, "segment, fill_depth, inpaint and render are skipped at K = 0: {j}");
    // A single-layer scene (flat depth, no matte) skips fill_depth and inpaint with a reason.
    io::write_exr(&s.path("flat.exr"), &Image::filled(W, H, 1, 2.0), &["Z"]).unwrap();
    let j = s.json(&["image.png", "--depth", "flat.exr", "--focus", "0.5", "--blur", "4", "-o", "f.png"]);
    for name in ["fill_depth", "inpaint"] {
        let st = stage(&j, name);
        assert_eq!(st["status"], "skipped", "{j}");
        assert!(st["reason"].as_str().is_some_and(|r| !r.is_empty()));
    }
    // --json stdout holds only the JSON.
    let out = s.run(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "--json", "-o", "q.png"]);
    let text = String::from_utf8(out.stdout).unwrap();
    serde_json::from_str::<serde_json::Value>(&text).unwrap();
}

#[test]
fn config_file_is_honoured_and_flags_override_it() {
    let s = Scene::new();
    std::fs::write(s.path("p.toml"), "[render]\nblur = 3.5\nlens = 9\n").unwrap();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "p.toml"]);
    assert_eq!(f64_of(&j["params"]["blur"]), 3.5, "{j}");
    assert_eq!(j["params"]["lens"], 9, "{j}");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "p.toml", "--blur", "2"]);
    assert_eq!(f64_of(&j["params"]["blur"]), 2.0, "flag overrides config: {j}");
    // Other sections and keys are honoured too.
    std::fs::write(s.path("k.toml"), "[render]\nkernel = \"exact\"\nblur = 0.0\n[output]\nbit_depth = 16\n").unwrap();
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "k.toml", "-o", "k.png"]);
    assert_eq!(stage(&j, "render")["status"], "ran", "config kernel = exact runs at K = 0: {j}");
    assert_eq!(image::open(s.path("k.png")).unwrap().color(), image::ColorType::Rgb16, "config output.bit_depth = 16");
    // The bundled pipeline.toml parses.
    let bundled = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipeline.toml");
    if bundled.is_file() {
        s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "--config", bundled.to_str().unwrap()]);
    }
}

#[test]
fn config_unknown_key_exits_2_naming_the_key() {
    let s = Scene::new();
    std::fs::write(s.path("bad.toml"), "[render]\nblurr = 3.5\n").unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "bad.toml", "-o", "o.png"], &["blurr", "bad.toml"]);
    std::fs::write(s.path("bad2.toml"), "[rendr]\nblur = 3.5\n").unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "bad2.toml", "-o", "o.png"], &["rendr"]);
    // A bad value in the config names the key.
    std::fs::write(s.path("bad3.toml"), "[render]\nlens = 4\n").unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "bad3.toml", "-o", "o.png"], &["lens", "bad3.toml"]);
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", "missing.toml", "-o", "o.png"], &["missing.toml"]);
}

#[test]
fn layers_npy_and_exr() {
    let s = Scene::new();
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::write_exr(&s.path("bg.exr"), &bg, &["R", "G", "B", "A", "D"]).unwrap();
    io::write_exr(&s.path("fg.exr"), &fg, &["R", "G", "B", "A", "D"]).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    let j = s.json(&["--layer", "fg.npy", "--layer", "bg.exr", "--focus", "0", "--blur", "4", "-o", "a.npy"]);
    assert_eq!(j["params"]["layers"], 2);
    for name in ["segment", "fill_depth", "inpaint"] {
        assert_eq!(stage(&j, name)["status"], "skipped", "{j}");
    }
    s.ok(&["--layer", "fg.exr", "--layer", "bg.npy", "--focus", "0", "--blur", "4", "-o", "b.npy"]);
    assert_eq!(read_npy(&s.path("a.npy")).data, read_npy(&s.path("b.npy")).data, "EXR and NPY layers give the same result");
    // --focus-at on layers picks the front-most mostly-opaque layer.
    let j = s.json(&["--layer", "fg.npy", "--layer", "bg.npy", "--focus-at", "15,11", "--blur", "4", "-o", "c.npy"]);
    assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-6, "{j}");
    // Three layers are allowed.
    s.ok(&["--layer", "fg.npy", "--layer", "fg.exr", "--layer", "bg.npy", "--focus", "0.5", "--blur", "3", "-o", "three.png"]);
    // Default output name for layers is the first layer's stem.
    s.ok(&["--layer", "fg.npy", "--layer", "bg.npy", "--focus", "0", "--blur", "3"]);
    assert!(s.path("fg_bokeh.png").is_file(), "{:?}", s.files());
    // Layer inputs and an image are exclusive; a layer needs 5 channels; sizes must agree.
    s.bad(&["image.png", "--layer", "fg.npy", "--focus", "0", "-o", "x.png"], &["--layer"]);
    io::save_npy(&s.path("four.npy"), &Image::new(W, H, 4)).unwrap();
    s.bad(&["--layer", "four.npy", "--focus", "0", "-o", "x.png"], &["four.npy"]);
    io::save_npy(&s.path("small.npy"), &Image::new(W / 2, H / 2, 5)).unwrap();
    s.bad(&["--layer", "fg.npy", "--layer", "small.npy", "--focus", "0", "--blur", "3", "-o", "x.png"], &["layer"]);
    let mut nan = bg.clone();
    nan.data[7] = f32::NAN;
    io::save_npy(&s.path("nan.npy"), &nan).unwrap();
    s.bad(&["--layer", "nan.npy", "--focus", "0", "-o", "x.png"], &["nan.npy"]);
}

// ---------------------------------------------------------------------------------------------
// Output formats
// ---------------------------------------------------------------------------------------------

#[test]
fn output_formats_agree() {
    let s = Scene::new();
    let args = ["image.png", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "4"];
    for out in ["o.png", "o16.png", "o.exr", "o.npy"] {
        let mut a = args.to_vec();
        a.extend(["-o", out]);
        if out == "o16.png" {
            a.extend(["--bit-depth", "16"]);
        }
        s.ok(&a);
    }
    let exr = read_exr(&s.path("o.exr"));
    let npy = read_npy(&s.path("o.npy"));
    assert_eq!((exr.width, exr.height, exr.channels), (W, H, 3));
    assert_eq!((npy.width, npy.height, npy.channels), (W, H, 3));
    assert_eq!(exr.data, npy.data, "EXR and NPY hold the same linear float32 values");
    assert!(npy.all_finite());
    // PNGs are the sRGB encoding of the same values.
    for (name, bits) in [("o.png", 8u8), ("o16.png", 16)] {
        let d = io::read_decoded(&s.path(name), &ReadLimits::default()).unwrap();
        assert_eq!(d.bit_depth, bits);
        let max = if bits == 8 { 255.0 } else { 65535.0 };
        for (q, &v) in d.image.data.iter().zip(&npy.data) {
            let want = (drbokeh::color::linear_to_srgb(v).clamp(0.0, 1.0) * max).round() / max;
            assert!((q - want).abs() <= 1.0 / max + 1e-6, "{name}: {q} vs {want}");
        }
    }
    // An unknown output extension is refused before any work.
    let mut a = args.to_vec();
    a.extend(["-o", "o.bmp"]);
    s.bad(&a, &["o.bmp"]);
}

#[test]
fn npy_output_of_layers_equals_the_library_render() {
    let s = Scene::new();
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    for (focus, blur) in [(0.0f32, 4.0f32), (1.0, 6.0), (0.5, 3.0)] {
        let (fs, bs) = (focus.to_string(), blur.to_string());
        s.ok(&[
            "--layer",
            "fg.npy",
            "--layer",
            "bg.npy",
            "--focus",
            &fs,
            "--blur",
            &bs,
            "--profile",
            "official",
            "--kernel",
            "exact",
            "-o",
            "r.npy",
        ]);
        let got = read_npy(&s.path("r.npy"));
        let layers = layers_of(&[&fg, &bg]);
        let st = RenderSettings {
            blur,
            focus,
            lens: render::auto_lens(&layers, blur, focus),
            occlusion: true,
            profile: drbokeh::render::Profile::Official,
            aperture: drbokeh::render::Aperture::DISC,
        };
        let want = render::render(&layers, &st, Kernel::Exact).unwrap();
        let e = max_abs_diff(&got.data, &want.data);
        assert!(e <= 1e-6, "focus {focus}, K {blur}: CLI and library differ by {e}");
    }
}

// ---------------------------------------------------------------------------------------------
// Nothing to render
// ---------------------------------------------------------------------------------------------

#[test]
fn blur_zero_returns_the_exr_input_unchanged() {
    let s = Scene::new();
    // HDR and odd values survive untouched.
    let mut rgb = texture(W, H, 3);
    rgb.data[0] = 1234.5;
    rgb.data[5] = 1e-7;
    io::write_exr(&s.path("hdr.exr"), &rgb, &["R", "G", "B"]).unwrap();
    s.ok(&["hdr.exr", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "0.3", "--blur", "0", "-o", "out.exr"]);
    let out = read_exr(&s.path("out.exr"));
    assert_eq!(out.data, rgb.data, "K = 0 must return the input exactly");
    // Also to NPY.
    s.ok(&["hdr.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "-o", "out.npy"]);
    assert_eq!(read_npy(&s.path("out.npy")).data, rgb.data);
}

#[test]
fn blur_zero_png_round_trips_8_bit_pixels() {
    let s = Scene::new();
    s.ok(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "0", "-o", "same.png"]);
    let a = image::open(s.path("image.png")).unwrap().to_rgb8();
    let b = image::open(s.path("same.png")).unwrap().to_rgb8();
    assert_eq!(a.as_raw(), b.as_raw(), "K = 0 must give back the same 8-bit pixels");
}

#[test]
fn blur_zero_with_layers_is_the_alpha_composite() {
    let s = Scene::new();
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::write_exr(&s.path("bg.exr"), &bg, &["R", "G", "B", "A", "D"]).unwrap();
    let j = s.json(&["--layer", "fg.npy", "--layer", "bg.exr", "--focus", "0.4", "--blur", "0", "-o", "c.npy"]);
    assert_eq!(stage(&j, "render")["status"], "skipped", "{j}");
    let got = read_npy(&s.path("c.npy"));
    let want = over(&[&fg, &bg]);
    let e = max_abs_diff(&got.data, &want.data);
    assert!(e <= 1e-6, "K = 0 with layers should be their over composite; differs by {e}");
}

#[test]
fn kernel_exact_at_blur_zero_is_not_the_identity() {
    let s = Scene::new();
    s.ok(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--focus",
        "1",
        "--blur",
        "0",
        "--profile",
        "official",
        "--kernel",
        "exact",
        "-o",
        "e.exr",
    ]);
    let out = read_exr(&s.path("e.exr"));
    let inp = read_exr(&s.path("image.exr"));
    let e = max_abs_diff(&out.data, &inp.data);
    assert!(e > 1e-3, "--kernel exact at K = 0 softens slightly (official soft step); got max change {e}");
    // On a single-layer scene (flat depth) it is only a slight softening: the centre keeps
    // 0.668 of the weight against ~0.06 for all its same-depth neighbours together.
    io::write_exr(&s.path("flat.exr"), &Image::filled(W, H, 1, 2.0), &["Z"]).unwrap();
    let j = s.json(&[
        "image.exr",
        "--depth",
        "flat.exr",
        "--focus",
        "0",
        "--blur",
        "0",
        "--profile",
        "official",
        "--kernel",
        "exact",
        "-o",
        "f.exr",
    ]);
    assert_eq!(j["params"]["layers"], 1, "{j}");
    let out = read_exr(&s.path("f.exr"));
    let e = max_abs_diff(&out.data, &inp.data);
    // Largest neighbour contrast in the texture is 0.8 (red subject vs background);
    // 0.8 * 0.06 / 0.73 = 0.066.
    assert!(e > 1e-3 && e < 0.07, "flat scene, exact kernel at K = 0 changed the image by {e}");
    // The physical profile (the default) at K = 0 is the identity, exact kernel included.
    s.ok(&["image.exr", "--depth", "flat.exr", "--focus", "0", "--blur", "0", "--kernel", "exact", "-o", "p.exr"]);
    assert_eq!(read_exr(&s.path("p.exr")).data, inp.data);
}

// ---------------------------------------------------------------------------------------------
// Bad input: exit 2, a message naming the file or flag, no output
// ---------------------------------------------------------------------------------------------

#[test]
fn missing_files() {
    let s = Scene::new();
    s.bad(&["nope.png", "--depth", "depth.exr", "--focus", "1", "-o", "o.png"], &["nope.png"]);
    s.bad(&["image.png", "--depth", "nodepth.exr", "--focus", "1", "-o", "o.png"], &["nodepth.exr"]);
    s.bad(&["image.png", "--depth", "depth.exr", "--matte", "nomatte.png", "--focus", "1", "-o", "o.png"], &["nomatte.png"]);
    s.bad(&["--layer", "nolayer.npy", "--focus", "1", "-o", "o.png"], &["nolayer.npy"]);
    // Default output name too: nothing written.
    s.bad(&["nope.png", "--depth", "depth.exr", "--focus", "1"], &["nope.png"]);
}

#[test]
fn undecodable_inputs() {
    let s = Scene::new();
    std::fs::write(s.path("x.png"), b"this is not a PNG at all, just some garbage bytes").unwrap();
    s.bad(&["x.png", "--depth", "depth.exr", "--focus", "1", "-o", "o.png"], &["x.png"]);
    s.bad(&["image.png", "--depth", "x.png", "--focus", "1", "-o", "o.png"], &["x.png"]);
    s.bad(&["image.png", "--depth", "depth.exr", "--matte", "x.png", "--focus", "1", "-o", "o.png"], &["x.png"]);
    // A truncated real PNG.
    let full = std::fs::read(s.path("image.png")).unwrap();
    std::fs::write(s.path("cut.png"), &full[..full.len() / 2]).unwrap();
    s.bad(&["cut.png", "--depth", "depth.exr", "--focus", "1", "-o", "o.png"], &["cut.png"]);
    // An empty file and a folder.
    std::fs::write(s.path("empty.exr"), b"").unwrap();
    s.bad(&["image.png", "--depth", "empty.exr", "--focus", "1", "-o", "o.png"], &["empty.exr"]);
    std::fs::create_dir(s.path("dir.png")).unwrap();
    s.bad(&["dir.png", "--depth", "depth.exr", "--focus", "1", "-o", "o.png"], &["dir.png"]);
}

#[test]
fn depth_size_mismatch_with_another_aspect_ratio() {
    let s = Scene::new();
    io::write_exr(&s.path("wide.exr"), &Image::filled(W, H / 3, 1, 2.0), &["Z"]).unwrap();
    let err = s.bad(&["image.png", "--depth", "wide.exr", "--focus", "1", "-o", "o.png"], &["wide.exr"]);
    assert!(err.contains("32x8") || err.contains("aspect"), "{err}");
}

#[test]
fn depth_same_aspect_at_half_resolution_warns_and_works() {
    let s = Scene::new();
    io::write_exr(&s.path("half.exr"), &depth_map(W / 2, H / 2), &["Z"]).unwrap();
    let out = s.run(&["image.png", "--depth", "half.exr", "--matte", "matte.png", "--focus", "1", "--blur", "4", "-o", "o.png"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("warning") && err.contains("half.exr"), "expected a resize warning naming the file: {err}");
    let img = image::open(s.path("o.png")).unwrap();
    assert_eq!((img.width() as usize, img.height() as usize), (W, H));
    // The render is the full-size map's, not a flat one: the map is in metres (1 and 4), and a
    // resize that clamped it to [0, 1] made every depth 1, so nothing was blurred (exit 0).
    let render = |depth: &str, out: &str| {
        let o = s.run(&["image.exr", "--depth", depth, "--focus", "1", "--blur", "4", "-o", out]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        read_npy(&s.path(out))
    };
    let (full, half) = (render("depth.exr", "full.npy"), render("half.exr", "half.npy"));
    let photo = texture(W, H, 1);
    let mean_abs = |a: &Image, b: &Image| a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs() as f64).sum::<f64>() / a.data.len() as f64;
    // How far a blur of this scene moves the photo, by another route: the classical scatter
    // (one layer, no occlusion) with the same full-size map. A render that blurred nothing
    // (the clamped map) is near 0 on this scale.
    let o = s.run(&["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--no-occlusion", "-o", "scatter.npy"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scale = mean_abs(&read_npy(&s.path("scatter.npy")), &photo);
    let (blurred, apart) = (mean_abs(&full, &photo), mean_abs(&half, &full));
    // Measured: 0.0235 and 0.0121 (the half-size map's edges are soft at this 32×24 size);
    // with the clamp, 0.0333.
    assert!(
        blurred > 0.5 * scale && apart < 0.7 * blurred,
        "full-size map's render {blurred:.4} from the photo (the scatter's {scale:.4}), half-size map's {apart:.4} from it"
    );
}

#[test]
fn invalid_depth_values() {
    let s = Scene::new();
    for (name, v) in [("nan", f32::NAN), ("inf", f32::INFINITY), ("neg", -1.0), ("zero", 0.0)] {
        let d = Image::filled(W, H, 1, v);
        let exr = format!("{name}.exr");
        let npy = format!("{name}.npy");
        io::write_exr(&s.path(&exr), &d, &["Z"]).unwrap();
        io::save_npy(&s.path(&npy), &d).unwrap();
        s.bad(&["image.png", "--depth", &exr, "--focus", "1", "-o", "o.png"], &[&exr]);
        s.bad(&["image.png", "--depth", &npy, "--focus", "1", "-o", "o.png"], &[&npy]);
    }
    // All NaN / Inf is invalid as disparity too.
    for name in ["nan", "inf"] {
        let npy = format!("{name}.npy");
        s.bad(&["image.png", "--depth", &npy, "--depth-kind", "disparity", "--focus", "1", "-o", "o.png"], &[&npy]);
    }
    // Partly invalid depth is filled, with a warning.
    let mut d = depth_map(W, H);
    d.data[3] = f32::NAN;
    d.data[40] = -5.0;
    io::save_npy(&s.path("holes.npy"), &d).unwrap();
    let out = s.run(&["image.png", "--depth", "holes.npy", "--focus", "1", "--blur", "3", "-o", "o.png"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("warning"));
}

#[test]
fn empty_images() {
    let s = Scene::new();
    let raw = |name: &str, shape: &[u64]| {
        use npyz::WriterBuilder;
        let mut buf = Vec::new();
        let mut w = npyz::WriteOptions::<f32>::new().default_dtype().shape(shape).writer(&mut buf).begin_nd().unwrap();
        w.extend(std::iter::empty::<f32>()).unwrap();
        w.finish().unwrap();
        std::fs::write(s.path(name), buf).unwrap();
    };
    raw("empty_layer.npy", &[0, 0, 5]);
    raw("empty_img.npy", &[0, 0, 3]);
    raw("empty_depth.npy", &[0, 4]);
    s.bad(&["--layer", "empty_layer.npy", "--focus", "0", "-o", "o.npy"], &["empty_layer.npy"]);
    s.bad(&["empty_img.npy", "--depth", "depth.exr", "--focus", "0", "-o", "o.npy"], &["empty_img.npy"]);
    s.bad(&["image.png", "--depth", "empty_depth.npy", "--focus", "0", "-o", "o.npy"], &["empty_depth.npy"]);
    // A PNG header declaring 0x0 pixels.
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let ihdr = [0u8, 0, 0, 0, 0, 0, 0, 0, 8, 2, 0, 0, 0];
    png.extend_from_slice(&(ihdr.len() as u32).to_be_bytes());
    let mut chunk = b"IHDR".to_vec();
    chunk.extend_from_slice(&ihdr);
    png.extend_from_slice(&chunk);
    png.extend_from_slice(&crc32(&chunk).to_be_bytes());
    std::fs::write(s.path("zero.png"), &png).unwrap();
    s.bad(&["zero.png", "--depth", "depth.exr", "--focus", "0", "-o", "o.npy"], &["zero.png"]);
}

#[test]
fn matte_with_wrong_size() {
    let s = Scene::new();
    io::write_png(&s.path("tall.png"), &Image::filled(H, W, 1, 1.0), 8, Transfer::Linear).unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--matte", "tall.png", "--focus", "1", "--blur", "3", "-o", "o.png"], &["tall.png"]);
    // Same aspect at half size is resized with a warning.
    io::write_png(&s.path("halfm.png"), &matte_map(W / 2, H / 2), 8, Transfer::Linear).unwrap();
    let out = s.run(&["image.png", "--depth", "depth.exr", "--matte", "halfm.png", "--focus", "1", "--blur", "3", "-o", "o.png"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("halfm.png"));
}

#[test]
fn bad_flag_values() {
    let s = Scene::new();
    let base = ["image.png", "--depth", "depth.exr", "-o", "o.png"];
    let with = |extra: &[&'static str]| -> Vec<&'static str> {
        let mut a = base.to_vec();
        a.extend_from_slice(extra);
        a
    };
    s.bad(&with(&["--focus", "1", "--lens", "4"]), &["--lens"]);
    s.bad(&with(&["--focus", "1", "--lens", "0"]), &["--lens"]);
    s.bad(&with(&["--focus", "1", "--blur", "-1"]), &["--blur"]);
    s.bad(&with(&["--focus", "1", "--blur", "nan"]), &["--blur"]);
    s.bad(&with(&["--focus", "1", "--blur", "abc"]), &["--blur"]);
    s.bad(&with(&["--focus", "nan"]), &["--focus"]);
    s.bad(&with(&["--focus", "1", "--layers", "0"]), &["--layers"]);
    s.bad(&with(&["--focus", "1", "--layers", "9"]), &["--layers"]);
    s.bad(&with(&["--focus", "1", "--layers", "many"]), &["--layers"]);
    s.bad(&with(&["--focus", "1", "--gamma", "0"]), &["--gamma"]);
    s.bad(&with(&["--focus-at", "32,5"]), &["--focus-at"]);
    s.bad(&with(&["--focus-at", "5,24"]), &["--focus-at"]);
    s.bad(&with(&["--focus-at", "3"]), &["--focus-at"]);
    s.bad(&with(&["--focus-depth", "0"]), &["--focus-depth"]);
    s.bad(&with(&["--focus-depth", "inf"]), &["--focus-depth"]);
    // Two focus flags at once.
    s.bad(&with(&["--focus", "1", "--focus-depth", "2"]), &["--focus"]);
    // No focus flag at all: clap usage error.
    s.bad(&base, &["--focus"]);
    // Missing --depth.
    s.bad(&["image.png", "--focus", "1", "-o", "o.png"], &["--depth"]);
    // Focus out of [0, 1] is clamped with a warning, not refused.
    let out = s.run(&with(&["--focus", "1.5", "--blur", "2"]));
    assert!(out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("clamped"));
}

/// Negative numbers given to flags that take numbers must be reported against the flag, like
/// `--blur -1` and `--focus -1` are.
#[test]

fn negative_values_name_their_flag() {
    let s = Scene::new();
    let base = ["image.png", "--depth", "depth.exr", "-o", "o.png"];
    for (extra, flag) in [
        (vec!["--focus", "1", "--gamma", "-2"], "--gamma"),
        (vec!["--focus", "1", "--lens", "-3"], "--lens"),
        (vec!["--focus-depth", "-2"], "--focus-depth"),
        (vec!["--focus-at", "-1,3"], "--focus-at"),
    ] {
        let mut a = base.to_vec();
        a.extend(extra);
        s.bad(&a, &[flag]);
    }
}

#[test]
fn output_equal_to_an_input_is_refused() {
    let s = Scene::new();
    let before = std::fs::read(s.path("image.png")).unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "image.png"], &["image.png"]);
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "./image.png"], &["image.png"]);
    let abs = s.path("image.png");
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", abs.to_str().unwrap()], &["image.png"]);
    s.bad(&["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "depth.exr"], &["depth.exr"]);
    s.bad(&["image.png", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "3", "-o", "matte.png"], &["matte.png"]);
    let (fg, bg) = scene_layers();
    io::save_npy(&s.path("fg.npy"), &fg).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    s.bad(&["--layer", "fg.npy", "--layer", "bg.npy", "--focus", "0", "--blur", "3", "-o", "bg.npy"], &["bg.npy"]);
    assert_eq!(std::fs::read(s.path("image.png")).unwrap(), before, "the input must be unchanged");
}

#[test]
fn output_in_a_missing_folder() {
    let s = Scene::new();
    let err = s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "nope/out.png"], &["nope"]);
    assert!(err.contains("out.png"), "{err}");
    assert!(!s.path("nope").exists());
}

// ---------------------------------------------------------------------------------------------
// Input variants, threads, links
// ---------------------------------------------------------------------------------------------

#[test]
fn input_variants() {
    let s = Scene::new();
    let rgb = texture(W, H, 1);
    // 16-bit PNG photo, JPEG photo.
    io::write_png(&s.path("img16.png"), &rgb, 16, Transfer::Srgb).unwrap();
    let q8: Vec<u8> = rgb.data.iter().map(|&v| (drbokeh::color::linear_to_srgb(v) * 255.0).round() as u8).collect();
    image::RgbImage::from_raw(W as u32, H as u32, q8).unwrap().save(s.path("img.jpg")).unwrap();
    // Depth as 16-bit PNG (z / 65535 in (0, 1]), as 16-bit TIFF and as NPY H x W.
    let z = depth_map(W, H);
    let z16: Vec<u16> = z.data.iter().map(|&v| (v / 4.0 * 65535.0).round() as u16).collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(W as u32, H as u32, z16.clone()).unwrap().save(s.path("d16.png")).unwrap();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(W as u32, H as u32, z16).unwrap().save(s.path("d16.tif")).unwrap();
    io::save_npy(&s.path("d.npy"), &z).unwrap();
    // Matte as the alpha of an RGBA PNG.
    let m = matte_map(W, H);
    let rgba: Vec<u8> = m.data.iter().flat_map(|&a| [200, 10, 10, (a * 255.0) as u8]).collect();
    image::RgbaImage::from_raw(W as u32, H as u32, rgba).unwrap().save(s.path("matte_rgba.png")).unwrap();

    let mut prev: Option<Vec<f32>> = None;
    for depth in ["depth.exr", "d16.png", "d16.tif", "d.npy"] {
        let j = s.json(&["img16.png", "--depth", depth, "--matte", "matte_rgba.png", "--focus-at", "15,11", "--blur", "4", "-o", "v.npy"]);
        assert!((f64_of(&j["params"]["focus"]) - 1.0).abs() < 1e-5, "{depth}: {j}");
        assert_eq!(j["params"]["layers"], 2, "{depth}: {j}");
        let out = read_npy(&s.path("v.npy"));
        // Every depth format gives the same disparity, hence the same picture.
        if let Some(p) = &prev {
            let e = max_abs_diff(p, &out.data);
            assert!(e < 1e-4, "{depth} renders differently ({e})");
        }
        prev = Some(out.data);
    }
    s.ok(&["img.jpg", "--depth", "d16.png", "--focus", "1", "--blur", "4", "-o", "j.png"]);
    assert!(s.path("j.png").is_file());
}

#[test]
fn threads_flag_gives_the_same_result() {
    let s = Scene::new();
    // The scene's render of `photo` into `out`, at `threads` when given (else all cores).
    let args = |photo: &'static str, threads: Option<&'static str>, out: &'static str| {
        let mut a = vec![photo, "--depth", "depth.exr", "--matte", "matte.png", "--focus", "0", "--blur", "5", "-o", out];
        a.extend(threads.map(|t| ["--threads", t]).into_iter().flatten());
        a
    };
    let j = s.json(&args("image.exr", Some("1"), "t1.npy"));
    assert_eq!(j["params"]["threads"], 1, "{j}");
    s.ok(&args("image.exr", None, "tn.npy"));
    assert_eq!(read_npy(&s.path("t1.npy")).data, read_npy(&s.path("tn.npy")).data);
    // The 8-bit PNG of an 8-bit photo (highlights stage, parallel fills, the parallel PNG
    // encoder) byte for byte at 1, 3 and 5 threads (issue 39).
    let png = |threads: &'static str, out: &'static str| {
        s.ok(&args("image.png", Some(threads), out));
        std::fs::read(s.path(out)).unwrap()
    };
    let one = png("1", "t1.png");
    assert!(one == png("3", "t3.png") && one == png("5", "t5.png"), "the PNG differs between thread counts");
}

#[cfg(unix)]
#[test]
fn output_symlinked_to_an_input_is_refused() {
    let s = Scene::new();
    std::os::unix::fs::symlink(s.path("image.png"), s.path("link.png")).unwrap();
    s.bad(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "link.png"], &["link.png"]);
}

/// `--save-layers` asks for the layered representation. When nothing is out of focus the
/// pipeline skips layering: it must then either still write the layers or say why it did not.
#[test]

fn save_layers_when_nothing_is_rendered() {
    let s = Scene::new();
    let out = s.run(&[
        "image.png",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "0",
        "--save-layers",
        "L",
        "-o",
        "o.png",
    ]);
    assert!(out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let wrote = s.path("L/0_fg.exr").is_file() && s.path("L/1_bg.exr").is_file();
    assert!(wrote || err.contains("layers"), "no layers in L/ ({:?}) and no warning: {err}", s.files());
}

/// Garbage behind each format's magic bytes, and truncations of real files, as every kind of
/// input: always exit 2 naming the file, never a panic or exit 1.
#[test]
fn corrupt_files_behind_valid_magic() {
    let s = Scene::new();
    let (fg, _) = scene_layers();
    io::save_npy(&s.path("good_layer.npy"), &fg).unwrap();
    io::write_exr(&s.path("good_layer.exr"), &fg, &["R", "G", "B", "A", "D"]).unwrap();
    io::save_npy(&s.path("good_depth.npy"), &depth_map(W, H)).unwrap();
    let mut rng = Rng::new(77);
    let mut cases: Vec<(String, Vec<u8>)> = Vec::new();
    let magics: [(&str, &[u8]); 5] = [
        ("png", b"\x89PNG\r\n\x1a\n"),
        ("jpg", &[0xFF, 0xD8, 0xFF, 0xE0]),
        ("tif", b"II*\0"),
        ("exr", &[0x76, 0x2F, 0x31, 0x01]),
        ("npy", b"\x93NUMPY"),
    ];
    for (ext, magic) in magics {
        let mut bytes = magic.to_vec();
        bytes.extend((0..300).map(|_| (rng.next_f32() * 256.0) as u8));
        cases.push((format!("junk.{ext}"), bytes));
    }
    for good in ["image.png", "image.exr", "depth.exr", "good_layer.npy", "good_layer.exr", "good_depth.npy"] {
        let full = std::fs::read(s.path(good)).unwrap();
        for (i, frac) in [0.1, 0.5, 0.9].into_iter().enumerate() {
            let ext = Path::new(good).extension().unwrap().to_str().unwrap();
            cases.push((format!("cut{i}_{}.{ext}", good.replace('.', "_")), full[..(full.len() as f64 * frac) as usize].to_vec()));
        }
    }
    for (name, bytes) in &cases {
        std::fs::write(s.path(name), bytes).unwrap();
    }
    for (name, _) in &cases {
        let n = name.as_str();
        s.bad(&[n, "--depth", "depth.exr", "--focus", "1", "--blur", "2", "-o", "o.png"], &[n]);
        s.bad(&["image.png", "--depth", n, "--focus", "1", "--blur", "2", "-o", "o.png"], &[n]);
        s.bad(&["image.png", "--depth", "depth.exr", "--matte", n, "--focus", "1", "--blur", "2", "-o", "o.png"], &[n]);
        s.bad(&["--layer", n, "--focus", "1", "--blur", "2", "-o", "o.png"], &[n]);
    }
}

/// A PNG whose header declares `w × h` RGB pixels, followed by a few bytes of image data
/// (far too few to decode).
fn png_header_only(w: u32, h: u32) -> Vec<u8> {
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    for (name, data) in [(&b"IHDR"[..], &ihdr[..]), (b"IDAT", &[0x78, 0x9c, 0, 0][..])] {
        png.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let mut chunk = name.to_vec();
        chunk.extend_from_slice(data);
        png.extend_from_slice(&chunk);
        png.extend_from_slice(&crc32(&chunk).to_be_bytes());
    }
    png
}

/// Issue 10: every size a user gives is bounded by what the image or the machine can use, and
/// cheap checks come before decoding: exit 2 with a message naming the flag or file.
#[test]
fn sizes_are_bounded_and_checked_before_work() {
    let s = Scene::new();
    let base = ["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "4"];
    let with = |extra: &[&'static str]| -> Vec<&'static str> { base.iter().copied().chain(extra.iter().copied()).collect() };
    // A 32x24 image can use a window of at most 2·40 + 1 = 81.
    s.ok(&with(&["--lens", "81", "-o", "l81.png"]));
    let e = s.bad(&with(&["--lens", "100001", "-o", "o.png"]), &["--lens", "100001", "81"]);
    assert!(!e.contains("render.lens"), "{e}");
    s.bad(&with(&["--lens", "83", "-o", "o.png"]), &["--lens"]);
    s.bad(&with(&["--threads", "100000", "-o", "o.png"]), &["--threads", "100000"]);
    s.bad(&with(&["--threads", "0", "-o", "o.png"]), &["--threads"]);
    // The output folder is checked before a (here undecodable) photo is read.
    std::fs::write(s.path("broken.png"), b"\x89PNG\r\n\x1a\nnot really").unwrap();
    s.bad(&["broken.png", "--depth", "depth.exr", "--focus", "1", "-o", "missing/o.png"], &["missing"]);
    // A depth map of another aspect ratio is refused from its header, before decoding.
    std::fs::write(s.path("tall_header.png"), png_header_only(24, 32)).unwrap();
    s.bad(&["image.png", "--depth", "tall_header.png", "--focus", "1", "-o", "o.png"], &["tall_header.png", "aspect"]);
    // So is a matte (reliability.md: "depth map and matte"): its header alone says it all.
    s.bad(
        &["image.png", "--depth", "depth.exr", "--matte", "tall_header.png", "--focus", "1", "-o", "o.png"],
        &["tall_header.png", "aspect"],
    );
    // bench frames are bounded too.
    let mut bench = common::drbokeh(s.dir.path());
    bench.args(["bench", "--size", "100000x100000", "--out", "b"]);
    common::assert_usage_error(s.dir.path(), "drbokeh bench --size 100000x100000", &["--size"], || common::run(bench));
    // reliability.md: "bench --size sides 16–4096", both ends.
    for size in ["15x64", "64x4097"] {
        let mut bench = common::drbokeh(s.dir.path());
        bench.args(["bench", "--size", size, "--out", "b"]);
        common::assert_usage_error(s.dir.path(), &format!("drbokeh bench --size {size}"), &["--size", "16 to 4096"], || common::run(bench));
    }
}

/// Issue 10: a photo whose header declares more pixels than the memory available can render
/// is refused from its header (exit 2, naming the file and both sizes) instead of aborting
/// in an allocation. The limit is an address-space ulimit of 3 GB; the header says 10000 x
/// 10000 (about 12 GB to render).
#[cfg(target_os = "linux")]
#[test]
fn a_photo_that_cannot_fit_in_memory_is_refused_before_decoding() {
    let s = Scene::new();
    std::fs::write(s.path("huge.png"), png_header_only(10_000, 10_000)).unwrap();
    io::write_exr(&s.path("huge_depth.exr"), &Image::filled(100, 100, 1, 2.0), &["Z"]).unwrap();
    let before = snapshot(s.dir.path());
    let bin = env!("CARGO_BIN_EXE_drbokeh");
    let out = Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v 3000000 && exec '{bin}' render huge.png --depth huge_depth.exr --focus 1 -o o.png"))
        .current_dir(s.dir.path())
        .env("RAYON_NUM_THREADS", "2")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("huge.png") && err.contains("memory") && err.contains("GB"), "{err}");
    assert_eq!(before, snapshot(s.dir.path()));
}

// ---------------------------------------------------------------------------------------------
// Silent acceptance of broken data (issue 10)

/// A JPEG cut short renders as grey in the decoder; the CLI refuses it as a photo and as a
/// depth map (exit 2, naming the file and the truncation).
#[test]
fn truncated_jpeg_inputs_are_refused() {
    let s = Scene::new();
    let mut f = std::fs::File::create(s.path("photo.jpg")).unwrap();
    let rgb = image::RgbImage::from_fn(W as u32, H as u32, |x, y| image::Rgb([x as u8 * 7, y as u8 * 9, 100]));
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut f, 90).encode_image(&rgb).unwrap();
    drop(f);
    s.ok(&["photo.jpg", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "-o", "ok.png"]);
    let full = std::fs::read(s.path("photo.jpg")).unwrap();
    std::fs::write(s.path("cut.jpg"), &full[..full.len() - 40]).unwrap();
    s.bad(&["cut.jpg", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "-o", "o.png"], &["cut.jpg", "truncated JPEG"]);
    s.bad(&["image.png", "--depth", "cut.jpg", "--focus", "1", "--blur", "2", "-o", "o.png"], &["cut.jpg", "truncated JPEG"]);
}

/// A FIFO (or a character device) given as any input is refused at once, not opened: opening
/// a FIFO for reading would block until a writer comes.
#[cfg(unix)]
#[test]
fn fifo_and_device_inputs_are_refused_without_blocking() {
    let s = Scene::new();
    // Outside the scene folder: `Scene::bad` reads every file there to check nothing changed.
    let other = tempfile::tempdir().unwrap();
    let fifo = other.path().join("pipe.exr");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    let (fifo, limit) = (fifo.to_str().unwrap(), Duration::from_secs(20));
    io::save_npy(&s.path("bg.npy"), &scene_layers().1).unwrap();
    for (special, kind) in [(fifo, "FIFO"), ("/dev/null", "character device")] {
        let n = [special, "not a regular file", kind];
        s.bad_within(&[special, "--depth", "depth.exr", "--focus", "1", "--blur", "2", "-o", "o.png"], &n, limit);
        s.bad_within(&["image.png", "--depth", special, "--focus", "1", "--blur", "2", "-o", "o.png"], &n, limit);
        s.bad_within(&["image.png", "--depth", "depth.exr", "--matte", special, "--focus", "1", "--blur", "2", "-o", "o.png"], &n, limit);
        s.bad_within(&["--layer", special, "--layer", "bg.npy", "--focus", "0", "--blur", "2", "-o", "o.png"], &n, limit);
        s.bad_within(&["image.png", "--depth", "depth.exr", "--focus", "1", "--config", special, "-o", "o.png"], &n, limit);
    }
    // The batch manifest.
    let mut batch = common::drbokeh(s.dir.path());
    let out_dir = other.path().join("out");
    batch.args(["batch", s.dir.path().to_str().unwrap(), "-o", out_dir.to_str().unwrap(), "--focus", "0", "--manifest", fifo]);
    // The scene folder stays as it was (the FIFO's folder cannot be read to check).
    common::assert_usage_error(s.dir.path(), "drbokeh batch --manifest FIFO", &["pipe.exr", "FIFO"], || run_within(batch, limit));
}

/// An 8-bit depth map renders, with a precision warning naming the file on stderr and in
/// `--json`'s warnings; a float depth map gets none.
#[test]
fn eight_bit_depth_map_warns() {
    let s = Scene::new();
    let mut d8 = depth_map(W, H);
    d8.map_inplace(|z| z / 4.0);
    io::write_png(&s.path("depth8.png"), &d8, 8, Transfer::Linear).unwrap();
    let args = ["image.png", "--depth", "depth8.png", "--focus", "1", "--blur", "3", "-o", "o.png"];
    let out = s.run(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("warning: ") && err.contains("depth8.png") && err.contains("8-bit depth map"), "{err}");
    let j = s.json(&args);
    let warnings: Vec<&str> = j["warnings"].as_array().unwrap().iter().filter_map(|w| w.as_str()).collect();
    assert!(warnings.iter().any(|w| w.contains("depth8.png") && w.contains("256 depth levels")), "{j}");
    let j = s.json(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "o.png"]);
    assert!(!j["warnings"].to_string().contains("depth levels"), "{j}");
}

/// Layer alpha outside [0, 1] is used as stored but warned about (stderr and `--json`).
#[test]
fn layer_alpha_outside_unit_range_warns() {
    let s = Scene::new();
    let (mut fg, bg) = scene_layers();
    fg.pixel_mut(12, 9)[3] = 1.75;
    io::save_npy(&s.path("hot.npy"), &fg).unwrap();
    io::save_npy(&s.path("bg.npy"), &bg).unwrap();
    let args = ["--layer", "hot.npy", "--layer", "bg.npy", "--focus", "0", "--blur", "3", "-o", "o.png"];
    let out = s.run(&args);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("warning: ") && err.contains("hot.npy") && err.contains("alpha") && err.contains("1.75"), "{err}");
    let j = s.json(&args);
    assert!(j["warnings"].to_string().contains("hot.npy"), "{j}");
    let j = s.json(&["--layer", "bg.npy", "--focus", "0", "--blur", "3", "-o", "o.png"]);
    assert!(!j["warnings"].to_string().contains("alpha"), "{j}");
}

/// DESIGN.md's stability rule (finite output for every finite input) at the top of f32's range:
/// a layer of the largest finite colour (f32::MAX; its sums overflowed the official profile's
/// fast kernel, which then refused the render with exit 1) renders with every profile and
/// kernel, and a uniform colour stays that colour (relative 1e-5).
#[test]
fn the_largest_finite_colours_render_finite() {
    let s = Scene::new();
    let layer = Image::from_vec(W, H, 5, (0..W * H).flat_map(|i| [f32::MAX, f32::MAX, f32::MAX, 1.0, (i % W) as f32 / W as f32]).collect())
        .unwrap();
    io::save_npy(&s.path("huge.npy"), &layer).unwrap();
    for profile in ["official", "physical"] {
        for kernel in ["fast", "exact"] {
            let what = format!("--profile {profile} --kernel {kernel}");
            s.ok(&["--layer", "huge.npy", "--focus", "0", "--blur", "6", "--profile", profile, "--kernel", kernel, "-o", "o.npy"]);
            let out = read_npy(&s.path("o.npy"));
            for &v in &out.data {
                assert!(v.is_finite() && (v / f32::MAX - 1.0).abs() < 1e-5, "{what}: {v}");
            }
        }
    }
}

/// reliability.md ("unbounded sizes"): the exact kernel announces a render of more than a
/// minute, with its estimated duration, before it starts. A 300x300 layer through an 801-wide
/// window on one thread is estimated at some 11 minutes: the warning must come while the
/// render runs (the test stops it once the warning is read, or after 60 s without it).
#[test]
fn a_long_exact_render_is_announced_before_it_starts() {
    use std::io::BufRead;
    let s = Scene::new();
    let n = 300;
    let layer = Image::from_vec(n, n, 5, (0..n * n).flat_map(|i| [0.5, 0.4, 0.3, 1.0, (i % n) as f32 / n as f32]).collect()).unwrap();
    io::save_npy(&s.path("big.npy"), &layer).unwrap();
    let mut child = drbokeh_cmd(
        s.dir.path(),
        &["--layer", "big.npy", "--focus", "0", "--blur", "300", "--kernel", "exact", "--lens", "801", "--threads", "1", "-o", "o.npy"],
    )
    .stderr(std::process::Stdio::piped())
    .spawn()
    .unwrap();
    let stderr = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let t0 = std::time::Instant::now();
    let mut seen = Vec::new();
    let announced = loop {
        match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(line) if line.contains("exact kernel will take about") => break Some(line),
            Ok(line) => seen.push(line),
            Err(std::sync::mpsc::RecvTimeoutError::Timeout) if t0.elapsed() < Duration::from_secs(60) => {}
            Err(_) => break None,
        }
    };
    let finished = child.try_wait().unwrap();
    let _ = child.kill();
    let _ = child.wait();
    let line = announced.unwrap_or_else(|| panic!("no announcement within 60 s; stderr: {seen:?}"));
    assert!(finished.is_none(), "the render was over before its announcement was read: {line}");
    assert!(line.contains("minutes") && line.contains("300x300"), "{line}");
}

/// Issue 10: an interrupted `render` left `.NAME.PID-NONCE.drbokeh-tmp` beside its output.
/// SIGINT arrives while the output is being written (the temporary file exists): the command
/// exits 130 and leaves neither the temporary file nor an output. The write of a 16-bit PNG of
/// a 4-megapixel noisy image takes far longer than the 1 ms poll; should the write still win
/// the race, the attempt is repeated.
#[cfg(unix)]
#[test]
fn interrupted_render_removes_its_temporary_file() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path();
    let (w, h) = (2400, 1800);
    io::write_png(&p.join("big.png"), &texture(w, h, 7), 8, Transfer::Srgb).unwrap();
    io::write_exr(&p.join("flat.exr"), &Image::filled(w, h, 1, 4.0), &["Z"]).unwrap();
    let temps = || list_files(p).into_iter().filter(|f| f.ends_with(".drbokeh-tmp")).collect::<Vec<_>>();
    for _attempt in 0..5 {
        let mut child = common::drbokeh(p)
            .args(["render", "big.png", "--depth", "flat.exr", "--focus", "0.5", "--blur", "0", "--bit-depth", "16", "-o", "out.png"])
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let t0 = std::time::Instant::now();
        while temps().is_empty() && child.try_wait().unwrap().is_none() && t0.elapsed().as_secs() < 60 {
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        if child.try_wait().unwrap().is_some() {
            // Finished before its output was seen being written: try again.
            let _ = std::fs::remove_file(p.join("out.png"));
            continue;
        }
        assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        if out.status.success() {
            let _ = std::fs::remove_file(p.join("out.png"));
            continue;
        }
        assert_eq!(out.status.code(), Some(130), "{err}");
        assert!(temps().is_empty(), "temporary files left: {:?}", list_files(p));
        assert!(!p.join("out.png").exists());
        assert!(!err.contains("panicked"), "{err}");
        return;
    }
    panic!("the render never got interrupted while writing (5 attempts)");
}

/// Issue 10: a flag that cannot apply to the chosen output says so instead of being ignored.
#[test]
fn bit_depth_with_a_float_output_warns() {
    let s = Scene::new();
    let out = s.run(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "--bit-depth", "16", "-o", "o.exr"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("warning:") && err.contains("bit depth of 16") && err.contains("o.exr"), "{err}");
    let out = s.run(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "--bit-depth", "16", "-o", "o.png"]);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("bit depth"));
    // And -v keeps the line saying where the result went.
    let out = s.run(&["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "2", "-v", "-o", "v.png"]);
    assert!(String::from_utf8_lossy(&out.stderr).contains("wrote v.png"));
}

/// Issue 11: `--profile physical` renders with either kernel; in focus it returns the photo
/// unchanged.
#[test]
fn physical_profile_from_the_command_line() {
    let s = Scene::new();
    let j = s.json(&["image.exr", "--depth", "depth.exr", "--focus", "1", "--blur", "4", "--profile", "physical", "-o", "f.npy"]);
    assert!(j["warnings"].as_array().unwrap().is_empty(), "{j}");
    assert!(read_npy(&s.path("f.npy")).all_finite());
    let j = s.json(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "4",
        "--profile",
        "physical",
        "--kernel",
        "exact",
        "-o",
        "p.npy",
    ]);
    assert!(j["warnings"].as_array().unwrap().is_empty(), "{j}");
    let out = read_npy(&s.path("p.npy"));
    assert!(out.all_finite());
    // Blur 0 on one opaque layer: every pixel is in focus, the output is the input, bit for bit.
    let rgb = texture(W, H, 3);
    let mut l = Image::new(W, H, 5);
    for (o, c) in l.data.chunks_exact_mut(5).zip(rgb.data.chunks_exact(3)) {
        o.copy_from_slice(&[c[0], c[1], c[2], 1.0, 0.5]);
    }
    io::save_npy(&s.path("one.npy"), &l).unwrap();
    s.ok(&["--layer", "one.npy", "--focus", "1", "--blur", "0", "--profile", "physical", "--kernel", "exact", "-o", "same.npy"]);
    assert!(read_npy(&s.path("same.npy")).data == rgb.data, "blur 0 changed the layer");
    s.ok(&["--layer", "one.npy", "--focus", "1", "--blur", "0", "--profile", "physical", "-o", "same-fast.npy"]);
    assert!(read_npy(&s.path("same-fast.npy")).data == rgb.data, "blur 0 changed the layer (fast kernel)");
}

#[test]
fn inpaint_patchmatch_from_flag_and_config() {
    let s = Scene::new();
    let base = ["image.exr", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "0", "--blur", "5"];
    let j = s.json(&[&base[..], &["--inpaint", "patchmatch", "--threads", "1", "-o", "p1.npy"]].concat());
    let inpaint = &stage(&j, "inpaint")["detail"];
    assert_eq!(inpaint["method"], "patchmatch", "{j}");
    assert!(inpaint["filled_px"].as_u64().unwrap() > 0, "{j}");
    std::fs::write(s.path("pm.toml"), "[inpaint]\nmethod = \"patchmatch\"\n").unwrap();
    s.ok(&[&base[..], &["--config", "pm.toml", "-o", "pn.npy"]].concat());
    s.ok(&[&base[..], &["-o", "t.npy"]].concat());
    let (p1, pn, t) = (read_npy(&s.path("p1.npy")), read_npy(&s.path("pn.npy")), read_npy(&s.path("t.npy")));
    assert!(p1.all_finite());
    // The same result from the config and with any thread count; not Telea's.
    assert_eq!(p1.data, pn.data);
    assert!(max_abs_diff(&p1.data, &t.data) > 0.0);
}

// ---------------------------------------------------------------------------------------------
// Reliability round 3: destinations, the edge band, flat depth, silent surprises
// ---------------------------------------------------------------------------------------------

/// The standard render's arguments with `extra` after them.
fn render_args<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec!["image.png", "--depth", "depth.exr", "--matte", "matte.png", "--focus", "1", "--blur", "3"];
    a.extend_from_slice(extra);
    a
}

/// `-o` over a file `--save-layers` writes in the same run, by any spelling, is refused before
/// anything is written; so is a `--save-layers` that is an existing file.
#[test]
fn output_over_a_saved_layer_is_refused() {
    let s = Scene::new();
    for out in ["L/0_fg.exr", "L/0_fg_color.png", "L/1_bg.exr"] {
        s.bad(&render_args(&["--save-layers", "L", "-o", out]), &[out, "--save-layers", "same file"]);
    }
    s.bad(&render_args(&["--layers", "3", "--save-layers", "L", "-o", "L/2_layer.exr"]), &["L/2_layer.exr", "--save-layers"]);
    // The folder exists already: any spelling of it.
    std::fs::create_dir(s.path("L")).unwrap();
    for out in ["L/0_fg_alpha.png", "./L/../L/1_bg_disparity.png"] {
        s.bad(&render_args(&["--save-layers", "L", "-o", out]), &[out, "--save-layers"]);
    }
    std::fs::write(s.path("F"), b"a file").unwrap();
    s.bad(&render_args(&["--save-layers", "F", "-o", "o.png"]), &["F", "--save-layers", "folder"]);
}

/// A second `--save-layers` run into the same folder with another layer count leaves only its
/// own layers there (README's `--layer DIR/*.exr` idiom must render this run's layers), says
/// what it removed, and leaves other files alone.
#[test]
fn save_layers_clears_an_earlier_runs_layers() {
    let s = Scene::new();
    s.ok(&render_args(&["--layers", "1", "--save-layers", "L", "-o", "one.png"]));
    assert!(s.path("L/0_bg.exr").exists());
    std::fs::write(s.path("L/notes.txt"), b"mine").unwrap();
    let out = s.run(&render_args(&["--save-layers", "L", "-o", "two.png"]));
    assert!(out.status.success(), "{}", common::stderr(&out));
    let err = common::stderr(&out);
    assert!(err.contains("removed") && err.contains("0_bg.exr"), "{err}");
    let left = list_files(&s.path("L"));
    let want: BTreeSet<String> = ["0_fg", "1_bg"]
        .iter()
        .flat_map(|l| [".exr", "_color.png", "_alpha.png", "_disparity.png"].map(|e| format!("{l}{e}")))
        .chain(["notes.txt".to_string()])
        .collect();
    assert_eq!(left, want);
    // The saved layers render as the run did.
    s.ok(&["--layer", "L/0_fg.exr", "--layer", "L/1_bg.exr", "--focus", "1", "--blur", "3", "-o", "again.png"]);
    let (a, b) = (
        io::read_decoded(&s.path("two.png"), &ReadLimits::default()).unwrap(),
        io::read_decoded(&s.path("again.png"), &ReadLimits::default()).unwrap(),
    );
    assert!(max_abs_diff(&a.image.data, &b.image.data) <= 1.5 / 255.0);
}

/// A flat depth map (one value everywhere) is one plane: it is in focus at the focus asked
/// for, the photo comes back unchanged, and a warning names the file.
#[test]
fn flat_depth_map_is_one_plane_in_focus() {
    let s = Scene::new();
    io::write_exr(&s.path("flat.exr"), &Image::filled(W, H, 1, 2.5), &["Z"]).unwrap();
    let photo = read_exr(&s.path("image.exr"));
    for extra in [&[][..], &["--kernel", "exact"], &["--matte", "matte.png"]] {
        let mut a = vec!["image.exr", "--depth", "flat.exr", "--focus", "1", "--blur", "4", "-o", "o.exr"];
        a.extend_from_slice(extra);
        let j = s.json(&a);
        let warned = j["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("flat.exr has no depth range"));
        assert!(warned, "{a:?}: {}", j["warnings"]);
        let d = max_abs_diff(&read_exr(&s.path("o.exr")).data, &photo.data);
        assert!(d < 1e-5, "{a:?}: the flat scene was blurred (max difference {d})");
    }
}

/// Euclidean distance from (x, y) to the nearest pixel of the foreground square.
fn distance_to_fg(x: usize, y: usize) -> f32 {
    let dx = (FG_X.start as f32 - x as f32).max(x as f32 - (FG_X.end - 1) as f32).max(0.0);
    let dy = (FG_Y.start as f32 - y as f32).max(y as f32 - (FG_Y.end - 1) as f32).max(0.0);
    (dx * dx + dy * dy).sqrt()
}

/// In-focus background pixels come back as they were next to the subject: with a binary matte
/// the edge band is not re-synthesized at all, and with any matte no band pixel beyond the
/// foreground's blur changes while the background is in focus.
#[test]
fn in_focus_background_next_to_the_matte_is_unchanged() {
    let s = Scene::new();
    let photo = read_exr(&s.path("image.exr"));
    // A soft matte: the square, with a ring of 0.5 around it.
    let mut soft = matte_map(W, H);
    for y in 0..H {
        for x in 0..W {
            if !in_fg(x, y) && distance_to_fg(x, y) <= 1.0 {
                soft.data[y * W + x] = 0.5;
            }
        }
    }
    io::write_exr(&s.path("soft.exr"), &soft, &["Y"]).unwrap();
    let base = |matte: &'static str, extra: &[&'static str]| {
        let mut a = vec!["image.exr", "--depth", "depth.exr", "--matte", matte, "-o", "o.exr"];
        a.extend_from_slice(extra);
        a
    };
    // Everything in focus, rendered anyway: the photo back, and no band pixel replaced.
    let j = s.json(&base("matte.png", &["--focus", "0.5", "--blur", "0", "--kernel", "exact"]));
    assert_eq!(stage(&j, "inpaint")["detail"]["edge_band_replaced_px"], 0, "{j}");
    let d = max_abs_diff(&read_exr(&s.path("o.exr")).data, &photo.data);
    assert!(d < 1e-5, "blur 0 changed the photo by {d}");
    // The background in focus, the subject blurred by 1.5 px: pixels 2 px or more from the
    // subject see no blur and keep their colour exactly.
    for matte in ["matte.png", "soft.exr"] {
        for kernel in ["exact", "fast"] {
            s.ok(&base(matte, &["--focus", "0", "--blur", "1.5", "--kernel", kernel]));
            let out = read_exr(&s.path("o.exr"));
            for y in 0..H {
                for x in 0..W {
                    let reach = if matte == "soft.exr" { 3.0 } else { 2.0 };
                    if distance_to_fg(x, y) >= reach {
                        let (a, b) = (out.pixel(x, y), photo.pixel(x, y));
                        assert!(max_abs_diff(a, b) < 1e-5, "{matte} {kernel}: pixel ({x}, {y}) changed: {a:?} vs {b:?}");
                    }
                }
            }
        }
    }
}

/// An output that exists and is not a regular file is never replaced by one: a FIFO or a
/// character device is written through (a FIFO nobody reads is refused at once), a link
/// stays a link (its target gets the image), a folder or a link to nothing is refused.
#[test]
fn special_outputs_are_written_through_or_refused_never_replaced() {
    use std::os::unix::fs::FileTypeExt;
    let s = Scene::new();
    // Outside the scene folder: `Scene::bad` reads every file there.
    let other = tempfile::tempdir().unwrap();
    let fifo = other.path().join("pipe.png");
    assert!(Command::new("mkfifo").arg(&fifo).status().expect("mkfifo").success());
    let fifo_s = fifo.to_str().unwrap();
    let is_fifo = |p: &Path| std::fs::symlink_metadata(p).unwrap().file_type().is_fifo();
    s.bad_within(&render_args(&["-o", fifo_s]), &[fifo_s, "FIFO", "no process is reading"], Duration::from_secs(20));
    assert!(is_fifo(&fifo));
    // With a reader, the image streams through.
    let reader = {
        let fifo = fifo.clone();
        std::thread::spawn(move || std::fs::read(&fifo).unwrap())
    };
    // The reader opens the FIFO first (a writer that finds none is refused).
    let mut streamed = None;
    for _ in 0..200 {
        let out = s.run(&render_args(&["-o", fifo_s]));
        if out.status.success() {
            streamed = Some(reader.join().unwrap());
            break;
        }
        std::thread::sleep(Duration::from_millis(25));
    }
    let bytes = streamed.expect("never written through the FIFO");
    assert!(bytes.starts_with(b"\x89PNG"), "{} bytes, not a PNG", bytes.len());
    assert!(is_fifo(&fifo));
    // Standard output, a pipe here: the PNG comes out there.
    let piped = s.run(&render_args(&["-o", "/dev/stdout"]));
    assert!(piped.status.success(), "{}", common::stderr(&piped));
    assert!(piped.stdout.starts_with(b"\x89PNG"), "no PNG on standard output ({} bytes)", piped.stdout.len());
    // Character devices: written through, still devices.
    s.ok(&render_args(&["-o", "/dev/null"]));
    assert!(std::fs::metadata("/dev/null").unwrap().file_type().is_char_device());
    let full = s.run(&render_args(&["-o", "/dev/full"]));
    assert_ne!(full.status.code(), Some(0));
    assert!(common::stderr(&full).contains("/dev/full") && !common::stderr(&full).contains("panicked"));
    assert!(std::fs::metadata("/dev/full").unwrap().file_type().is_char_device());
    // A link to a regular file stays a link; its target is the image.
    std::fs::write(other.path().join("real.png"), b"old").unwrap();
    std::os::unix::fs::symlink(other.path().join("real.png"), s.path("link.png")).unwrap();
    std::os::unix::fs::symlink("/dev/null", s.path("null.png")).unwrap();
    s.ok(&render_args(&["-o", "link.png"]));
    s.ok(&render_args(&["-o", "null.png"]));
    for l in ["link.png", "null.png"] {
        assert!(std::fs::symlink_metadata(s.path(l)).unwrap().file_type().is_symlink(), "{l} was replaced");
    }
    assert!(std::fs::read(other.path().join("real.png")).unwrap().starts_with(b"\x89PNG"));
    // A folder, and a link to nothing.
    std::fs::create_dir(s.path("dir.png")).unwrap();
    s.bad(&render_args(&["-o", "dir.png"]), &["dir.png", "folder"]);
    let dangling = other.path().join("dangling.png");
    std::os::unix::fs::symlink(other.path().join("missing/x.png"), &dangling).unwrap();
    s.bad(&render_args(&["-o", dangling.to_str().unwrap()]), &["dangling.png", "does not exist"]);
    assert!(std::fs::symlink_metadata(&dangling).unwrap().file_type().is_symlink());
}

/// Negative numbers reach the option's own rule (clap took them for flags: "unexpected
/// argument '-1'"); a wrong `[segment] layers` in a config names the key and what it accepts.
#[test]
fn negative_counts_and_wrong_config_values_name_their_option() {
    let s = Scene::new();
    for (flag, v) in [("--threads", "-1"), ("--layers", "-1"), ("--quality", "-1"), ("--lens", "-1"), ("--threads", "0")] {
        let err = s.bad(&render_args(&[flag, v, "-o", "o.png"]), &[flag]);
        assert!(!err.contains("unexpected argument"), "{err}");
    }
    for v in ["-1", "2.5", "0", "\"x\""] {
        std::fs::write(s.path("c.toml"), format!("[segment]\nlayers = {v}\n")).unwrap();
        s.bad(&render_args(&["--config", "c.toml", "-o", "o.png"]), &["c.toml", "segment.layers", "1..=8"]);
    }
}

/// Writes `img` (values in [0, 1]) as a uint8 NPY array of its 8-bit sRGB codes, as
/// `numpy.save` of a decoded 8-bit photo would.
fn save_u8_npy(path: &Path, img: &Image) {
    let header = format!("{{'descr': '|u1', 'fortran_order': False, 'shape': ({}, {}, {}), }}", img.height, img.width, img.channels);
    let pad = 64 - (10 + header.len() + 1) % 64;
    let header = format!("{header}{}\n", " ".repeat(pad % 64));
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    bytes.extend(img.data.iter().map(|&v| (drbokeh::color::linear_to_srgb(v).clamp(0.0, 1.0) * 255.0).round() as u8));
    std::fs::write(path, bytes).unwrap();
}

/// A uint8 NPY photo holds what an 8-bit PNG holds and renders like one (it was read as linear
/// light 0-255, a blown-out render with exit 0).
#[test]
fn uint8_npy_photo_reads_as_an_8_bit_image() {
    let s = Scene::new();
    let png = io::read_decoded(&s.path("image.png"), &ReadLimits::default()).unwrap().image;
    let linear: Vec<f32> = png.data.iter().map(|&v| drbokeh::color::srgb_to_linear(v)).collect();
    save_u8_npy(&s.path("photo.npy"), &Image::from_vec(W, H, 3, linear).unwrap());
    s.ok(&render_args(&["-o", "from_png.exr"]));
    let mut a = render_args(&["-o", "from_npy.exr"]);
    a[0] = "photo.npy";
    s.ok(&a);
    let d = max_abs_diff(&read_exr(&s.path("from_png.exr")).data, &read_exr(&s.path("from_npy.exr")).data);
    assert!(d < 1e-5, "a uint8 NPY photo renders {d} away from the same PNG");
}

/// A photo's alpha channel is dropped with a warning when it is not opaque everywhere (a
/// cut-out subject belongs in `--matte`), and options that given layers or `--no-occlusion`
/// make meaningless are named as ignored.
#[test]
fn dropped_alpha_and_ignored_options_are_said() {
    let s = Scene::new();
    let rgb = texture(W, H, 1);
    let with_alpha = |a: f32| Image::stack(&[&rgb, &Image::filled(W, H, 1, a)]);
    io::write_png(&s.path("cut.png"), &with_alpha(0.5), 8, Transfer::Srgb).unwrap();
    io::write_png(&s.path("opaque.png"), &with_alpha(1.0), 8, Transfer::Srgb).unwrap();
    let warnings = |args: &[&str]| -> String { s.json(args)["warnings"].to_string() };
    let w = warnings(&["cut.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "o.png"]);
    assert!(w.contains("cut.png") && w.contains("alpha") && w.contains("--matte"), "{w}");
    let w = warnings(&["opaque.png", "--depth", "depth.exr", "--focus", "1", "--blur", "3", "-o", "o.png"]);
    assert!(!w.contains("alpha"), "{w}");
    let w = warnings(&render_args(&["--no-occlusion", "--inpaint", "patchmatch", "--layers", "3", "-o", "o.png"]));
    for flag in ["--inpaint is ignored", "--layers is ignored", "--matte is ignored", "--no-occlusion"] {
        assert!(w.contains(flag), "{flag}: {w}");
    }
    io::save_npy(&s.path("bg.npy"), &scene_layers().1).unwrap();
    let w = warnings(&["--layer", "bg.npy", "--layers", "auto", "--focus", "0", "--blur", "2", "-o", "o.png"]);
    assert!(w.contains("--layers is ignored") && w.contains("--layer)"), "{w}");
}

/// Issue 40's focus pull: the layers built once, every frame equal (bit for bit) to a single
/// render of those layers at the frame's focus and blur, for given layers (24 frames) and for
/// a photo (its layers written by --save-layers, a blur range, linear easing).
#[test]
fn a_focus_pull_equals_single_renders_of_its_layers() {
    let s = Scene::new();
    s.ok(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus",
        "1",
        "--blur",
        "5",
        "--save-layers",
        "L",
        "-o",
        "o.npy",
    ]);
    let layers = ["--layer", "L/0_fg.exr", "--layer", "L/1_bg.exr"];
    // As for one render, the frames' folder must exist (it is named when it does not).
    s.bad(&[layers.as_slice(), &["--focus-from", "0", "--focus-to", "1", "--frames", "2", "-o", "pull/%04d.npy"]].concat(), &["pull"]);
    std::fs::create_dir(s.path("pull")).unwrap();
    let mut a = layers.to_vec();
    a.extend(["--focus-from", "0.05", "--focus-to", "1", "--frames", "24", "--blur", "6", "-o", "pull/%04d.npy"]);
    let j = s.json(&a);
    let frames = j["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 24, "{j}");
    let foci: Vec<f64> = frames.iter().map(|f| f["focus"].as_f64().unwrap()).collect();
    assert!((foci[0] - 0.05).abs() < 1e-7 && foci[23] == 1.0, "{foci:?}");
    assert!(foci.windows(2).all(|w| w[1] > w[0]), "the focus moves one way: {foci:?}");
    // Smooth easing (the default): the first and last steps are the smallest.
    let steps: Vec<f64> = foci.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(steps[0] < steps[11] && steps[22] < steps[11], "{steps:?}");
    let mut distinct = 0;
    for (i, f) in frames.iter().enumerate() {
        let file = format!("pull/{i:04}.npy");
        assert_eq!(f["output"].as_str(), Some(file.as_str()));
        let mut one = layers.to_vec();
        let focus = f["focus"].as_f64().unwrap().to_string();
        one.extend(["--focus", &focus, "--blur", "6", "-o", "one.npy"]);
        s.ok(&one);
        let (got, want) = (read_npy(&s.path(&file)), read_npy(&s.path("one.npy")));
        assert!(got.data == want.data, "frame {i} (focus {focus}) differs from a single render");
        if i > 0 && read_npy(&s.path(&format!("pull/{:04}.npy", i - 1))).data != got.data {
            distinct += 1;
        }
    }
    assert!(distinct >= 20, "the frames barely change: {distinct} of 23 steps");

    // From the photo: built once (--save-layers writes what the frames render), a blur range.
    let j = s.json(&[
        "image.exr",
        "--depth",
        "depth.exr",
        "--matte",
        "matte.png",
        "--focus-from",
        "1",
        "--focus-to",
        "0.2",
        "--frames",
        "3",
        "--blur-from",
        "3",
        "--blur-to",
        "9",
        "--easing",
        "linear",
        "--save-layers",
        "P",
        "-o",
        "f%d.png",
    ]);
    let frames = j["frames"].as_array().unwrap();
    let got: Vec<(f64, f64)> = frames.iter().map(|f| (f["focus"].as_f64().unwrap(), f["blur"].as_f64().unwrap())).collect();
    for (g, w) in got.iter().zip([(1.0, 3.0), (0.6, 6.0), (0.2, 9.0)]) {
        assert!((g.0 - w.0).abs() < 1e-6 && (g.1 - w.1).abs() < 1e-5, "{got:?}");
    }
    for (i, f) in frames.iter().enumerate() {
        let (focus, blur) = (f["focus"].as_f64().unwrap().to_string(), f["blur"].as_f64().unwrap().to_string());
        s.ok(&["--layer", "P/0_fg.exr", "--layer", "P/1_bg.exr", "--focus", &focus, "--blur", &blur, "-o", "one.png"]);
        let (a, b) = (image::open(s.path(&format!("f{i}.png"))).unwrap(), image::open(s.path("one.png")).unwrap());
        assert!(a.to_rgb8() == b.to_rgb8(), "photo frame {i} differs from a single render of the saved layers");
    }
    // Bad pulls: exit 2 naming the flag, nothing written.
    s.bad(
        &["image.exr", "--depth", "depth.exr", "--focus-from", "0", "--focus-to", "1", "--frames", "3", "-o", "x.png"],
        &["--output", "%04d"],
    );
    s.bad(&["image.exr", "--depth", "depth.exr", "--focus-from", "0", "--focus-to", "1", "--frames", "0", "-o", "x%d.png"], &["--frames"]);
    s.bad(
        &["image.exr", "--depth", "depth.exr", "--focus-from", "0", "--focus-to", "1", "--frames", "2", "--focus", "1", "-o", "x%d.png"],
        &["--focus"],
    );
    s.bad(&["image.exr", "--depth", "depth.exr", "--focus-from", "0", "--frames", "2", "-o", "x%d.png"], &["--focus-to"]);
}

/// Issue 41: shell completions and the manual page, generated from the argument definitions;
/// the bash script sources cleanly and registers the completion.
#[test]
fn completions_and_the_manual_page() {
    let d = tempfile::tempdir().unwrap();
    let run = |args: &[&str]| {
        let mut c = common::drbokeh(d.path());
        c.args(args);
        let out = common::run(c);
        assert!(out.status.success(), "drbokeh {args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    for shell in ["bash", "zsh", "fish", "powershell", "elvish"] {
        let text = run(&["completions", shell]);
        assert!(text.contains("render") && text.contains("focus-at") && text.contains("view"), "{shell}: {}", &text[..text.len().min(300)]);
    }
    let bash = d.path().join("drbokeh.bash");
    std::fs::write(&bash, run(&["completions", "bash"])).unwrap();
    let out = Command::new("bash").arg("-c").arg(format!("source '{}' && complete -p drbokeh", bash.display())).output().unwrap();
    assert!(out.status.success() && String::from_utf8_lossy(&out.stdout).contains("drbokeh"), "{}", String::from_utf8_lossy(&out.stderr));
    let man = run(&["man"]);
    assert!(man.contains(".TH drbokeh 1") && man.contains("render") && man.contains("batch") && man.contains("inspect"), "{man}");
    let out = common::run({
        let mut c = common::drbokeh(d.path());
        c.args(["completions", "tcsh"]);
        c
    });
    assert_eq!(out.status.code(), Some(2), "an unknown shell is a usage error");
}

/// `--aperture` / `--anamorphic` / `--chromatic` / `[aperture]`: the JSON names the shape, the shape changes
/// the picture, and every bad value exits 2 naming the flag or the file, writing nothing.
#[test]
fn aperture_shapes_and_their_bad_values() {
    let s = Scene::new();
    let base = ["image.png", "--depth", "depth.exr", "--focus", "1", "--blur", "12"];
    let with = |extra: &[&str], out: &str| -> Vec<String> { base.iter().chain(extra).chain(&["-o", out]).map(|a| a.to_string()).collect() };
    let args = with(&["--aperture", "blades:5,rotation=90,curvature=0.2"], "penta.png");
    let j = s.json(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert_eq!(j["params"]["aperture"], "blades:5,rotation=90,curvature=0.2");
    let disc = with(&[], "disc.png");
    assert_eq!(s.json(&disc.iter().map(String::as_str).collect::<Vec<_>>())["params"]["aperture"], "disc");
    std::fs::write(s.path("ap.toml"), "[aperture]\nshape = \"blades:6\"\nanamorphic = 1.5\n").unwrap();
    let cfg = with(&["--config", "ap.toml"], "hexa.png");
    assert_eq!(
        s.json(&cfg.iter().map(String::as_str).collect::<Vec<_>>())["params"]["aperture"],
        "blades:6,rotation=0,curvature=0,anamorphic=1.5"
    );
    let read = |n: &str| io::read_decoded(&s.path(n), &drbokeh::io::ReadLimits::default()).unwrap().image;
    assert_ne!(read("penta.png").data, read("disc.png").data, "the aperture changed nothing");

    // Aperture images that cannot be one.
    let mut black = Image::new(8, 8, 1);
    io::write_png(&s.path("black.png"), &black, 8, Transfer::Linear).unwrap();
    black.data[5] = f32::NAN;
    io::write_exr(&s.path("nan.exr"), &black, &["Y"]).unwrap();
    io::write_png(&s.path("huge.png"), &Image::from_vec(1100, 2, 1, vec![1.0; 2200]).unwrap(), 8, Transfer::Linear).unwrap();
    std::fs::write(s.path("empty.png"), b"").unwrap();
    for (value, needle) in [
        ("blades:2", "--aperture"),
        ("blades:65", "--aperture"),
        ("blades:6,curvature=1.5", "--aperture"),
        ("blades:6,curvature=-0.5", "--aperture"),
        ("hexagon", "--aperture"),
        ("image:black.png", "black.png"),
        ("image:nan.exr", "nan.exr"),
        ("image:huge.png", "huge.png"),
        ("image:empty.png", "empty.png"),
        ("image:missing.png", "missing.png"),
    ] {
        let a = with(&["--aperture", value], "bad.png");
        s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &[needle]);
    }
    for value in ["0", "-1", "20", "nan"] {
        let a = with(&["--anamorphic", value], "bad.png");
        s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["--anamorphic"]);
    }
    for value in ["1.5", "-2", "nan"] {
        let a = with(&["--bubble", value], "bad.png");
        s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["--bubble"]);
    }
    // Chromatic aberration: named in the report, red and blue blurred differently (the
    // official profile too: it scales the CoC, not the shape), bad values refused.
    let chroma = with(&["--chromatic", "0.2", "--profile", "official"], "chroma.png");
    assert_eq!(s.json(&chroma.iter().map(String::as_str).collect::<Vec<_>>())["params"]["aperture"], "disc,chromatic=0.2");
    let official = with(&["--profile", "official"], "official.png");
    s.json(&official.iter().map(String::as_str).collect::<Vec<_>>());
    let (c, o) = (read("chroma.png"), read("official.png"));
    let differs = |ch: usize| c.data.iter().zip(&o.data).skip(ch).step_by(c.channels).any(|(a, b)| a != b);
    assert!(differs(0) && differs(2), "chromatic aberration left red or blue unchanged");
    for value in ["0.6", "-0.51", "nan"] {
        let a = with(&["--chromatic", value], "bad.png");
        s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["--chromatic"]);
    }
    // Cat's eye: named in the report, changes the picture, refused where it has no meaning.
    let cat = with(&["--cat-eye", "1"], "cat.png");
    assert_eq!(s.json(&cat.iter().map(String::as_str).collect::<Vec<_>>())["params"]["aperture"], "disc,cat_eye=1");
    assert_ne!(read("cat.png").data, read("disc.png").data, "the cat's eye changed nothing");
    for value in ["1.5", "-0.1", "nan"] {
        let a = with(&["--cat-eye", value], "bad.png");
        s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["--cat-eye"]);
    }
    // With an image aperture and with a bubble it is taken (named, finite, not the uncut
    // render); with the official profile (the disc only) it is refused.
    io::write_png(&s.path("open.png"), &Image::from_vec(4, 4, 1, vec![1.0; 16]).unwrap(), 8, Transfer::Linear).unwrap();
    for (extra, plain, label) in [
        (&["--aperture", "image:open.png"][..], "uncut_image.png", "image:open.png,cat_eye=0.5"),
        (&["--bubble", "0.5"], "uncut_bubble.png", "disc,bubble=0.5,cat_eye=0.5"),
    ] {
        let uncut = with(extra, plain);
        s.json(&uncut.iter().map(String::as_str).collect::<Vec<_>>());
        let extra: Vec<&str> = extra.iter().copied().chain(["--cat-eye", "0.5"]).collect();
        let a = with(&extra, "cut.png");
        assert_eq!(s.json(&a.iter().map(String::as_str).collect::<Vec<_>>())["params"]["aperture"], label);
        let cut = read("cut.png");
        assert!(cut.all_finite());
        assert_ne!(cut.data, read(plain).data, "{extra:?}: the cat's eye changed nothing");
    }
    let a = with(&["--cat-eye", "0.5", "--profile", "official"], "bad.png");
    s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["cat"]);
    std::fs::write(s.path("chroma.toml"), "[aperture]\nchromatic = 0.7\n").unwrap();
    let a = with(&["--config", "chroma.toml"], "bad.png");
    s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["chroma.toml", "aperture.chromatic"]);
    let a = with(&["--aperture", "blades:6", "--profile", "official"], "bad.png");
    s.bad(&a.iter().map(String::as_str).collect::<Vec<_>>(), &["--aperture", "official"]);
}
