//! Depth maps embedded in the photo (Google's GDepth XMP and Dynamic Depth 1.0 container
//! items in a JPEG), end to end: a render
//! without `--depth` uses the embedded map and equals the render with the same map decoded by
//! hand and passed as `--depth`; `inspect` names the fields and extracts the map; every bad
//! file exits 2 naming the photo and the field (never a panic, never a render without depth);
//! with nothing to give depth, the message names the three ways forward. ExifTool (installed
//! into `.tools/` by `scripts/setup-test-env.sh`) is the independent reader and writer.

use crate::common;
#[path = "common/dynamic_depth.rs"]
mod dynamic_depth;
#[path = "common/gdepth.rs"]
mod gdepth;

use common::assert_usage_error;
use drbokeh::Image;
use drbokeh::io::{self, ReadLimits};
use dynamic_depth::{DynamicDepthJpeg, Item};
use gdepth::{GDepthJpeg, depth_of, grey_png, normalized, photo_jpeg, quantized};
use std::path::Path;
use std::process::{Command, Output};

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

fn drbokeh(dir: &Path, args: &[&str]) -> Output {
    let mut c = common::drbokeh(dir);
    c.args(args);
    common::run(c)
}

fn ok_json(dir: &Path, args: &[&str]) -> serde_json::Value {
    let out = drbokeh(dir, args);
    assert!(out.status.success(), "drbokeh {} failed: {}", args.join(" "), common::stderr(&out));
    serde_json::from_slice(&out.stdout)
        .unwrap_or_else(|e| panic!("drbokeh {}: not JSON ({e}): {}", args.join(" "), String::from_utf8_lossy(&out.stdout)))
}

/// The bundled example: its photo as 8-bit sRGB and its depth map.
fn example() -> (image::RgbImage, Image) {
    let rgb = image::open(root().join("examples/scene/image.png")).unwrap().to_rgb8();
    let z = io::read_depth(&root().join("examples/scene/depth.exr"), &ReadLimits::default()).unwrap();
    (rgb, z)
}

/// A GDepth map of the metric depth `z`: `format` with Near/Far the range of `z`, at the size
/// `w` x `h`, as a `bits`-bit PNG. Returns the PNG, near, far, and the map decoded by hand
/// (metric depth of the stored samples, f64 arithmetic, at `w` x `h`).
fn encode_map(z: &Image, format: &str, w: usize, h: usize, bits: u8) -> (Vec<u8>, f64, f64, Image) {
    let small = z.resized(w, h);
    let near = small.data.iter().fold(f32::INFINITY, |a, &v| a.min(v)) as f64;
    let far = small.data.iter().fold(0f32, |a, &v| a.max(v)) as f64;
    let mut n = small.clone();
    n.map_inplace(|d| normalized(format, d as f64, near, far).clamp(0.0, 1.0) as f32);
    let png = grey_png(&n, bits);
    let max = ((1u32 << bits) - 1) as f64;
    let decoded: Vec<f32> = quantized(&n, bits).iter().map(|&q| depth_of(format, q as f64 / max, near, far) as f32).collect();
    (png, near, far, Image::from_vec(w, h, 1, decoded).unwrap())
}

fn read_png8(path: &Path) -> Vec<u8> {
    image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8().into_raw()
}

/// The check: the bundled example's depth written into its JPEG as GDepth
/// (RangeInverse, 8-bit PNG, Near/Far from the depth map, the usual half-size map), rendered
/// without --depth, equals (within 1/255) the render of the same JPEG with the map decoded by
/// hand and passed as --depth; the same with the XMP split over standard + extended segments.
#[test]
fn embedded_map_renders_as_the_same_map_given_as_depth() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let (png, near, far, by_hand) = encode_map(&z, "RangeInverse", 240, 160, 8);
    io::write_exr(&d.join("by_hand.exr"), &by_hand, &["Z"]).unwrap();
    let base = GDepthJpeg::new(photo_jpeg(&rgb), "RangeInverse", near, far, "image/png", &png);
    std::fs::write(d.join("photo.jpg"), base.bytes()).unwrap();
    // Several extended segments: chunks far smaller than an APP1 segment's 64 KB.
    std::fs::write(d.join("split.jpg"), base.clone().extended(700).bytes()).unwrap();
    let focus = ["--focus-at", "300,118", "--blur", "20", "--json"];
    let with = |photo: &str, out: &str, extra: &[&str]| {
        let mut a = vec!["render", photo, "-o", out];
        a.extend(focus);
        a.extend(extra);
        ok_json(d, &a)
    };
    let reference = with("photo.jpg", "file.png", &["--depth", "by_hand.exr"]);
    assert_eq!(reference["depth_source"]["kind"], "file", "{reference}");
    let want = read_png8(&d.join("file.png"));
    for (photo, out) in [("photo.jpg", "embedded.png"), ("split.jpg", "split.png")] {
        let j = with(photo, out, &[]);
        let s = &j["depth_source"];
        assert_eq!(s["kind"], "embedded", "{j}");
        assert_eq!(s["container"], "gdepth");
        assert_eq!(s["format"], "RangeInverse");
        assert_eq!(s["mime"], "image/png");
        assert_eq!((s["width"].as_u64(), s["height"].as_u64(), s["bit_depth"].as_u64()), (Some(240), Some(160), Some(8)));
        assert_eq!((s["near"].as_f64(), s["far"].as_f64()), (Some(near), Some(far)));
        let segments = s["xmp"]["extended_segments"].as_u64().unwrap();
        assert!(if photo == "split.jpg" { segments > 2 } else { segments == 0 }, "{photo}: {s}");
        let got = read_png8(&d.join(out));
        let worst = got.iter().zip(&want).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
        eprintln!("{photo}: largest difference from the --depth render {worst}/255");
        assert!(worst <= 1, "{photo}: the embedded map's render is {worst}/255 off the --depth render");
        // Not a trivial pass: the scene is blurred somewhere.
        let photo_px = image::open(d.join(photo)).unwrap().to_rgb8().into_raw();
        assert!(got.iter().zip(&photo_px).any(|(a, b)| a.abs_diff(*b) > 20), "{photo}: nothing was blurred");
    }
    // -v names where the depth came from.
    let out = drbokeh(d, &["render", "photo.jpg", "--focus", "0", "-o", "v.png", "-v"]);
    let err = common::stderr(&out);
    assert!(out.status.success() && err.contains("embedded in photo.jpg: GDepth RangeInverse"), "{err}");
}

