//! `drbokeh render` on photos whose lights are clipped (issue 35): the highlights stage runs on
//! 8- and 16-bit files, reports the lights it found in `--json`, gives their blur its light
//! back, leaves linear photos bit-identical, and refuses bad options by name.
//!
//! The scene is small (64x48: a textured backdrop with six small lights, a subject in front),
//! so the file runs in a few seconds.

use crate::common;

use common::{assert_usage_error, drbokeh, run, stderr};
use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{self, ReadLimits};
use std::path::Path;

const W: usize = 64;
const H: usize = 48;
/// Light centres (px), radius 2 px, radiance 20 (linear, white = 1).
const LIGHTS: [(f64, f64); 6] = [(8.3, 9.6), (24.7, 8.2), (40.4, 10.9), (9.1, 30.3), (25.6, 36.8), (39.2, 27.5)];
const RADIANCE: f32 = 20.0;

/// Share of pixel (x, y) covered by a light, from 16 x 16 samples.
fn light_area(x: usize, y: usize) -> f32 {
    let at = |k: usize| (k as f64 + 0.5) / 16.0;
    let inside = |k: usize| LIGHTS.iter().any(|&(cx, cy)| (x as f64 + at(k % 16) - cx).hypot(y as f64 + at(k / 16) - cy) <= 2.0);
    (0..256).filter(|&k| inside(k)).count() as f32 / 256.0
}

/// The linear scene: a textured backdrop (0.1–0.4) with the lights, a dark subject over
/// `x >= 48`; and its depth (subject 1, backdrop 4).
fn scene() -> (Image, Image) {
    let mut photo = Image::filled(W, H, 3, 0.0);
    let mut depth = Image::filled(W, H, 1, 4.0);
    for y in 0..H {
        for x in 0..W {
            if x >= 48 {
                photo.pixel_mut(x, y).copy_from_slice(&[0.05, 0.04, 0.03]);
                depth.data[y * W + x] = 1.0;
                continue;
            }
            let t = 0.25 + 0.15 * ((x as f32 * 0.7).sin() * (y as f32 * 0.45).cos());
            let a = light_area(x, y);
            for (c, v) in photo.pixel_mut(x, y).iter_mut().enumerate() {
                *v = t * (1.0 - 0.1 * c as f32) * (1.0 - a) + RADIANCE * a;
            }
        }
    }
    (photo, depth)
}

/// Writes `photo8.png`, `photo16.png` (sRGB, clipped), `photo.exr` (linear) and `depth.exr`.
fn write_scene(dir: &Path) {
    let (photo, depth) = scene();
    io::write_png(&dir.join("photo8.png"), &photo, 8, Transfer::Srgb).unwrap();
    io::write_png(&dir.join("photo16.png"), &photo, 16, Transfer::Srgb).unwrap();
    io::write_exr(&dir.join("photo.exr"), &photo, &["R", "G", "B"]).unwrap();
    io::write_exr(&dir.join("depth.exr"), &depth, &["Z"]).unwrap();
}

/// `drbokeh render PHOTO --depth depth.exr --focus 1 --blur 10 -o OUT --json EXTRA...`: the
/// JSON report and the output (linear).
fn render(dir: &Path, photo: &str, out: &str, extra: &[&str]) -> (serde_json::Value, Image) {
    let mut cmd = drbokeh(dir);
    cmd.args(["render", photo, "--depth", "depth.exr", "--focus", "1", "--blur", "10", "-o", out, "--json"]).args(extra);
    let o = run(cmd);
    assert!(o.status.success(), "render {photo} {extra:?} failed: {}", stderr(&o));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).expect("--json output is JSON");
    (j, io::read_decoded(&dir.join(out), &ReadLimits::default()).unwrap().image)
}

/// The `highlights` stage of a report.
fn stage(j: &serde_json::Value) -> &serde_json::Value {
    j["stages"].as_array().unwrap().iter().find(|s| s["name"] == "highlights").unwrap_or_else(|| panic!("no highlights stage in {j}"))
}

fn sum(img: &Image) -> f64 {
    img.data.iter().map(|&v| v as f64).sum()
}

