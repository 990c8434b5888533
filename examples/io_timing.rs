//! Wall-clock timing of drbokeh's own image readers and writers on a photo-sized image:
//!
//! `cargo run --release --example io_timing -- WIDTH HEIGHT RUNS [--dir DIR] [--only NAME,NAME..] [--keep]`
//!
//! Generates a deterministic photo-like linear RGB image (smooth shading, texture and per-pixel
//! noise of about 1 level in 8 bits, like a camera's: a noiseless synthetic image compresses far
//! better than a photo and would flatter the PNG codec) and writes it in every input format into
//! DIR (default `out/io-timing-WxH`): `png8.png`, `png16.png`, `jpeg.jpg` (quality 92),
//! `tiff8.tif`, `tiff16.tif` (uncompressed), `exr32.exr` (float, drbokeh's writer) and
//! `exr16.exr` (half), `exr32zip.exr` (float, ZIP16 through the `exr` crate). The JPEG, TIFF and half EXR files are made with the `image` / `exr`
//! crates (drbokeh writes none of them). `scripts/io_timing_ref.py` reads and writes the same
//! files with Pillow and OpenCV.
//!
//! Then times, RUNS times each, one case after the other in one process:
//! - `read NAME`: [`read_photo`] with the sRGB transfer (what `drbokeh render` does with a photo:
//!   decode, scale, sRGB to linear, finiteness check);
//! - `write png8` / `write png16`: [`write_png`] (sRGB, atomic), `write exr32`: [`write_exr`].
//!
//! Prints one line per case: `CASE  median ms  min ms  file size`, and `--only` restricts the
//! cases to those whose name contains one of the comma-separated words.

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{ReadLimits, read_photo, write_exr, write_png};
use image::{ImageEncoder, codecs::jpeg::JpegEncoder, codecs::tiff::TiffEncoder};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// SplitMix64 finaliser: a deterministic hash of the sample index (the noise's source), so
/// the image is the same whatever the thread count.
fn hash(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Linear RGB in [0, ~1]: diagonal shading, a few soft discs, a fine texture, and noise of
/// about ±1 8-bit level (uniform, ±0.004 in sRGB terms).
fn photo(w: usize, h: usize) -> Image {
    let mut img = Image::new(w, h, 3);
    img.data.par_chunks_mut(w * 3).enumerate().for_each(|(y, row)| {
        let v = y as f32 / h as f32;
        for x in 0..w {
            let u = x as f32 / w as f32;
            let disc = |cx: f32, cy: f32, r: f32| (1.0 - (((u - cx).powi(2) + (v - cy).powi(2)).sqrt() / r)).clamp(0.0, 1.0);
            let tex = 0.04 * ((x as f32 * 0.21).sin() * (y as f32 * 0.17).cos());
            let base = [
                0.15 + 0.5 * u * v + 0.6 * disc(0.3, 0.4, 0.2),
                0.2 + 0.3 * (1.0 - u) + 0.4 * disc(0.7, 0.6, 0.25),
                0.1 + 0.4 * v + 0.3 * disc(0.5, 0.2, 0.15),
            ];
            for (c, b) in base.iter().enumerate() {
                let i = (y * w + x) * 3 + c;
                let n = (hash(i as u64) >> 40) as f32 / (1u64 << 24) as f32 - 0.5;
                let srgb = Transfer::Srgb.encode((b + tex).clamp(0.0, 1.0)) + n * 0.008;
                row[x * 3 + c] = Transfer::Srgb.decode(srgb.clamp(0.0, 1.0));
            }
        }
    });
    img
}

/// Writes the input files the `read` cases time (see the module doc).
fn make_files(dir: &Path, img: &Image) {
    std::fs::create_dir_all(dir).unwrap();
    write_png(&dir.join("png8.png"), img, 8, Transfer::Srgb).unwrap();
    write_png(&dir.join("png16.png"), img, 16, Transfer::Srgb).unwrap();
    write_exr(&dir.join("exr32.exr"), img, &["R", "G", "B"]).unwrap();
    let (w, h) = (img.width as u32, img.height as u32);
    let q8: Vec<u8> = img.data.iter().map(|&v| (Transfer::Srgb.encode(v).clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    let q16: Vec<u16> = img.data.iter().map(|&v| (Transfer::Srgb.encode(v).clamp(0.0, 1.0) * 65535.0).round() as u16).collect();
    let file = |n: &str| std::io::BufWriter::new(std::fs::File::create(dir.join(n)).unwrap());
    JpegEncoder::new_with_quality(file("jpeg.jpg"), 92).write_image(&q8, w, h, image::ExtendedColorType::Rgb8).unwrap();
    TiffEncoder::new(file("tiff8.tif")).write_image(&q8, w, h, image::ExtendedColorType::Rgb8).unwrap();
    let b16: Vec<u8> = q16.iter().flat_map(|v| v.to_ne_bytes()).collect();
    TiffEncoder::new(file("tiff16.tif")).write_image(&b16, w, h, image::ExtendedColorType::Rgb16).unwrap();
    let (iw, c) = (img.width, img.channels);
    let px = |x: usize, y: usize, k: usize| exr::prelude::f16::from_f32(img.data[(y * iw + x) * c + k]);
    exr::prelude::write_rgb_file(dir.join("exr16.exr"), img.width, img.height, |x, y| (px(x, y, 0), px(x, y, 1), px(x, y, 2))).unwrap();
    // Float with ZIP16 (what most tools write): decompression-bound to read.
    {
        use exr::prelude::*;
        let ch = |k: usize, n: &str| AnyChannel::new(n, FlatSamples::F32(img.data.iter().skip(k).step_by(c).copied().collect()));
        let enc = Encoding { compression: Compression::ZIP16, blocks: Blocks::ScanLines, line_order: LineOrder::Increasing };
        let layer = Layer::new(
            (img.width, img.height),
            LayerAttributes::default(),
            enc,
            AnyChannels::sort(SmallVec::from_vec(vec![ch(0, "R"), ch(1, "G"), ch(2, "B")])),
        );
        exr::prelude::Image::from_layer(layer).write().to_file(dir.join("exr32zip.exr")).unwrap();
    }
}

/// Median and minimum of `runs` timings of `f`, in milliseconds.
fn time(runs: usize, mut f: impl FnMut()) -> (f64, f64) {
    let mut t: Vec<f64> = (0..runs)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    t.sort_by(f64::total_cmp);
    (t[t.len() / 2], t[0])
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let usage = "usage: io_timing WIDTH HEIGHT RUNS [--dir DIR] [--only NAME,NAME..] [--keep]";
    let num = |i: usize| args.get(i).and_then(|s| s.parse::<usize>().ok()).expect(usage);
    let (w, h, runs) = (num(0), num(1), num(2).max(1));
    let opt = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).cloned();
    let dir = PathBuf::from(opt("--dir").unwrap_or(format!("out/io-timing-{w}x{h}")));
    let only: Vec<String> = opt("--only").map(|s| s.split(',').map(str::to_owned).collect()).unwrap_or_default();
    let wanted = |case: &str| only.is_empty() || only.iter().any(|o| case.contains(o.as_str()));

    let img = photo(w, h);
    // `--keep` reuses the files of an earlier run (so two builds read the same bytes).
    if !(args.iter().any(|a| a == "--keep") && dir.join("exr32zip.exr").exists()) {
        make_files(&dir, &img);
    }
    let size = |n: &str| std::fs::metadata(dir.join(n)).map(|m| m.len() as f64 / 1e6).unwrap_or(0.0);
    println!("{w}x{h} ({:.1} MP), median of {runs}, {} threads", (w * h) as f64 / 1e6, rayon::current_num_threads());
    let limits = ReadLimits::default();
    for name in ["png8.png", "png16.png", "jpeg.jpg", "tiff8.tif", "tiff16.tif", "exr32.exr", "exr32zip.exr", "exr16.exr"] {
        let case = format!("read {}", name.split('.').next().unwrap());
        if !wanted(&case) {
            continue;
        }
        let path = dir.join(name);
        let (med, min) = time(runs, || {
            std::hint::black_box(read_photo(&path, Transfer::Srgb, &limits).unwrap());
        });
        println!("{case:14} {med:9.1} ms {min:9.1} ms {:8.1} MB", size(name));
    }
    let out = dir.join("written");
    std::fs::create_dir_all(&out).unwrap();
    for (case, file) in [("write png8", "png8.png"), ("write png16", "png16.png"), ("write exr32", "exr32.exr")] {
        if !wanted(case) {
            continue;
        }
        let path = out.join(file);
        let (med, min) = time(runs, || match case {
            "write png8" => write_png(&path, &img, 8, Transfer::Srgb).unwrap(),
            "write png16" => write_png(&path, &img, 16, Transfer::Srgb).unwrap(),
            _ => write_exr(&path, &img, &["R", "G", "B"]).unwrap(),
        });
        let mb = std::fs::metadata(&path).map(|m| m.len() as f64 / 1e6).unwrap_or(0.0);
        println!("{case:14} {med:9.1} ms {min:9.1} ms {mb:8.1} MB");
    }
}