/// Both formats, 8 and 16 bits, attributes or elements, any prefix, standard or extended
/// XMP: `inspect --extract-depth` gives the map decoded by hand (the library's formulas
/// against the test's own).
#[test]
fn every_variant_decodes_to_the_hand_decoded_depth() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let photo = photo_jpeg(&rgb);
    let mut n = 0;
    for format in ["RangeInverse", "RangeLinear"] {
        for bits in [8u8, 16] {
            for (elements, extended) in [(false, None), (true, None), (false, Some(1000)), (true, Some(65000))] {
                let (png, near, far, by_hand) = encode_map(&z, format, 120, 80, bits);
                let mut g = GDepthJpeg::new(photo.clone(), format, near, far, "image/png", &png);
                g.elements = elements;
                g.extended_chunk = extended;
                g.prefix = if elements { "depthmap".into() } else { "GDepth".into() };
                n += 1;
                let (file, out) = (format!("v{n}.jpg"), format!("v{n}.exr"));
                std::fs::write(d.join(&file), g.bytes()).unwrap();
                let j = ok_json(d, &["inspect", &file, "--json", "--extract-depth", &out]);
                let what = format!("{format} {bits}-bit elements={elements} extended={extended:?}");
                assert_eq!(j["depth"]["format"], format, "{what}: {j}");
                assert_eq!(j["depth"]["bit_depth"].as_u64(), Some(bits as u64), "{what}");
                let got = io::read_depth(&d.join(&out), &ReadLimits::default()).unwrap();
                let worst = got.data.iter().zip(&by_hand.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
                assert!(worst < 1e-6, "{what}: extracted depth off the hand decode by {worst} (relative)");
            }
        }
    }
}

/// `inspect` names the GDepth fields and the photo's size and colour, as text and JSON;
/// `--extract-depth` writes EXR, NPY and PNG (depth / Far), atomically, never over the photo.
#[test]
fn inspect_names_the_fields_and_extracts_the_map() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let (png, near, far, by_hand) = encode_map(&z, "RangeInverse", 240, 160, 8);
    let g = GDepthJpeg::new(photo_jpeg(&rgb), "RangeInverse", near, far, "image/png", &png).set("ConfidenceMime", "image/png");
    std::fs::write(d.join("photo.jpg"), g.bytes()).unwrap();
    let out = drbokeh(d, &["inspect", "photo.jpg"]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", common::stderr(&out));
    for needle in [
        "photo.jpg: JPEG, 480x320, rgb, 8-bit",
        "GDepth:Format       RangeInverse",
        &format!("GDepth:Near         {near}"),
        &format!("GDepth:Far          {far}"),
        "GDepth:Units        m",
        "GDepth:MeasureType  OpticalAxis",
        "GDepth:Mime         image/png",
        &format!("GDepth:Data         240x160, 8-bit grey, {} bytes", png.len()),
        "GDepth:Confidence   image/png",
        "matte: none",
        "Dynamic Depth",
    ] {
        assert!(text.contains(needle), "inspect should print {needle:?}; got:\n{text}");
    }
    let j = ok_json(d, &["inspect", "photo.jpg", "--json"]);
    assert_eq!(
        (j["width"].as_u64(), j["height"].as_u64(), j["colour"].as_str(), j["bit_depth"].as_u64()),
        (Some(480), Some(320), Some("rgb"), Some(8))
    );
    let depth = &j["depth"];
    assert_eq!(
        (depth["kind"].as_str(), depth["format"].as_str(), depth["mime"].as_str()),
        (Some("gdepth"), Some("RangeInverse"), Some("image/png"))
    );
    assert_eq!((depth["near"].as_f64(), depth["far"].as_f64(), depth["units"].as_str()), (Some(near), Some(far), Some("m")));
    assert!(j["matte"].is_null(), "{j}");

    for ext in ["exr", "npy", "png"] {
        let out = format!("depth.{ext}");
        let o = drbokeh(d, &["inspect", "photo.jpg", "--extract-depth", &out]);
        assert!(o.status.success(), "{}", common::stderr(&o));
        let got = io::read_depth(&d.join(&out), &ReadLimits::default()).unwrap();
        // The PNG holds depth / Far in 16 bits.
        let (scale, tol) = if ext == "png" { (far as f32, 1.0 / 65535.0 * far as f32) } else { (1.0, 1e-6 * far as f32) };
        let worst = got.data.iter().zip(&by_hand.data).map(|(a, b)| (a * scale - b).abs()).fold(0f32, f32::max);
        assert!(worst <= tol, "{ext}: extracted map off by {worst}");
    }
    // The photo is an input: never a destination.
    assert_usage_error(d, "inspect --extract-depth onto the photo", &["photo.jpg", "--extract-depth"], || {
        drbokeh(d, &["inspect", "photo.jpg", "--extract-depth", "./photo.jpg"])
    });
    // Nothing to extract from a photo without depth.
    std::fs::write(d.join("plain.jpg"), photo_jpeg(&rgb)).unwrap();
    let o = drbokeh(d, &["inspect", "plain.jpg"]);
    assert!(o.status.success() && String::from_utf8_lossy(&o.stdout).contains("depth: none embedded"), "{}", common::stderr(&o));
    assert_usage_error(d, "inspect --extract-depth without depth", &["plain.jpg", "no depth map"], || {
        drbokeh(d, &["inspect", "plain.jpg", "--extract-depth", "x.exr"])
    });
}

