//! HEIC photos end to end (issue 45): the photo, its depth image and its portrait matte are
//! read through libheif; a render without `--depth`/`--matte` uses them and equals the render
//! with the same maps decoded by hand and passed as files; `inspect` names what the file holds
//! and extracts it; bad files exit 2 naming the photo and the item, never a crash.
//!
//! The independent writer and reader is pillow-heif (PyPI, `tests/oracle/heic.py`): it encodes
//! the pictures (x265) and decodes what a HEIC holds with its own bundled libheif; the
//! container's auxiliary-image boxes are written by that script per ISO/IEC 23008-12. The
//! real-camera file is an iPhone portrait photo (`.tools/heif/pug.heic`, from pillow-heif's
//! source distribution, fetched by `scripts/setup-test-env.sh`), whose depth representation
//! SEI the synthetic files also carry.

use crate::common;

use common::assert_usage_error;
use drbokeh::Image;
use drbokeh::io::{self, ReadLimits};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn python() -> PathBuf {
    let py = root().join(".venv/bin/python");
    assert!(py.exists(), "{} missing: run scripts/setup-test-env.sh", py.display());
    py
}

/// The libheif drbokeh loads in these tests: the system's (`libheif.so.1`), else the copy
/// pillow-heif's wheel bundles in `.venv` (so the suite runs where the system has none).
fn libheif() -> Option<PathBuf> {
    static FOUND: std::sync::OnceLock<Option<PathBuf>> = std::sync::OnceLock::new();
    FOUND
        .get_or_init(|| {
            if std::env::var_os("DRBOKEH_LIBHEIF").is_some() || unsafe { libloading::Library::new("libheif.so.1") }.is_ok() {
                return None;
            }
            let lib = root().join(".venv/lib");
            let bundled = std::fs::read_dir(&lib).ok()?.filter_map(|e| e.ok()).find_map(|py| {
                let libs = py.path().join("site-packages/pillow_heif.libs");
                std::fs::read_dir(libs)
                    .ok()?
                    .filter_map(|e| e.ok())
                    .map(|e| e.path())
                    .find(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.starts_with("libheif") && n.contains(".so")))
            });
            Some(bundled.expect("no libheif: neither the system's libheif.so.1 nor pillow-heif's in .venv (run scripts/setup-test-env.sh)"))
        })
        .clone()
}

fn drbokeh(dir: &Path, args: &[&str]) -> Output {
    let mut c = common::drbokeh(dir);
    if let Some(l) = libheif() {
        c.env("DRBOKEH_LIBHEIF", l);
    }
    c.args(args);
    common::run(c)
}

fn ok_json(dir: &Path, args: &[&str]) -> serde_json::Value {
    let out = drbokeh(dir, args);
    assert!(out.status.success(), "drbokeh {} failed: {}", args.join(" "), common::stderr(&out));
    serde_json::from_slice(&out.stdout).unwrap_or_else(|e| panic!("drbokeh {}: not JSON ({e})", args.join(" ")))
}