#[test]
fn clipped_lights_of_8_and_16_bit_photos_get_their_light_back() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let (_, truth) = render(dir, "photo.exr", "truth.exr", &[]);
    for photo in ["photo8.png", "photo16.png"] {
        let (j, auto_render) = render(dir, photo, "auto.exr", &[]);
        let s = stage(&j);
        assert_eq!(s["status"], "ran", "{j}");
        let d = &s["detail"];
        assert_eq!(d["mode"], "auto");
        assert_eq!(d["lights"], LIGHTS.len(), "{photo}: {d}");
        assert!(d["light_added"].as_f64().unwrap() > 0.0, "{d}");
        let brightest = d["brightest"].as_array().unwrap();
        assert!(brightest.iter().all(|l| l["radiance"][0].as_f64().unwrap() > 2.0), "{photo}: dim lights: {d}");

        let (j, off) = render(dir, photo, "off.exr", &["--highlights", "off"]);
        assert_eq!(stage(&j)["status"], "skipped", "{j}");
        assert!(stage(&j)["reason"].as_str().unwrap().contains("off"), "{j}");
        // The blurred lights carry more of the true light than the clipped photo's do.
        let (t, a, o) = (sum(&truth), sum(&auto_render), sum(&off));
        assert!(a > o && (t - a).abs() < (t - o).abs() * 0.6, "{photo}: light in the render: truth {t:.0}, auto {a:.0}, off {o:.0}");
        assert!(auto_render.all_finite());
    }
}

#[test]
fn a_linear_photo_is_left_bit_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let (j, auto) = render(dir, "photo.exr", "auto.exr", &[]);
    assert_eq!(stage(&j)["status"], "skipped", "{j}");
    assert!(stage(&j)["reason"].as_str().unwrap().contains("linear"), "{j}");
    let (_, off) = render(dir, "photo.exr", "off.exr", &["--highlights", "off"]);
    assert_eq!(auto.data, off.data, "auto changed a linear photo's render");
}

#[test]
fn boost_brightens_what_is_above_the_threshold() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let (j, boosted) =
        render(dir, "photo8.png", "boost.exr", &["--highlights", "boost", "--highlight-gain", "8", "--highlight-threshold", "0.9"]);
    let d = &stage(&j)["detail"];
    assert_eq!(d["mode"], "boost", "{j}");
    assert!(d["light_added"].as_f64().unwrap() > 0.0, "{d}");
    let (_, off) = render(dir, "photo8.png", "off.exr", &["--highlights", "off"]);
    assert!(sum(&boosted) > sum(&off));
}

#[test]
fn bad_highlight_options_are_refused_by_name() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    let base = ["render", "photo8.png", "--depth", "depth.exr", "--focus", "1", "-o", "out.png"];
    for (flag, value) in
        [("--highlight-threshold", "1.5"), ("--highlight-threshold", "0"), ("--highlight-gain", "0.5"), ("--highlight-gain", "nan")]
    {
        assert_usage_error(dir, &format!("{flag} {value}"), &[flag], || {
            let mut c = drbokeh(dir);
            c.args(base).args([flag, value]);
            run(c)
        });
    }
    for (line, key) in [("gain = 500.0", "highlights.gain"), ("max_light_radius = 0.0", "highlights.max_light_radius")] {
        std::fs::write(dir.join("bad.toml"), format!("[highlights]\n{line}\n")).unwrap();
        assert_usage_error(dir, &format!("[highlights] {line}"), &[key], || {
            let mut c = drbokeh(dir);
            c.args(base).args(["--config", "bad.toml"]);
            run(c)
        });
        std::fs::remove_file(dir.join("bad.toml")).unwrap();
    }
}

/// `[highlights] max_lights` below the photo's lights: the largest are fitted, the rest
/// counted in `--json` and named in a warning that says how to fit them.
#[test]
fn max_lights_bounds_the_fits_and_says_so() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    write_scene(dir);
    std::fs::write(dir.join("few.toml"), "[highlights]\nmax_lights = 4\n").unwrap();
    let (j, out) = render(dir, "photo8.png", "few.exr", &["--config", "few.toml"]);
    let d = &stage(&j)["detail"];
    assert_eq!((d["lights"].as_u64(), d["over_budget"].as_u64()), (Some(4), Some(2)), "{d}");
    let warned = j["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("max_lights"));
    assert!(warned, "no warning names max_lights: {j}");
    assert!(out.all_finite());
}