/// A small scene (48x32 photo, 24x16 map) for the bad-input cases.
fn small() -> (Vec<u8>, Vec<u8>, f64, f64) {
    let mut rgb = image::RgbImage::new(48, 32);
    for (x, y, p) in rgb.enumerate_pixels_mut() {
        *p = image::Rgb([(x * 5) as u8, (y * 7) as u8, 90]);
    }
    let z = Image::from_vec(24, 16, 1, (0..24 * 16).map(|i| 1.0 + (i % 24) as f32 / 8.0).collect()).unwrap();
    let (png, near, far, _) = encode_map(&z, "RangeInverse", 24, 16, 8);
    (photo_jpeg(&rgb), png, near, far)
}

/// Every bad GDepth exits 2 from `render` (without --depth) and from `inspect`, naming the
/// photo and the field, writing nothing; never a panic, never a render without depth.
#[test]
fn bad_embedded_depth_exits_2_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (photo, png, near, far) = small();
    let good = GDepthJpeg::new(photo.clone(), "RangeInverse", near, far, "image/png", &png);
    let b64 = gdepth::base64(&png);
    let square = {
        let n = Image::filled(16, 16, 1, 0.5);
        gdepth::base64(&grey_png(&n, 8))
    };
    let colour = {
        let n = Image::from_vec(24, 16, 3, (0..24 * 16 * 3).map(|i| (i % 3) as f32 / 2.0).collect()).unwrap();
        gdepth::base64(&grey_png(&n, 8))
    };
    let mut split_missing = good.clone().extended(200);
    split_missing.drop_chunk = Some(1);
    let mut split_guid = good.clone().extended(200);
    split_guid.chunk_guid = Some("FFFFFFFFFFFFFFFFFFFFFFFFFFFFFFFF".into());
    let cases: Vec<(&str, GDepthJpeg, Vec<&str>)> = vec![
        ("truncated base64", good.clone().set("Data", &b64[..b64.len() / 2 + 1]), vec!["GDepth:Data"]),
        ("base64 cut at a group", good.clone().set("Data", &b64[..b64.len() / 8 * 4]), vec!["GDepth:Data"]),
        ("invalid base64", good.clone().set("Data", "****"), vec!["GDepth:Data", "base64"]),
        ("empty data", good.clone().set("Data", ""), vec!["GDepth:Data"]),
        ("missing data", good.clone().without("Data"), vec!["GDepth:Data"]),
        ("other aspect ratio", good.clone().set("Data", &square), vec!["GDepth:Data", "16x16", "48x32", "aspect ratio"]),
        ("colour depth image", good.clone().set("Data", &colour), vec!["GDepth:Data", "colour"]),
        (
            "100000x100000 header",
            good.clone().set("Data", &gdepth::base64(&gdepth::png_claiming(100_000, 100_000))),
            vec!["GDepth:Data", "100000x100000", "limit"],
        ),
        ("near above far", good.clone().set("Near", "4").set("Far", "1"), vec!["GDepth:Near", "GDepth:Far"]),
        ("near equal to far", good.clone().set("Near", "2").set("Far", "2"), vec!["GDepth:Near", "GDepth:Far"]),
        ("negative near", good.clone().set("Near", "-1"), vec!["GDepth:Near"]),
        ("NaN near", good.clone().set("Near", "NaN"), vec!["GDepth:Near"]),
        ("infinite far", good.clone().set("Far", "inf"), vec!["GDepth:Far"]),
        ("near not a number", good.clone().set("Near", "near"), vec!["GDepth:Near", "not a number"]),
        ("zero near, RangeInverse", good.clone().set("Near", "0"), vec!["GDepth:Near", "RangeInverse"]),
        ("missing far", good.clone().without("Far"), vec!["GDepth:Far"]),
        ("unknown format", good.clone().set("Format", "RangeLog"), vec!["GDepth:Format", "RangeLog"]),
        ("missing format", good.clone().without("Format"), vec!["GDepth:Format"]),
        ("unknown mime", good.clone().set("Mime", "image/webp"), vec!["GDepth:Mime", "image/webp"]),
        ("mime disagrees with data", good.clone().set("Mime", "image/jpeg"), vec!["GDepth:Mime", "GDepth:Data"]),
        ("malformed XMP", good.clone().set("Format", "Range\"Inverse"), vec!["XMP", "well-formed"]),
        ("extended XMP chunk missing", split_missing, vec!["extended XMP", "missing"]),
        ("extended XMP GUID mismatch", split_guid, vec!["xmpNote:HasExtendedXMP", "FFFFFFFFFFFFFFFFFFFFFFFFFFFFFFFF"]),
    ];
    for (i, (what, g, needles)) in cases.iter().enumerate() {
        let name = format!("bad{i}.jpg");
        std::fs::write(d.join(&name), g.bytes()).unwrap();
        let mut all = needles.clone();
        all.push(&name);
        assert_usage_error(d, &format!("render: {what}"), &all, || drbokeh(d, &["render", &name, "--focus", "0.5", "-o", "out.png"]));
        assert_usage_error(d, &format!("inspect: {what}"), &all, || drbokeh(d, &["inspect", &name, "--json"]));
    }
    // An explicit --depth wins: the embedded map (here broken) is not even read.
    let bad = good.clone().set("Near", "4").set("Far", "1");
    std::fs::write(d.join("broken.jpg"), bad.bytes()).unwrap();
    let z = Image::from_vec(48, 32, 1, (0..48 * 32).map(|i| 1.0 + (i % 48) as f32 / 16.0).collect()).unwrap();
    io::write_exr(&d.join("z.exr"), &z, &["Z"]).unwrap();
    let j = ok_json(d, &["render", "broken.jpg", "--depth", "z.exr", "--focus", "0.5", "-o", "ok.png", "--json"]);
    assert_eq!(j["depth_source"]["kind"], "file", "{j}");
}