/// Runs `tests/oracle/heic.py` with `args` in `dir`.
fn oracle(dir: &Path, args: &[&str]) {
    let out = Command::new(python())
        .arg(root().join("tests/oracle/heic.py"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run tests/oracle/heic.py");
    assert!(out.status.success(), "heic.py {}: {}", args.join(" "), String::from_utf8_lossy(&out.stderr));
}

/// The iPhone HEIC the setup script fetches.
fn iphone_heic() -> PathBuf {
    let p = root().join(".tools/heif/pug.heic");
    assert!(p.is_file(), "{} missing: run scripts/setup-test-env.sh", p.display());
    p
}

/// Saves `v` (h x w x c samples, u8) as a uint8 `.npy` for the oracle.
fn save_u8(path: &Path, w: usize, h: usize, c: usize, v: &[u8]) {
    let mut shape = vec![h as u64, w as u64];
    if c > 1 {
        shape.push(c as u64);
    }
    use npyz::WriterBuilder;
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut out = npyz::WriteOptions::<u8>::new().default_dtype().shape(&shape).writer(file).begin_nd().unwrap();
    out.extend(v.iter().copied()).unwrap();
    out.finish().unwrap();
}

/// A `.npy` the oracle wrote: (shape, samples as f64).
fn load(path: &Path) -> (Vec<usize>, Vec<f64>) {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let npy = npyz::NpyFile::new(&bytes[..]).unwrap();
    let shape: Vec<usize> = npy.shape().iter().map(|&s| s as usize).collect();
    let v: Vec<f64> = match npy.dtype().descr().trim_matches('\'') {
        "|u1" => npy.into_vec::<u8>().unwrap().into_iter().map(f64::from).collect(),
        "<u2" => npy.into_vec::<u16>().unwrap().into_iter().map(f64::from).collect(),
        d => panic!("{}: dtype {d}", path.display()),
    };
    (shape, v)
}

/// The bundled example as a HEIC: its photo (8-bit), a `dw` x `dh` depth image holding its
/// normalized disparity in 8 bits (stating the iPhone file's uniform-disparity range when
/// `sei`), and its matte at `mw` x `mh` (none when 0). Written to `dir/name`.
fn example_heic(dir: &Path, name: &str, (dw, dh): (usize, usize), sei: bool, (mw, mh): (usize, usize)) {
    let rgb = image::open(root().join("examples/scene/image.png")).unwrap().to_rgb8();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    save_u8(&dir.join("photo.npy"), w, h, 3, rgb.as_raw());
    let z = io::read_depth(&root().join("examples/scene/depth.exr"), &ReadLimits::default()).unwrap().resized(dw, dh);
    let (lo, hi) = z.data.iter().fold((f32::INFINITY, 0f32), |(a, b), &d| (a.min(1.0 / d), b.max(1.0 / d)));
    let n: Vec<u8> = z.data.iter().map(|&d| ((1.0 / d - lo) / (hi - lo) * 255.0).round() as u8).collect();
    save_u8(&dir.join("depth.npy"), dw, dh, 1, &n);
    let mut args = vec!["write".to_owned(), name.to_owned(), "photo.npy".into(), "--depth".into(), "depth.npy".into()];
    if sei {
        args.extend(["--depth-sei-from".into(), iphone_heic().display().to_string()]);
    }
    if mw > 0 {
        let m = io::read_matte(&root().join("examples/scene/matte.png"), &ReadLimits::default()).unwrap().resized(mw, mh);
        let q: Vec<u8> = m.data.iter().map(|&a| (a * 255.0).round() as u8).collect();
        save_u8(&dir.join("matte.npy"), mw, mh, 1, &q);
        args.extend(["--matte".into(), "matte.npy".into()]);
    }
    oracle(dir, &args.iter().map(String::as_str).collect::<Vec<_>>());
}

/// What pillow-heif reads from `dir/name`, in `dir/name.read/`.
fn pillow_read(dir: &Path, name: &str) -> PathBuf {
    let out = dir.join(format!("{name}.read"));
    std::fs::create_dir_all(&out).unwrap();
    oracle(dir, &["read", name, out.to_str().unwrap()]);
    out
}

/// Metric depth by hand from pillow-heif's raw samples and its uniform-disparity range:
/// `1 / (d_min + q/255 (d_max − d_min))`, in f64.
fn depth_by_hand(read: &Path) -> (Image, f64, f64) {
    let meta: serde_json::Value = serde_json::from_slice(&std::fs::read(read.join("depth.json")).unwrap()).unwrap();
    assert_eq!(meta["representation_type"], 1, "{meta}");
    let (d_min, d_max) = (meta["d_min"].as_f64().unwrap(), meta["d_max"].as_f64().unwrap());
    let (shape, q) = load(&read.join("depth.npy"));
    let z: Vec<f32> = q.iter().map(|&q| (1.0 / (d_min + q / 255.0 * (d_max - d_min))) as f32).collect();
    (Image::from_vec(shape[1], shape[0], 1, z).unwrap(), d_min, d_max)
}

/// pillow-heif's auxiliary images: (item id, type, samples in [0, 1] as an image).
fn aux_by_hand(read: &Path) -> Vec<(u64, String, Image)> {
    let list: serde_json::Value = serde_json::from_slice(&std::fs::read(read.join("aux.json")).unwrap()).unwrap();
    list.as_array()
        .unwrap()
        .iter()
        .map(|a| {
            let id = a["item_id"].as_u64().unwrap();
            let (shape, q) = load(&read.join(format!("aux_{id}.npy")));
            let img = Image::from_vec(shape[1], shape[0], 1, q.iter().map(|&v| (v / 255.0) as f32).collect()).unwrap();
            (id, a["aux_type"].as_str().unwrap().to_owned(), img)
        })
        .collect()
}

/// pillow-heif's portrait matte, in [0, 1].
fn matte_by_hand(read: &Path) -> Image {
    aux_by_hand(read).into_iter().find(|a| a.1 == MATTE_URN).expect("pillow-heif sees the matte").2
}

fn max_diff(a: &Image, b: &Image) -> f32 {
    assert_eq!((a.width, a.height, a.channels), (b.width, b.height, b.channels));
    common::max_abs_diff(&a.data, &b.data)
}

const MATTE_URN: &str = "urn:com:apple:photo:2018:aux:portraiteffectsmatte";

/// The check for HEIC: a render without --depth and --matte (the embedded depth image
/// and portrait matte, at half size) equals, within 1/255, the render of the same HEIC with the
/// maps pillow-heif decodes, turned into depth by hand, passed as --depth and --matte.
#[test]
fn embedded_depth_and_matte_render_as_the_same_maps_given_by_hand() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    example_heic(d, "photo.heic", (240, 160), true, (240, 160));
    let read = pillow_read(d, "photo.heic");
    let (z, d_min, d_max) = depth_by_hand(&read);
    io::write_exr(&d.join("z.exr"), &z, &["Z"]).unwrap();
    let matte = matte_by_hand(&read);
    io::write_exr(&d.join("matte.exr"), &matte, &["A"]).unwrap();

    let common_args = ["--focus-at", "200,150", "--blur", "12", "--json"];
    let mut a = vec!["render", "photo.heic", "-o", "embedded.png"];
    a.extend(common_args);
    let j = ok_json(d, &a);
    let ds = &j["depth_source"];
    assert_eq!((ds["kind"].as_str(), ds["container"].as_str()), (Some("embedded"), Some("heif")), "{j}");
    assert_eq!((ds["heif"]["d_min"].as_f64(), ds["heif"]["d_max"].as_f64()), (Some(d_min), Some(d_max)), "{j}");
    assert_eq!(ds["heif"]["representation"], "uniform_disparity", "{j}");
    let ms = &j["matte_source"];
    assert_eq!((ms["kind"].as_str(), ms["aux_type"].as_str(), ms["width"].as_u64()), (Some("embedded"), Some(MATTE_URN), Some(240)), "{j}");
    assert!(j["stages"].as_array().unwrap().iter().any(|s| s["name"] == "inpaint" && s["reason"].is_null()), "two layers: {j}");

    let mut b = vec!["render", "photo.heic", "--depth", "z.exr", "--matte", "matte.exr", "-o", "by_hand.png"];
    b.extend(common_args);
    let jb = ok_json(d, &b);
    assert_eq!(jb["matte_source"]["kind"], "file", "{jb}");
    let (x, y) = (read_png(&d.join("embedded.png")), read_png(&d.join("by_hand.png")));
    let worst = x.iter().zip(&y).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
    assert!(worst <= 1, "embedded vs by hand: {worst}/255");

    // Without the matte (--no-embedded-matte), the render differs: the matte was used.
    let mut c = vec!["render", "photo.heic", "--no-embedded-matte", "-o", "no_matte.png"];
    c.extend(common_args);
    let jc = ok_json(d, &c);
    assert!(jc["matte_source"].is_null(), "{jc}");
    let z3 = read_png(&d.join("no_matte.png"));
    assert!(x.iter().zip(&z3).any(|(a, b)| a.abs_diff(*b) > 8), "the embedded matte changes the render");
}

fn read_png(path: &Path) -> Vec<u8> {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8().into_raw()
}

/// `inspect` names the depth image, its representation, the matte and the other auxiliary
/// images; `--extract-depth` and `--extract-matte` write what pillow-heif decodes (depth
/// turned into metres by hand); the photo's pixels are pillow-heif's within one level.
#[test]
fn inspect_and_extract_agree_with_pillow_heif() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // A 48 x 32 depth image: libheif's encoder codes a picture this small as 64 x 64 (its `ispe`)
    // and crops it back with a `clap` property, which drbokeh applies.
    example_heic(d, "photo.heic", (48, 32), true, (240, 160));
    let read = pillow_read(d, "photo.heic");
    let (z, d_min, d_max) = depth_by_hand(&read);
    let out = drbokeh(d, &["inspect", "photo.heic"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", common::stderr(&out));
    for needle in [
        "photo.heic: HEIF, 480x320, rgb, 8-bit",
        "depth: HEIF depth image (item 2)",
        "representation      uniform_disparity",
        &format!("d_min               {d_min}"),
        &format!("d_max               {d_max}"),
        "image               48x32, 8-bit grey",
        &format!("matte: HEIF auxiliary image 3 ({MATTE_URN}), 240x160 8-bit"),
    ] {
        assert!(text.contains(needle), "inspect should print {needle:?}; got:\n{text}");
    }
    let j = ok_json(d, &["inspect", "photo.heic", "--json"]);
    assert_eq!((j["format"].as_str(), j["width"].as_u64(), j["height"].as_u64()), (Some("HEIF"), Some(480), Some(320)), "{j}");
    assert_eq!((j["depth"]["kind"].as_str(), j["depth"]["format"].as_str()), (Some("heif"), Some("UniformDisparity")), "{j}");
    assert_eq!(j["matte"]["aux_type"], MATTE_URN, "{j}");
    assert_eq!(j["auxiliary"][0]["used_as"], "matte", "{j}");

    for ext in ["exr", "npy"] {
        let o =
            drbokeh(d, &["inspect", "photo.heic", "--extract-depth", &format!("depth.{ext}"), "--extract-matte", &format!("matte.{ext}")]);
        assert!(o.status.success(), "{}", common::stderr(&o));
        let got = io::read_depth(&d.join(format!("depth.{ext}")), &ReadLimits::default()).unwrap();
        let rel = got.data.iter().zip(&z.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
        assert!(rel < 1e-6, "{ext}: extracted depth off by {rel} (relative)");
        let m = io::read_matte(&d.join(format!("matte.{ext}")), &ReadLimits::default()).unwrap();
        assert!(max_diff(&m, &matte_by_hand(&read)) < 1e-6, "{ext}: extracted matte");
    }
    let o = drbokeh(d, &["inspect", "photo.heic", "--extract-matte", "matte.png"]);
    assert!(o.status.success(), "{}", common::stderr(&o));
    let m = io::read_matte(&d.join("matte.png"), &ReadLimits::default()).unwrap();
    assert_eq!(max_diff(&m, &matte_by_hand(&read)), 0.0, "the 8-bit PNG holds the matte's samples");

    // The photo's pixels, against pillow-heif's decoding (another libheif, another YCbCr
    // conversion: within one level).
    with_libheif(|| {
        let ours = io::read_decoded(&d.join("photo.heic"), &ReadLimits::default()).unwrap();
        let (shape, theirs) = load(&read.join("photo.npy"));
        assert_eq!((shape[1], shape[0], shape[2]), (ours.image.width, ours.image.height, 3));
        let worst = ours.image.data.iter().zip(&theirs).map(|(a, b)| (a * 255.0 - *b as f32).abs()).fold(0f32, f32::max);
        assert!(worst <= 1.0 + 1e-3, "photo off by {worst} levels");
    });
    // Nothing to extract: the photo has no matte.
    example_heic(d, "no_matte.heic", (120, 80), true, (0, 0));
    assert_usage_error(d, "inspect --extract-matte without a matte", &["no_matte.heic", "no matte"], || {
        drbokeh(d, &["inspect", "no_matte.heic", "--extract-matte", "x.png"])
    });
}

/// Runs `f` with this process's libheif lookup pointed where [`libheif`] says (in-process
/// reads load it once per process).
fn with_libheif(f: impl FnOnce()) {
    if let Some(l) = libheif() {
        static SET: std::sync::Once = std::sync::Once::new();
        // SAFETY: set once, before any read in this process loads libheif.
        SET.call_once(|| unsafe { std::env::set_var("DRBOKEH_LIBHEIF", l) });
    }
    f()
}

/// The iPhone's own HEIC: drbokeh's depth (representation, range, samples) and photo are
/// pillow-heif's; the HDR gain map is listed and not used.
#[test]
fn iphone_heic_reads_as_pillow_heif_reads_it() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::copy(iphone_heic(), d.join("pug.heic")).unwrap();
    let read = pillow_read(d, "pug.heic");
    let (z, d_min, d_max) = depth_by_hand(&read);
    let j = ok_json(d, &["inspect", "pug.heic", "--json", "--extract-depth", "z.npy"]);
    assert_eq!((j["width"].as_u64(), j["height"].as_u64(), j["bit_depth"].as_u64()), (Some(4032), Some(3024), Some(8)), "{j}");
    let h = &j["depth"]["heif"];
    assert_eq!(
        (h["representation"].as_str(), h["d_min"].as_f64(), h["d_max"].as_f64()),
        (Some("uniform_disparity"), Some(d_min), Some(d_max))
    );
    assert_eq!((j["depth"]["width"].as_u64(), j["depth"]["height"].as_u64()), (Some(768), Some(576)), "{j}");
    let got = io::read_depth(&d.join("z.npy"), &ReadLimits::default()).unwrap();
    let rel = got.data.iter().zip(&z.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
    assert!(rel < 1e-6, "depth off by {rel}");
    assert!(j["matte"].is_null(), "{j}");
    let gain = &j["auxiliary"][0];
    assert_eq!((gain["aux_type"].as_str(), gain["used_as"].as_str()), (Some("urn:com:apple:photo:2020:aux:hdrgainmap"), Some("not used")));
    with_libheif(|| {
        let ours = io::read_decoded(&d.join("pug.heic"), &ReadLimits::default()).unwrap();
        let (_, theirs) = load(&read.join("photo.npy"));
        let diffs: Vec<f32> = ours.image.data.iter().zip(&theirs).map(|(a, b)| (a * 255.0 - *b as f32).abs()).collect();
        let worst = diffs.iter().fold(0f32, |a, &b| a.max(b));
        let mean = diffs.iter().sum::<f32>() / diffs.len() as f32;
        assert!(worst <= 2.0 + 1e-3 && mean < 0.5, "photo off by {worst} levels (mean {mean})");
    });
}

/// Bad HEIC input exits 2 naming the photo (and the item at fault); a damaged file never
/// crashes the process; a missing libheif says how to install it.
#[test]
fn bad_heic_exits_2_naming_the_photo() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    example_heic(d, "good.heic", (120, 80), true, (240, 160));
    let render = |name: &str| drbokeh(d, &["render", name, "--focus", "0.5", "-o", "out.png"]);

    // A depth image of another aspect ratio; a matte of another aspect ratio.
    let rgb = image::open(root().join("examples/scene/image.png")).unwrap().to_rgb8();
    save_u8(&d.join("photo.npy"), 480, 320, 3, rgb.as_raw());
    save_u8(&d.join("square.npy"), 64, 64, 1, &vec![128u8; 64 * 64]);
    save_u8(&d.join("ok_depth.npy"), 120, 80, 1, &(0..120 * 80).map(|i| (i % 120) as u8).collect::<Vec<_>>());
    oracle(d, &["write", "square_depth.heic", "photo.npy", "--depth", "square.npy"]);
    oracle(d, &["write", "square_matte.heic", "photo.npy", "--depth", "ok_depth.npy", "--matte", "square.npy"]);
    for (name, needles) in [
        ("square_depth.heic", vec!["square_depth.heic", "HEIF depth image (item 2)", "64x64", "480x320", "aspect ratio"]),
        ("square_matte.heic", vec!["square_matte.heic", "HEIF portrait matte (item 3)", "64x64", "aspect ratio"]),
    ] {
        assert_usage_error(d, &format!("render {name}"), &needles, || render(name));
        assert_usage_error(d, &format!("inspect {name}"), &needles, || drbokeh(d, &["inspect", name]));
    }

    // A primary image whose header claims 100000 x 100000: refused before decoding.
    let good = std::fs::read(d.join("good.heic")).unwrap();
    let ispe = good.windows(4).position(|w| w == b"ispe").expect("an ispe box");
    let mut huge = good.clone();
    huge[ispe + 8..ispe + 12].copy_from_slice(&100_000u32.to_be_bytes());
    huge[ispe + 12..ispe + 16].copy_from_slice(&100_000u32.to_be_bytes());
    std::fs::write(d.join("huge.heic"), &huge).unwrap();
    assert_usage_error(d, "render a 100000x100000 HEIC", &["huge.heic"], || render("huge.heic"));

    // Cut anywhere, or with bytes changed: exit 0 or 2, never a crash; a cut file is an error.
    let mut rng = common::Rng::new(45);
    for k in 0..12 {
        let cut = (good.len() as f32 * (0.05 + 0.9 * k as f32 / 12.0)) as usize;
        std::fs::write(d.join("cut.heic"), &good[..cut]).unwrap();
        let o = drbokeh(d, &["inspect", "cut.heic", "--json"]);
        assert_eq!(o.status.code(), Some(2), "cut at {cut}: {}", common::stderr(&o));
        assert!(common::stderr(&o).contains("cut.heic"), "{}", common::stderr(&o));
        let mut flipped = good.clone();
        for _ in 0..8 {
            let i = (rng.next_f32() * flipped.len() as f32) as usize % flipped.len();
            flipped[i] ^= 1 << ((rng.next_f32() * 8.0) as u32 % 8);
        }
        std::fs::write(d.join("flipped.heic"), &flipped).unwrap();
        let o = drbokeh(d, &["render", "flipped.heic", "--focus", "0.5", "-o", "flipped.png"]);
        assert!(matches!(o.status.code(), Some(0) | Some(2)), "flipped bytes ({k}): {:?} {}", o.status, common::stderr(&o));
    }

    // No libheif: the message names the photo, what was tried and how to install it.
    let mut c = common::drbokeh(d);
    c.env("DRBOKEH_LIBHEIF", d.join("no-such-libheif.so")).args(["render", "good.heic", "--focus", "0.5", "-o", "out.png"]);
    assert_usage_error(d, "render without libheif", &["good.heic", "libheif", "DRBOKEH_LIBHEIF", "apt install libheif1"], || {
        common::run(c)
    });

    // A depth image that states no representation: read as relative disparity, with a warning.
    oracle(d, &["write", "plain_depth.heic", "photo.npy", "--depth", "ok_depth.npy"]);
    let j = ok_json(d, &["render", "plain_depth.heic", "--focus", "0.5", "-o", "plain.png", "--json"]);
    assert!(j["depth_source"]["heif"]["representation"].is_null(), "{j}");
    let warned = j["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("states no depth representation"));
    assert!(warned, "{j}");
    // One depth image: no "several depth images" warning.
    assert!(!j["warnings"].to_string().contains("depth images"), "{j}");

    // A HEIC without a depth image, no --depth, no model: the three ways forward.
    oracle(d, &["write", "flat.heic", "photo.npy"]);
    let three = ["--depth", "[depth.onnx]", "--model-dir", "flat.heic embeds no depth map (no HEIF depth image)"];
    assert_usage_error(d, "render a HEIC without depth", &three, || render("flat.heic"));
}

/// `drbokeh batch` picks up HEIC photos and, without a depth companion, uses the depth image
/// and matte they embed; a photo with neither a companion nor an embedded map fails naming the
/// companions looked for and the ways forward, the others still run.
#[test]
fn batch_uses_the_embedded_depth_and_matte() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("in")).unwrap();
    example_heic(&d.join("in"), "portrait.HEIC", (240, 160), true, (240, 160));
    std::fs::copy(root().join("examples/scene/image.png"), d.join("in/plain.png")).unwrap();
    for f in ["photo.npy", "depth.npy", "matte.npy"] {
        std::fs::remove_file(d.join("in").join(f)).unwrap();
    }
    let out = drbokeh(d, &["batch", "in", "-o", "out", "--focus", "0.5", "--json"]);
    assert_eq!(out.status.code(), Some(3), "one item fails (exit 3): {}", common::stderr(&out));
    let summary: serde_json::Value = serde_json::from_slice(&std::fs::read(d.join("out/drbokeh-batch.json")).unwrap()).unwrap();
    let items = summary["items"].as_array().unwrap_or_else(|| panic!("{summary}"));
    let by_name = |n: &str| items.iter().find(|i| i["image"] == n).unwrap_or_else(|| panic!("{n}: {summary}"));
    assert_eq!(by_name("portrait.HEIC")["status"], "ok", "{summary}");
    let failed = by_name("plain.png");
    assert_eq!(failed["status"], "failed", "{summary}");
    let msg = failed["reason"].as_str().unwrap_or_default();
    assert!(msg.contains("no depth map found") && msg.contains("{stem}_depth") && msg.contains("three ways"), "{msg}");
    // The batch's render is the single render's.
    let j = ok_json(d, &["render", "in/portrait.HEIC", "--focus", "0.5", "-o", "single.png", "--json"]);
    assert_eq!(j["matte_source"]["kind"], "embedded", "{j}");
    assert_eq!(read_png(&d.join("out/portrait_bokeh.png")), read_png(&d.join("single.png")));
}