/// With no depth file, no embedded map and no model, the message names the three ways forward
/// (exit 2, nothing written), for a JPEG, a PNG, and a GDepth JPEG told to ignore its map.
#[test]
fn no_depth_anywhere_names_the_three_ways() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (photo, png, near, far) = small();
    std::fs::write(d.join("plain.jpg"), &photo).unwrap();
    image::load_from_memory(&photo).unwrap().save(d.join("plain.png")).unwrap();
    std::fs::write(d.join("gdepth.jpg"), GDepthJpeg::new(photo, "RangeInverse", near, far, "image/png", &png).bytes()).unwrap();
    let three = ["--depth", "GDepth", "[depth.onnx]", "--model-dir", "drbokeh inspect"];
    for (args, why) in [
        (vec!["render", "plain.jpg"], "plain.jpg embeds no depth map"),
        (vec!["render", "plain.png"], "read from JPEG photos"),
        (vec!["render", "gdepth.jpg", "--no-embedded-depth"], "--no-embedded-depth"),
    ] {
        let mut a = args.clone();
        a.extend(["--focus", "0.5", "-o", "out.png"]);
        let mut needles = three.to_vec();
        needles.push(why);
        assert_usage_error(d, &a.join(" "), &needles, || drbokeh(d, &a));
    }
}

/// The embedded map comes before a depth model: with a model folder holding the depth stub,
/// the photo's own map is used (ONNX Runtime is never loaded, so this needs none).
#[test]
fn embedded_map_comes_before_a_depth_model() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (photo, png, near, far) = small();
    std::fs::write(d.join("gdepth.jpg"), GDepthJpeg::new(photo, "RangeInverse", near, far, "image/png", &png).bytes()).unwrap();
    let models = root().join("models-stub");
    let j = ok_json(
        d,
        &["render", "gdepth.jpg", "--model-dir", models.to_str().unwrap(), "--focus", "0.5", "-o", "o.png", "--json", "--threads", "1"],
    );
    assert_eq!(j["depth_source"]["kind"], "embedded", "{j}");
    assert!(j["stages"].as_array().unwrap().iter().all(|s| s["name"] != "depth_model"), "{j}");
}

// ---------------------------------------------------------------------------------------------
// ExifTool, the independent reader and writer
// ---------------------------------------------------------------------------------------------

/// ExifTool as a command: `$DRBOKEH_EXIFTOOL` (an `exiftool` script), else the copy
/// `scripts/setup-test-env.sh` unpacks into `.tools/exiftool` (Debian's
/// libimage-exiftool-perl), run with the system `perl`.
fn exiftool() -> Command {
    if let Some(p) = std::env::var_os("DRBOKEH_EXIFTOOL") {
        return Command::new(p);
    }
    let base = root().join(".tools/exiftool/usr");
    let script = base.join("bin/exiftool");
    assert!(
        script.is_file(),
        "{} is missing: run scripts/setup-test-env.sh (it unpacks Debian's libimage-exiftool-perl there), \
         or set DRBOKEH_EXIFTOOL to an exiftool executable",
        script.display()
    );
    let mut c = Command::new("perl");
    c.arg("-I").arg(base.join("share/perl5")).arg(script);
    c
}

fn run_exiftool(dir: &Path, args: &[&str]) -> Output {
    let mut c = exiftool();
    c.current_dir(dir).args(args);
    let out = common::run(c);
    assert!(out.status.success(), "exiftool {} failed: {}", args.join(" "), common::stderr(&out));
    out
}

/// ExifTool reads back our test files' GDepth fields, standard and extended, with no warning,
/// and extracts the very PNG we embedded.
#[test]
fn exiftool_reads_our_gdepth_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let (png, near, far, _) = encode_map(&z, "RangeInverse", 240, 160, 8);
    let g = GDepthJpeg::new(photo_jpeg(&rgb), "RangeInverse", near, far, "image/png", &png);
    std::fs::write(d.join("standard.jpg"), g.bytes()).unwrap();
    std::fs::write(d.join("extended.jpg"), g.clone().extended(700).bytes()).unwrap();
    let mut e = g.clone().extended(700);
    e.elements = true;
    std::fs::write(d.join("elements.jpg"), e.bytes()).unwrap();
    for file in ["standard.jpg", "extended.jpg", "elements.jpg"] {
        let out = run_exiftool(d, &["-j", "-n", "-G1", "-XMP-GDepth:all", "-Warning", file]);
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let t = &j[0];
        assert!(t.get("ExifTool:Warning").is_none() && t.get("Warning").is_none(), "{file}: ExifTool warns: {t}");
        assert_eq!(t["XMP-GDepth:Format"], "RangeInverse", "{file}: {t}");
        assert_eq!(t["XMP-GDepth:Near"].as_f64(), Some(near), "{file}: {t}");
        assert_eq!(t["XMP-GDepth:Far"].as_f64(), Some(far), "{file}: {t}");
        assert_eq!(t["XMP-GDepth:Mime"], "image/png", "{file}: {t}");
        assert_eq!(t["XMP-GDepth:Units"], "m", "{file}: {t}");
        assert_eq!(t["XMP-GDepth:MeasureType"], "OpticalAxis", "{file}: {t}");
        let image = run_exiftool(d, &["-b", "-XMP-GDepth:DepthImage", file]).stdout;
        assert!(image == png, "{file}: ExifTool extracts {} bytes, not the {}-byte PNG we embedded", image.len(), png.len());
    }
}

/// ExifTool writes GDepth into a plain JPEG (a 16-bit map big enough that it splits the XMP
/// into a standard and an extended packet over several APP1 segments, with its own GUID);
/// drbokeh reads the fields and decodes the map as the hand decode does, and renders with it.
#[test]
fn drbokeh_reads_gdepth_written_by_exiftool() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, mut z) = example();
    // Noise in the low bits keeps the PNG large, as a real 16-bit map's is: more than one APP1
    // segment holds.
    let mut rng = common::Rng::new(45);
    for v in &mut z.data {
        *v *= 1.0 + 0.01 * rng.next_f32();
    }
    let (png, near, far, by_hand) = encode_map(&z, "RangeLinear", 480, 320, 16);
    assert!(png.len() > 70_000, "the map should need extended XMP: {} bytes", png.len());
    std::fs::write(d.join("plain.jpg"), photo_jpeg(&rgb)).unwrap();
    std::fs::write(d.join("depth.png"), &png).unwrap();
    let (n, f) = (format!("-XMP-GDepth:Near={near}"), format!("-XMP-GDepth:Far={far}"));
    run_exiftool(
        d,
        &[
            "-o",
            "gdepth.jpg",
            "-XMP-GDepth:Format=RangeLinear",
            &n,
            &f,
            "-XMP-GDepth:Mime=image/png",
            "-XMP-GDepth:Units=m",
            "-XMP-GDepth:DepthImage<=depth.png",
            "plain.jpg",
        ],
    );
    let j = ok_json(d, &["inspect", "gdepth.jpg", "--json", "--extract-depth", "depth.exr"]);
    let depth = &j["depth"];
    assert_eq!(depth["format"], "RangeLinear", "{j}");
    assert_eq!((depth["near"].as_f64(), depth["far"].as_f64()), (Some(near), Some(far)), "{j}");
    assert_eq!((depth["width"].as_u64(), depth["height"].as_u64(), depth["bit_depth"].as_u64()), (Some(480), Some(320), Some(16)));
    assert_eq!(depth["data_bytes"].as_u64(), Some(png.len() as u64));
    let got = io::read_depth(&d.join("depth.exr"), &ReadLimits::default()).unwrap();
    let worst = got.data.iter().zip(&by_hand.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
    assert!(worst < 1e-6, "ExifTool-written map decodes {worst} (relative) off the hand decode");
    assert!(depth["xmp"]["extended_segments"].as_u64().unwrap() >= 2, "{j}");
    assert!(depth["xmp"]["guid"].as_str().is_some_and(|g| g.len() == 32), "{j}");
    let r = ok_json(d, &["render", "gdepth.jpg", "--focus", "0", "-o", "o.png", "--json"]);
    assert_eq!(r["depth_source"]["kind"], "embedded", "{r}");
}

/// The reader never panics: a GDepth JPEG (standard and extended XMP) and a Dynamic Depth JPEG
/// cut at every byte, and
/// with thousands of random bytes changed, reads as a depth map, as none, or as an error, each
/// error naming the photo.
#[test]
fn damaged_files_never_panic() {
    use drbokeh::io::embedded::read_embedded_bytes;
    let (photo, png, near, far) = small();
    let good = GDepthJpeg::new(photo.clone(), "RangeInverse", near, far, "image/png", &png);
    let dd = DynamicDepthJpeg::new(photo, "RangeInverse", near, far, "image/png", &png, &png);
    let limits = ReadLimits { max_pixels: 1 << 20 };
    let p = Path::new("photo.jpg");
    let check = |b: &[u8], what: &str| {
        let r = std::panic::catch_unwind(|| read_embedded_bytes(p, b, &limits));
        match r {
            Err(_) => panic!("{what}: the reader panicked"),
            Ok(Err(e)) => assert!(e.to_string().contains("photo.jpg"), "{what}: {e}"),
            Ok(Ok(_)) => {}
        }
    };
    let mut rng = common::Rng::new(7);
    for bytes in [good.bytes(), good.clone().extended(150).bytes(), dd.bytes()] {
        assert!(read_embedded_bytes(p, &bytes, &limits).unwrap().is_some());
        for cut in 0..bytes.len() {
            check(&bytes[..cut], &format!("cut at {cut}"));
        }
        for k in 0..3000 {
            let mut b = bytes.clone();
            for _ in 0..1 + k % 4 {
                let i = (rng.next_f32() * b.len() as f32) as usize % b.len();
                b[i] = (rng.next_f32() * 256.0) as u8;
            }
            check(&b, &format!("mutation {k}"));
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Dynamic Depth 1.0: the depth image a container item after the primary JPEG
// ---------------------------------------------------------------------------------------------

/// A confidence map of the depth map's size (item 1, before the depth item: its length moves
/// the depth item's offset).
fn confidence_png(w: usize, h: usize) -> Vec<u8> {
    grey_png(&Image::from_vec(w, h, 1, (0..w * h).map(|i| (i % 7) as f32 / 6.0).collect()).unwrap(), 8)
}

/// The check for Dynamic Depth: the bundled example's depth as a Depth Photo's depth
/// item (after a confidence item), rendered without --depth, equals (within 1/255) the render
/// with the map decoded by hand and given as --depth; with fields as attributes or elements,
/// the depth map on camera 0 or 1, and another trailer after the items. `inspect` names the
/// fields and `--extract-depth` gives the hand decode.
#[test]
fn dynamic_depth_renders_as_the_same_map_given_as_depth() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let (png, near, far, by_hand) = encode_map(&z, "RangeLinear", 240, 160, 16);
    let conf = confidence_png(240, 160);
    io::write_exr(&d.join("by_hand.exr"), &by_hand, &["Z"]).unwrap();
    let base = DynamicDepthJpeg::new(photo_jpeg(&rgb), "RangeLinear", near, far, "image/png", &png, &conf);
    let mut elements = base.clone();
    elements.elements = true;
    elements.cameras_before = 1;
    elements.after = b"\xFF\xD8 another trailer \xFF\xD9".to_vec();
    // The primary's Length takes no room after it; padding follows the depth image inside its
    // Length.
    let padded = (png.len() + 16).to_string();
    elements = elements.item_field(0, "Length", Some("4096")).item_field(2, "Length", Some(&padded)).item_field(2, "Padding", Some("16"));
    elements.items[2].payload.extend([0u8; 16]);
    std::fs::write(d.join("dd.jpg"), base.bytes()).unwrap();
    std::fs::write(d.join("elements.jpg"), elements.bytes()).unwrap();
    let focus = ["--focus-at", "300,118", "--blur", "20", "--json"];
    let with = |photo: &str, out: &str, extra: &[&str]| {
        let mut a = vec!["render", photo, "-o", out];
        a.extend(focus);
        a.extend(extra);
        ok_json(d, &a)
    };
    with("dd.jpg", "file.png", &["--depth", "by_hand.exr"]);
    let want = read_png8(&d.join("file.png"));
    for (photo, out, camera, file) in [("dd.jpg", "dd.png", 0, &base), ("elements.jpg", "elements.png", 1, &elements)] {
        let photo_len = file.bytes().len() - file.items[2].payload.len() - conf.len() - file.after.len();
        let j = with(photo, out, &[]);
        let s = &j["depth_source"];
        assert_eq!((s["kind"].as_str(), s["container"].as_str()), (Some("embedded"), Some("dynamic-depth")), "{j}");
        assert_eq!(
            (s["format"].as_str(), s["mime"].as_str(), s["units"].as_str()),
            (Some("RangeLinear"), Some("image/png"), Some("Meters"))
        );
        assert_eq!((s["width"].as_u64(), s["height"].as_u64(), s["bit_depth"].as_u64()), (Some(240), Some(160), Some(16)));
        assert_eq!((s["near"].as_f64(), s["far"].as_f64()), (Some(near), Some(far)));
        let item = &s["item"];
        assert_eq!(
            (item["uri"].as_str(), item["index"].as_u64(), item["camera"].as_u64()),
            (Some("android/depthmap"), Some(2), Some(camera))
        );
        assert_eq!(item["offset"].as_u64(), Some((photo_len + conf.len()) as u64), "{photo}: {item}");
        assert_eq!(item["confidence_uri"], "android/confidencemap");
        assert_eq!((s["data_bytes"].as_u64(), item["padding"].as_u64()), (Some(png.len() as u64), Some(16 * camera)), "{item}");
        let warned = j["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("camera 1"));
        assert_eq!(warned, camera == 1, "{photo}: {j}");
        let got = read_png8(&d.join(out));
        let worst = got.iter().zip(&want).map(|(a, b)| a.abs_diff(*b)).max().unwrap();
        assert!(worst <= 1, "{photo}: the embedded map's render is {worst}/255 off the --depth render");
        let photo_px = image::open(d.join(photo)).unwrap().to_rgb8().into_raw();
        assert!(got.iter().zip(&photo_px).any(|(a, b)| a.abs_diff(*b) > 20), "{photo}: nothing was blurred");
        // inspect: the fields, the item, the map.
        let out = drbokeh(d, &["inspect", photo, "--extract-depth", "x.exr"]);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{}", common::stderr(&out));
        for needle in [
            "depth: Dynamic Depth",
            "DepthMap:Format     RangeLinear",
            &format!("DepthMap:Near       {near}"),
            "DepthMap:Units      Meters",
            &format!("DepthMap:DepthURI   android/depthmap (camera {camera})"),
            &format!("Container:Item 2    image/png, 240x160, 16-bit grey, {} bytes", png.len()),
            "DepthMap:ConfidenceURI android/confidencemap (not used)",
        ] {
            assert!(text.contains(needle), "{photo}: inspect should print {needle:?}; got:\n{text}");
        }
        let got = io::read_depth(&d.join("x.exr"), &ReadLimits::default()).unwrap();
        let worst = got.data.iter().zip(&by_hand.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-6, "{photo}: extracted depth off the hand decode by {worst} (relative)");
    }
    // A file with both: the Dynamic Depth map is used, and the GDepth one named as not.
    let mut both = base.clone();
    both.extra_attributes = format!(
        " xmlns:GDepth=\"{}\" GDepth:Format=\"RangeInverse\" GDepth:Near=\"1\" GDepth:Far=\"2\" GDepth:Mime=\"image/png\" GDepth:Data=\"{}\"",
        gdepth::NS_GDEPTH,
        gdepth::base64(&png)
    );
    std::fs::write(d.join("both.jpg"), both.bytes()).unwrap();
    let j = with("both.jpg", "both.png", &[]);
    assert_eq!(j["depth_source"]["container"], "dynamic-depth", "{j}");
    assert!(j["warnings"].as_array().unwrap().iter().any(|w| w.as_str().unwrap().contains("GDepth")), "{j}");
}

/// Every bad Dynamic Depth file exits 2 from `render` and `inspect`, naming the photo and the
/// field; never a panic, never a render without depth.
#[test]
fn bad_dynamic_depth_exits_2_naming_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (photo, png, near, far) = small();
    let conf = confidence_png(24, 16);
    let good = DynamicDepthJpeg::new(photo.clone(), "RangeInverse", near, far, "image/png", &png, &conf);
    let square = grey_png(&Image::filled(16, 16, 1, 0.5), 8);
    let with_payload = |p: &[u8]| {
        let mut g = good.clone().item_field(2, "Length", Some(&p.len().to_string()));
        g.items[2].payload = p.to_vec();
        g
    };
    let cut = {
        let b = good.bytes();
        b[..b.len() - png.len() / 2].to_vec()
    };
    let long = (png.len() + 1000).to_string();
    // Where the item starts, counted from the primary image's end: after the confidence map.
    let from = format!("from byte {} of the {} bytes", conf.len(), conf.len() + png.len());
    // The same length, so the APP1 segment's length still holds: the XMP then has no directory.
    let undirected = {
        let mut b = good.bytes();
        let (tag, other) = (b"Container:Directory", b"Container:Directorz");
        while let Some(k) = b.windows(tag.len()).position(|w| w == tag) {
            b[k..k + tag.len()].copy_from_slice(other);
        }
        b
    };
    let cases: Vec<(&str, Vec<u8>, Vec<&str>)> = vec![
        ("file cut inside the depth item", cut, vec!["Container:Item 2", "android/depthmap", "beyond the file's end"]),
        (
            "length beyond the end",
            good.clone().item_field(2, "Length", Some(&long)).bytes(),
            vec!["Container:Item 2", "Item:Length", &from],
        ),
        ("no directory", undirected, vec!["DepthMap", "no Container:Directory"]),
        (
            "depth URI names no item",
            good.clone().depth_field("DepthURI", Some("android/nothing")).bytes(),
            vec!["DepthMap:DepthURI", "android/nothing", "android/depthmap"],
        ),
        (
            "two items with the URI",
            good.clone().item_field(1, "DataURI", Some("android/depthmap")).bytes(),
            vec!["DepthMap:DepthURI", "2 Container:Items"],
        ),
        (
            "the primary as the depth map",
            good.clone().depth_field("DepthURI", Some("primary_image")).bytes(),
            vec!["Container:Item 0", "primary image"],
        ),
        ("missing depth URI", good.clone().depth_field("DepthURI", None).bytes(), vec!["DepthMap:DepthURI"]),
        ("length not a number", good.clone().item_field(1, "Length", Some("12k")).bytes(), vec!["Container:Item 1 Item:Length", "12k"]),
        ("missing length", good.clone().item_field(1, "Length", None).bytes(), vec!["Container:Item 1 Item:Length", "missing"]),
        ("missing mime", good.clone().item_field(2, "Mime", None).bytes(), vec!["Container:Item 2 Item:Mime"]),
        (
            "padding as long as the item",
            good.clone().item_field(2, "Padding", Some(&png.len().to_string())).bytes(),
            vec!["Item:Padding", "Item:Length"],
        ),
        (
            "mime disagrees with data",
            good.clone().item_field(2, "Mime", Some("image/jpeg")).bytes(),
            vec!["Container:Item 2", "Item:Mime", "image/jpeg"],
        ),
        ("unknown mime", good.clone().item_field(2, "Mime", Some("image/webp")).bytes(), vec!["Item:Mime", "image/webp"]),
        ("other aspect ratio", with_payload(&square).bytes(), vec!["Container:Item 2", "16x16", "48x32", "aspect ratio"]),
        (
            "100000x100000 header",
            with_payload(&gdepth::png_claiming(100_000, 100_000)).bytes(),
            vec!["Container:Item 2", "100000x100000", "limit"],
        ),
        (
            "near above far",
            good.clone().depth_field("Near", Some("4")).depth_field("Far", Some("1")).bytes(),
            vec!["DepthMap:Near", "DepthMap:Far"],
        ),
        ("NaN far", good.clone().depth_field("Far", Some("NaN")).bytes(), vec!["DepthMap:Far"]),
        ("unknown format", good.clone().depth_field("Format", Some("RangeLog")).bytes(), vec!["DepthMap:Format", "RangeLog"]),
        ("missing format", good.clone().depth_field("Format", None).bytes(), vec!["DepthMap:Format"]),
        (
            "no end of the primary image",
            {
                // The photo cut before its end-of-image marker, the items gone with it.
                let b = good.bytes();
                b[..b.len() - png.len() - conf.len() - 2].to_vec()
            },
            vec!["end-of-image"],
        ),
    ];
    for (i, (what, bytes, needles)) in cases.iter().enumerate() {
        let name = format!("dd_bad{i}.jpg");
        std::fs::write(d.join(&name), bytes).unwrap();
        let mut all = needles.clone();
        all.push(&name);
        assert_usage_error(d, &format!("render: {what}"), &all, || drbokeh(d, &["render", &name, "--focus", "0.5", "-o", "out.png"]));
        assert_usage_error(d, &format!("inspect: {what}"), &all, || drbokeh(d, &["inspect", &name, "--json"]));
    }
    // Format is compared without case, as the reference reader does; a Segmentation map is
    // not a depth map (the file embeds none, and says so).
    std::fs::write(d.join("lower.jpg"), good.clone().depth_field("Format", Some("rangeinverse")).bytes()).unwrap();
    let j = ok_json(d, &["inspect", "lower.jpg", "--json"]);
    assert_eq!(j["depth"]["format"], "RangeInverse", "{j}");
    // The primary image takes no room after itself, so its Padding is not checked against its
    // Length; an item of no bytes (no padding either) is allowed where it is not the depth map.
    let mut empty = good.clone().item_field(0, "Padding", Some("4"));
    let nothing = Item {
        fields: vec![("Mime".into(), "image/png".into()), ("Length".into(), "0".into()), ("DataURI".into(), "android/empty".into())],
        payload: Vec::new(),
    };
    empty.items.insert(1, nothing);
    std::fs::write(d.join("empty.jpg"), empty.bytes()).unwrap();
    let j = ok_json(d, &["inspect", "empty.jpg", "--json"]);
    assert_eq!(j["depth"]["container"], "dynamic-depth", "{j}");
    std::fs::write(d.join("seg.jpg"), good.clone().depth_field("ItemSemantic", Some("Segmentation")).bytes()).unwrap();
    let j = ok_json(d, &["inspect", "seg.jpg", "--json"]);
    assert!(j["depth"].is_null(), "{j}");
}

/// ExifTool reads our Dynamic Depth files' structures (the directory's items and the depth
/// map's fields) with no warning: the test writer follows the specification as ExifTool does.
#[test]
fn exiftool_reads_our_dynamic_depth_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (photo, png, near, far) = small();
    let conf = confidence_png(24, 16);
    let g = DynamicDepthJpeg::new(photo, "RangeInverse", near, far, "image/png", &png, &conf);
    let mut e = g.clone();
    e.elements = true;
    std::fs::write(d.join("attributes.jpg"), g.bytes()).unwrap();
    std::fs::write(d.join("elements.jpg"), e.bytes()).unwrap();
    for file in ["attributes.jpg", "elements.jpg"] {
        let out = run_exiftool(d, &["-j", "-n", "-struct", "-XMP-Device:all", "-Warning", file]);
        let j: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let t = &j[0];
        assert!(t.get("Warning").is_none(), "{file}: ExifTool warns: {t}");
        let items = t["Container"]["Directory"].as_array().unwrap_or_else(|| panic!("{file}: no directory: {t}"));
        let got: Vec<(String, u64, String)> = items
            .iter()
            .map(|i| {
                let i = &i["Item"];
                (i["Mime"].as_str().unwrap().to_owned(), i["Length"].as_u64().unwrap(), i["DataURI"].as_str().unwrap().to_owned())
            })
            .collect();
        assert_eq!(
            got,
            vec![
                ("image/jpeg".into(), 0, "primary_image".into()),
                ("image/png".into(), conf.len() as u64, "android/confidencemap".into()),
                ("image/png".into(), png.len() as u64, "android/depthmap".into()),
            ],
            "{file}: {t}"
        );
        let cameras = t["Cameras"].as_array().unwrap_or_else(|| panic!("{file}: no cameras: {t}"));
        let map = &cameras[0]["Camera"]["DepthMap"];
        assert_eq!(
            (map["Format"].as_str(), map["Near"].as_f64(), map["Far"].as_f64()),
            (Some("RangeInverse"), Some(near), Some(far)),
            "{file}: {t}"
        );
        assert_eq!(map["DepthURI"], "android/depthmap", "{file}: {t}");
    }
}

/// ExifTool writes the Dynamic Depth structures into a plain JPEG; the items' bytes are then
/// appended as the specification lays them out. drbokeh reads the map as the hand decode.
#[test]
fn drbokeh_reads_dynamic_depth_written_by_exiftool() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (rgb, z) = example();
    let (png, near, far, by_hand) = encode_map(&z, "RangeInverse", 120, 80, 8);
    let conf = confidence_png(120, 80);
    std::fs::write(d.join("plain.jpg"), photo_jpeg(&rgb)).unwrap();
    let container = format!(
        "-XMP-Device:Container={{Directory=[{{Item={{Mime=image/jpeg,Length=0,DataURI=primary_image}}}},\
         {{Item={{Mime=image/png,Length={},DataURI=android/confidencemap}}}},\
         {{Item={{Mime=image/png,Length={},DataURI=android/depthmap}}}}]}}",
        conf.len(),
        png.len()
    );
    let cameras = format!(
        "-XMP-Device:Cameras=[{{Camera={{DepthMap={{ItemSemantic=Depth,Format=RangeInverse,Near={near},Far={far},Units=Meters,\
         DepthURI=android/depthmap,ConfidenceURI=android/confidencemap,MeasureType=OpticalAxis}},\
         Image={{ItemSemantic=Primary,ItemURI=primary_image}}}}}}]"
    );
    run_exiftool(d, &["-o", "xmp.jpg", &container, &cameras, "plain.jpg"]);
    let mut b = std::fs::read(d.join("xmp.jpg")).unwrap();
    b.extend(&conf);
    b.extend(&png);
    std::fs::write(d.join("dd.jpg"), b).unwrap();
    let j = ok_json(d, &["inspect", "dd.jpg", "--json", "--extract-depth", "depth.exr"]);
    let depth = &j["depth"];
    assert_eq!((depth["container"].as_str(), depth["format"].as_str()), (Some("dynamic-depth"), Some("RangeInverse")), "{j}");
    assert_eq!((depth["near"].as_f64(), depth["far"].as_f64()), (Some(near), Some(far)), "{j}");
    let got = io::read_depth(&d.join("depth.exr"), &ReadLimits::default()).unwrap();
    let worst = got.data.iter().zip(&by_hand.data).map(|(a, b)| ((a - b) / b).abs()).fold(0f32, f32::max);
    assert!(worst < 1e-6, "ExifTool-written Dynamic Depth map decodes {worst} (relative) off the hand decode");
    let r = ok_json(d, &["render", "dd.jpg", "--focus", "0", "-o", "o.png", "--json"]);
    assert_eq!(r["depth_source"]["container"], "dynamic-depth", "{r}");
}
