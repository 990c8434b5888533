//! Integration tests of `drbokeh::io`: round trips for every format and channel layout,
//! colour decoding, depth/matte/layer channel rules, and every error path (missing, garbage,
//! truncated, empty, oversized files; atomic writes).

use crate::common;
use common::crc32;

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{
    self, Encoding, FileFormat, OutputFormat, ReadLimits, read_decoded, read_depth, read_depth_map, read_layer, read_matte, read_photo,
    write_exr, write_output, write_png,
};
use std::path::{Path, PathBuf};

fn lim() -> ReadLimits {
    ReadLimits::default()
}

fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// Deterministic test pattern in [0, 1].
fn pattern(w: usize, h: usize, c: usize) -> Image {
    let data = (0..w * h * c).map(|i| ((i * 37 + 11) % 101) as f32 / 100.0).collect();
    Image::from_vec(w, h, c, data).unwrap()
}

fn assert_close(a: &[f32], b: &[f32], tol: f32) {
    assert_eq!(a.len(), b.len());
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!((x - y).abs() <= tol, "sample {i}: {x} vs {y} (tol {tol})");
    }
}

fn err_of<T: std::fmt::Debug>(r: drbokeh::Result<T>) -> String {
    r.expect_err("expected an error").to_string()
}

fn save_npy(path: &Path, img: &Image) {
    io::save_npy(path, img).unwrap();
}

/// Writes an NPY file with an arbitrary shape (little-endian float32).
fn raw_npy(path: &Path, shape: &[u64], data: &[f32]) {
    use npyz::WriterBuilder;
    let mut buf = Vec::new();
    let mut w = npyz::WriteOptions::new().default_dtype().shape(shape).writer(&mut buf).begin_nd().unwrap();
    w.extend(data.iter().copied()).unwrap();
    w.finish().unwrap();
    std::fs::write(path, buf).unwrap();
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend_from_slice(&(data.len() as u32).to_be_bytes());
    let mut body = kind.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
}

/// A PNG with a valid signature and IHDR claiming `w x h` RGB 8-bit, a tiny IDAT and IEND.
fn png_header_only(w: u32, h: u32) -> Vec<u8> {
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&w.to_be_bytes());
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(&mut out, b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    png_chunk(&mut out, b"IEND", &[]);
    out
}

fn write_tiff<C: tiff::encoder::colortype::ColorType>(path: &Path, w: u32, h: u32, data: &[C::Inner])
where
    [C::Inner]: tiff::encoder::TiffValue,
{
    let f = std::fs::File::create(path).unwrap();
    let mut enc = tiff::encoder::TiffEncoder::new(f).unwrap();
    enc.write_image::<C>(w, h, data).unwrap();
}

fn list_dir(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

// ---------------------------------------------------------------------------------------------
// PNG

#[test]
fn png_round_trip_all_layouts_8_and_16_bit() {
    let dir = tmp();
    for channels in 1..=4 {
        for bits in [8u8, 16] {
            let img = pattern(7, 5, channels);
            let p = dir.path().join(format!("c{channels}_{bits}.png"));
            write_png(&p, &img, bits, Transfer::Linear).unwrap();
            let d = read_decoded(&p, &lim()).unwrap();
            assert_eq!(d.format, FileFormat::Png);
            assert_eq!(d.encoding, Encoding::Display);
            assert_eq!(d.bit_depth, bits);
            assert_eq!(d.has_alpha, matches!(channels, 2 | 4));
            assert_eq!((d.image.width, d.image.height, d.image.channels), (7, 5, channels));
            let max = if bits == 8 { 255.0 } else { 65535.0 };
            assert_close(&d.image.data, &img.data, 0.5 / max + 1e-7);
        }
    }
}

#[test]
fn png_srgb_round_trip_through_write_and_read_photo() {
    let dir = tmp();
    let img = pattern(6, 4, 3);
    let p = dir.path().join("srgb.png");
    write_png(&p, &img, 16, Transfer::Srgb).unwrap();
    let back = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert_close(&back.data, &img.data, 2e-4);
}

/// The table-driven, parallel quantizer and the direct integer-to-linear read are exact: a
/// noisy image spanning several parallel blocks (300 x 500 RGBA, values in [-0.1, 1.1] with
/// NaN) is written as 8 and 16-bit sRGB PNG; the `image` crate (an independent reader) finds
/// exactly the levels of the plain formula, and `read_photo` returns exactly
/// `srgb_to_linear(level / max)` for them.
#[test]
fn png_srgb_levels_exact_against_the_formula_and_an_independent_reader() {
    let dir = tmp();
    let (w, h) = (300, 500);
    let mut img = Image::new(w, h, 4);
    let mut x = 0x2545_F491_4F6C_DD1Du64;
    for v in img.data.iter_mut() {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        *v = (x >> 40) as f32 / (1u64 << 24) as f32 * 1.2 - 0.1;
    }
    img.data[5] = f32::NAN;
    for bits in [8u8, 16] {
        let max = if bits == 8 { 255.0f32 } else { 65535.0 };
        let level = |k: usize, v: f32| {
            let e = if k == 3 { v } else { Transfer::Srgb.encode(v) };
            (if e.is_nan() { 0.0 } else { e.clamp(0.0, 1.0) } * max).round()
        };
        let want: Vec<f32> = img.data.iter().enumerate().map(|(i, &v)| level(i % 4, v)).collect();
        let p = dir.path().join(format!("noisy{bits}.png"));
        write_png(&p, &img, bits, Transfer::Srgb).unwrap();
        let got: Vec<f32> = match image::open(&p).unwrap() {
            image::DynamicImage::ImageRgba8(b) => b.into_raw().into_iter().map(f32::from).collect(),
            image::DynamicImage::ImageRgba16(b) => b.into_raw().into_iter().map(f32::from).collect(),
            other => panic!("unexpected layout {:?}", other.color()),
        };
        assert!(got == want, "{bits}-bit levels differ from the formula");
        let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
        let expect: Vec<f32> = want.chunks(4).flat_map(|px| px[..3].iter().map(|&q| Transfer::Srgb.decode(q / max))).collect();
        assert!(photo.data == expect, "{bits}-bit read_photo differs from decode(level / max)");
    }
}

#[test]
fn srgb_decode_of_8_bit_128() {
    let dir = tmp();
    let p = dir.path().join("grey128.png");
    image::GrayImage::from_pixel(3, 2, image::Luma([128u8])).save(&p).unwrap();
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert_eq!((photo.width, photo.height, photo.channels), (3, 2, 3), "grey is expanded to RGB");
    for &v in &photo.data {
        assert!((v - 0.2158605).abs() < 1e-6, "{v}");
    }
    let gamma = read_photo(&p, Transfer::Gamma(2.2), &lim()).unwrap();
    let expect = (128.0f32 / 255.0).powf(2.2);
    assert!((gamma.data[0] - expect).abs() < 1e-6);
    let linear = read_photo(&p, Transfer::Linear, &lim()).unwrap();
    assert_eq!(linear.data[0], 128.0 / 255.0);
}

#[test]
fn photo_drops_alpha() {
    let dir = tmp();
    let p = dir.path().join("rgba.png");
    image::RgbaImage::from_pixel(2, 2, image::Rgba([255, 0, 255, 10])).save(&p).unwrap();
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert_eq!(photo.channels, 3);
    assert_eq!(&photo.data[..3], &[1.0, 0.0, 1.0]);
}

#[test]
fn png_16_bit_precision_is_kept() {
    let dir = tmp();
    let p = dir.path().join("deep.png");
    // Neighbouring 16-bit codes that collapse to one value in 8 bits.
    let codes: Vec<u16> = (0..12).map(|i| 30000 + i).collect();
    image::ImageBuffer::<image::Luma<u16>, _>::from_raw(4, 3, codes.clone()).unwrap().save(&p).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!(d.bit_depth, 16);
    for (v, q) in d.image.data.iter().zip(&codes) {
        assert_eq!(*v, *q as f32 / 65535.0);
    }
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    let mut distinct: Vec<f32> = photo.data.iter().step_by(3).copied().collect();
    distinct.dedup();
    assert_eq!(distinct.len(), 12, "16-bit codes must stay distinct after sRGB decoding");
    for (v, q) in photo.data.iter().step_by(3).zip(&codes) {
        assert!((v - drbokeh::color::srgb_to_linear(*q as f32 / 65535.0)).abs() < 1e-7);
    }
    // And as a depth map: value / 65535.
    let depth = read_depth_map(&p, &lim()).unwrap();
    assert_eq!(depth.bit_depth, 16);
    assert_eq!(depth.image.data[5], 30005.0 / 65535.0);
}

/// The row-by-row PNG route of `read_photo` and `read_decoded` (decoded bands converted while
/// the next is decoded) against the whole-image route (the `image` crate's samples, scaled, then
/// the transfer per value), bit for bit: every colour type at every bit depth, with and without
/// `tRNS`, three transfers, on a frame of several bands (32 rows each) with a partial last band.
#[test]
fn png_rows_equal_the_whole_image_route() {
    use png::{BitDepth as B, ColorType as C};
    let dir = tmp();
    let (w, h) = (37u32, 75u32);
    let mut rng = common::Rng::new(11);
    let cases: &[(C, B, Option<&[u8]>)] = &[
        (C::Grayscale, B::One, None),
        (C::Grayscale, B::Two, None),
        (C::Grayscale, B::Four, Some(&[0, 3])),
        (C::Grayscale, B::Eight, None),
        (C::Grayscale, B::Eight, Some(&[0, 40])),
        (C::Grayscale, B::Sixteen, None),
        (C::GrayscaleAlpha, B::Eight, None),
        (C::GrayscaleAlpha, B::Sixteen, None),
        (C::Rgb, B::Eight, None),
        (C::Rgb, B::Eight, Some(&[0, 9, 0, 9, 0, 9])),
        (C::Rgb, B::Sixteen, None),
        (C::Rgba, B::Eight, None),
        (C::Rgba, B::Sixteen, None),
        (C::Indexed, B::One, None),
        (C::Indexed, B::Four, Some(&[0, 128, 255])),
        (C::Indexed, B::Eight, None),
    ];
    for (k, &(colour, depth, trns)) in cases.iter().enumerate() {
        let bits = depth as usize;
        let row_bytes = (w as usize * colour.samples() * bits).div_ceil(8);
        let data: Vec<u8> = (0..row_bytes * h as usize).map(|_| (rng.next_f32() * 256.0) as u8).collect();
        let p = dir.path().join(format!("v{k}.png"));
        {
            let mut enc = png::Encoder::new(std::io::BufWriter::new(std::fs::File::create(&p).unwrap()), w, h);
            enc.set_color(colour);
            enc.set_depth(depth);
            if colour == C::Indexed {
                enc.set_palette((0..768).map(|i| (i * 7 % 256) as u8).collect::<Vec<u8>>());
            }
            if let Some(t) = trns {
                enc.set_trns(t.to_vec());
            }
            enc.write_header().unwrap().write_image_data(&data).unwrap();
        }
        // The whole-image route: the `image` crate's samples, scaled to [0, 1].
        let whole = image::open(&p).unwrap();
        let c = whole.color().channel_count() as usize;
        let (scaled, bits): (Vec<f32>, u8) = match whole.color().bytes_per_pixel() as usize / c {
            1 => (whole.as_bytes().iter().map(|&q| q as f32 / 255.0).collect(), 8),
            _ => (whole.as_bytes().as_chunks::<2>().0.iter().map(|&q| u16::from_ne_bytes(q) as f32 / 65535.0).collect(), 16),
        };
        let decoded = read_decoded(&p, &lim()).unwrap();
        assert_eq!((decoded.image.channels, decoded.bit_depth, decoded.has_alpha), (c, bits, matches!(c, 2 | 4)));
        assert!(decoded.image.data == scaled, "{colour:?} {depth:?} tRNS {trns:?}: read_decoded differs");
        let which: &[usize] = if c < 3 { &[0, 0, 0] } else { &[0, 1, 2] };
        for transfer in [Transfer::Srgb, Transfer::Gamma(2.2), Transfer::Linear] {
            let expect: Vec<f32> = scaled.chunks(c).flat_map(|px| which.iter().map(|&i| transfer.decode(px[i]))).collect();
            let rows = read_photo(&p, transfer, &lim()).unwrap();
            assert_eq!((rows.width, rows.height, rows.channels), (w as usize, h as usize, 3));
            assert!(rows.data == expect, "{colour:?} {depth:?} tRNS {trns:?} {transfer:?}: read_photo differs");
        }
    }
}

/// A PNG cut at any byte reads (or fails) as the whole-image route through the `image` crate
/// decides: the row-by-row route neither accepts a stream the other refuses (cut inside the
/// compressed data's checksum, say) nor refuses one it accepts, and it never panics.
#[test]
fn png_cut_anywhere_reads_as_the_image_crate_decides() {
    let dir = tmp();
    let src = dir.path().join("whole.png");
    write_png(&src, &pattern(9, 40, 3), 16, Transfer::Srgb).unwrap();
    let bytes = std::fs::read(&src).unwrap();
    let p = dir.path().join("cut.png");
    for cut in 8..=bytes.len() {
        std::fs::write(&p, &bytes[..cut]).unwrap();
        let whole = image::open(&p).is_ok();
        match read_photo(&p, Transfer::Srgb, &lim()) {
            Ok(_) => assert!(whole, "cut at {cut} of {}: read, the image crate refuses it", bytes.len()),
            Err(e) => {
                let e = e.to_string();
                assert!(!whole, "cut at {cut} of {}: refused ({e}), the image crate reads it", bytes.len());
                assert!(e.contains("cut.png") && !e.contains("panicked"), "{e}");
            }
        }
    }
    // Bytes changed at random (chunk CRCs left stale, or fixed so the corruption reaches the
    // decoder): the same answer as the image crate, and the same pixels when both read.
    let mut rng = common::Rng::new(5);
    let (mut read, mut refused) = (0, 0);
    for k in 0..400 {
        let mut b = bytes.clone();
        let i = 8 + (rng.next_f32() * (b.len() - 8) as f32) as usize % (b.len() - 8);
        b[i] ^= 1 << (k % 8);
        if k % 2 == 1 {
            // Recompute every chunk's CRC so the change is judged by the decoder, not the CRC.
            let mut at = 8;
            while at + 12 <= b.len() {
                let len = u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as usize;
                if at + 12 + len > b.len() {
                    break;
                }
                let crc = crc32(&b[at + 4..at + 8 + len]);
                b[at + 8 + len..at + 12 + len].copy_from_slice(&crc.to_be_bytes());
                at += 12 + len;
            }
        }
        std::fs::write(&p, &b).unwrap();
        let whole = image::open(&p).ok();
        match (read_photo(&p, Transfer::Linear, &lim()), whole) {
            (Ok(rows), Some(w)) => {
                let want: Vec<f32> = w.to_rgb16().into_raw().iter().map(|&q| q as f32 / 65535.0).collect();
                assert!(rows.data == want, "flip {k} at byte {i}: the two routes read different pixels");
                read += 1;
            }
            (Err(e), None) => {
                assert!(!e.to_string().contains("panicked"), "{e}");
                refused += 1;
            }
            (r, w) => panic!("flip {k} at byte {i}: read_photo {:?}, image crate {}", r.map(|_| ()), w.is_some()),
        }
    }
    assert!(read > 20 && refused > 20, "both outcomes must be exercised: {read} read, {refused} refused");
}

/// An interlaced (Adam7) PNG is read whole, not row by row: the same pixels as the same image
/// stored plainly. The file is built by hand (the `png` encoder writes no Adam7): each pass's
/// rows with filter byte 0, in one stored (uncompressed) deflate block.
#[test]
fn interlaced_png_photo_reads_as_the_plain_one() {
    let dir = tmp();
    let (w, h) = (13usize, 11usize);
    let px = |x: usize, y: usize| [(x * 19) as u8, (y * 23) as u8, (x * y) as u8];
    let mut raw = Vec::new();
    for (x0, y0, dx, dy) in [(0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2), (0, 1, 1, 2)] {
        if x0 >= w {
            continue;
        }
        for y in (y0..h).step_by(dy) {
            raw.push(0);
            for x in (x0..w).step_by(dx) {
                raw.extend_from_slice(&px(x, y));
            }
        }
    }
    let adler = {
        let (mut a, mut b) = (1u32, 0u32);
        for &v in &raw {
            a = (a + v as u32) % 65521;
            b = (b + a) % 65521;
        }
        (b << 16) | a
    };
    let mut z = vec![0x78, 0x01, 0x01];
    z.extend_from_slice(&(raw.len() as u16).to_le_bytes());
    z.extend_from_slice(&(!(raw.len() as u16)).to_le_bytes());
    z.extend_from_slice(&raw);
    z.extend_from_slice(&adler.to_be_bytes());
    let mut file = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&(w as u32).to_be_bytes());
    ihdr.extend_from_slice(&(h as u32).to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 1]);
    png_chunk(&mut file, b"IHDR", &ihdr);
    png_chunk(&mut file, b"IDAT", &z);
    png_chunk(&mut file, b"IEND", &[]);
    let interlaced = dir.path().join("adam7.png");
    std::fs::write(&interlaced, &file).unwrap();
    let plain = dir.path().join("plain.png");
    let rgb: Vec<u8> = (0..h).flat_map(|y| (0..w).flat_map(move |x| px(x, y))).collect();
    image::RgbImage::from_raw(w as u32, h as u32, rgb).unwrap().save(&plain).unwrap();
    let a = read_photo(&interlaced, Transfer::Srgb, &lim()).unwrap();
    let b = read_photo(&plain, Transfer::Srgb, &lim()).unwrap();
    assert_eq!((a.width, a.height), (w, h));
    assert!(a.data == b.data, "the interlaced file reads differently");
    // Cut inside its pixel data, it is corrupt, whichever route reads it.
    let cut = dir.path().join("adam7_cut.png");
    std::fs::write(&cut, &file[..file.len() - 120]).unwrap();
    let e = err_of(read_photo(&cut, Transfer::Srgb, &lim()));
    assert!(e.contains("adam7_cut.png") && e.contains("corrupt or truncated PNG"), "{e}");
}

#[test]
fn eight_bit_depth_exposes_its_bit_depth() {
    let dir = tmp();
    let p = dir.path().join("depth8.png");
    image::GrayImage::from_fn(4, 4, |x, y| image::Luma([(x * 10 + y) as u8])).save(&p).unwrap();
    let d = read_depth_map(&p, &lim()).unwrap();
    assert_eq!(d.bit_depth, 8);
    assert_eq!(d.image.channels, 1);
    assert_eq!(d.image.data[1], 10.0 / 255.0);
}

#[test]
fn depth_from_grey_rgb_is_accepted_but_colour_is_refused() {
    let dir = tmp();
    let grey = dir.path().join("grey_rgb.png");
    image::RgbImage::from_fn(3, 3, |x, _| image::Rgb([x as u8 * 50; 3])).save(&grey).unwrap();
    let d = read_depth(&grey, &lim()).unwrap();
    assert_eq!(d.channels, 1);
    assert_eq!(d.data[2], 100.0 / 255.0);
    let colour = dir.path().join("colour.png");
    image::RgbImage::from_fn(3, 3, |x, _| image::Rgb([x as u8, 0, 9])).save(&colour).unwrap();
    let e = err_of(read_depth(&colour, &lim()));
    assert!(e.contains("colour.png") && e.contains("single-channel"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// JPEG

#[test]
fn jpeg_reads_as_8_bit_display() {
    let dir = tmp();
    let p = dir.path().join("photo.jpg");
    let rgb = image::RgbImage::from_pixel(16, 16, image::Rgb([200, 100, 50]));
    let mut f = std::fs::File::create(&p).unwrap();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut f, 100).encode_image(&rgb).unwrap();
    drop(f);
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!((d.format, d.bit_depth, d.encoding, d.image.channels), (FileFormat::Jpeg, 8, Encoding::Display, 3));
    assert_close(&d.image.data[..3], &[200.0 / 255.0, 100.0 / 255.0, 50.0 / 255.0], 3.0 / 255.0);
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert!((photo.data[0] - drbokeh::color::srgb_to_linear(d.image.data[0])).abs() < 1e-7);

    let gp = dir.path().join("grey.jpeg");
    image::GrayImage::from_pixel(8, 8, image::Luma([77])).save(&gp).unwrap();
    let g = read_decoded(&gp, &lim()).unwrap();
    assert_eq!(g.image.channels, 1);
    assert!((g.image.data[0] - 77.0 / 255.0).abs() <= 2.0 / 255.0);
}

// ---------------------------------------------------------------------------------------------
// TIFF

#[test]
fn tiff_integer_layouts_round_trip() {
    use tiff::encoder::colortype::*;
    let dir = tmp();
    let (w, h) = (5u32, 3u32);
    let n = (w * h) as usize;
    let g8: Vec<u8> = (0..n as u8).map(|v| v * 13).collect();
    let p = dir.path().join("g8.tif");
    write_tiff::<Gray8>(&p, w, h, &g8);
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!((d.format, d.bit_depth, d.image.channels, d.has_alpha), (FileFormat::Tiff, 8, 1, false));
    assert_eq!(d.image.data, g8.iter().map(|&v| v as f32 / 255.0).collect::<Vec<_>>());

    let rgb16: Vec<u16> = (0..3 * n as u16).map(|v| v * 1001 + 7).collect();
    let p = dir.path().join("rgb16.tiff");
    write_tiff::<RGB16>(&p, w, h, &rgb16);
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!((d.bit_depth, d.image.channels, d.encoding), (16, 3, Encoding::Display));
    assert_eq!(d.image.data, rgb16.iter().map(|&v| v as f32 / 65535.0).collect::<Vec<_>>());
    let photo = read_photo(&p, Transfer::Linear, &lim()).unwrap();
    assert_eq!(photo.data, d.image.data, "16-bit TIFF photo keeps 16-bit precision");

    let rgba8: Vec<u8> = (0..4 * n).map(|v| (v * 3) as u8).collect();
    let p = dir.path().join("rgba8.tif");
    write_tiff::<RGBA8>(&p, w, h, &rgba8);
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!((d.image.channels, d.has_alpha), (4, true));
    let m = read_matte(&p, &lim()).unwrap();
    assert_eq!(m.data, rgba8.iter().skip(3).step_by(4).map(|&v| v as f32 / 255.0).collect::<Vec<_>>());

    let g16: Vec<u16> = (0..n as u16).map(|v| v * 4000).collect();
    let p = dir.path().join("depth16.tif");
    write_tiff::<Gray16>(&p, w, h, &g16);
    let depth = read_depth_map(&p, &lim()).unwrap();
    assert_eq!(depth.bit_depth, 16);
    assert_eq!(depth.image.data, g16.iter().map(|&v| v as f32 / 65535.0).collect::<Vec<_>>());
}

#[test]
fn tiff_float_depth_and_photo() {
    use tiff::encoder::colortype::*;
    let dir = tmp();
    let depth: Vec<f32> = (0..12).map(|i| 0.5 + i as f32 * 1.25).collect();
    let p = dir.path().join("depth32.tif");
    write_tiff::<Gray32Float>(&p, 4, 3, &depth);
    let d = read_depth_map(&p, &lim()).unwrap();
    assert_eq!((d.bit_depth, d.image.width, d.image.height), (32, 4, 3));
    assert_eq!(d.image.data, depth, "float TIFF depth is raw");

    let rgb: Vec<f32> = (0..36).map(|i| i as f32 * 0.3 - 1.0).collect();
    let p = dir.path().join("hdr.tif");
    write_tiff::<RGB32Float>(&p, 4, 3, &rgb);
    let dec = read_decoded(&p, &lim()).unwrap();
    assert_eq!(dec.encoding, Encoding::Linear);
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert_eq!(photo.data, rgb, "float TIFF photo is kept linear, no transfer applied");
}

// ---------------------------------------------------------------------------------------------
// EXR

#[test]
fn exr_rgb_rgba_round_trip() {
    let dir = tmp();
    let mut img = pattern(9, 4, 3);
    img.data[0] = 1234.5; // HDR survives
    img.data[1] = -0.25;
    let p = dir.path().join("rgb.exr");
    write_exr(&p, &img, &["R", "G", "B"]).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!((d.format, d.encoding, d.bit_depth, d.has_alpha), (FileFormat::Exr, Encoding::Linear, 32, false));
    assert_eq!(d.image, img);
    assert_eq!(read_photo(&p, Transfer::Srgb, &lim()).unwrap(), img);

    let rgba = pattern(3, 5, 4);
    let p = dir.path().join("rgba.exr");
    write_exr(&p, &rgba, &["R", "G", "B", "A"]).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    assert!(d.has_alpha);
    assert_eq!(d.image, rgba);
    assert_eq!(read_matte(&p, &lim()).unwrap(), rgba.channel(3));
}

#[test]
fn exr_y_channel_depth() {
    let dir = tmp();
    let depth = Image::from_vec(4, 2, 1, (0..8).map(|i| 1.0 + i as f32 * 10.0).collect()).unwrap();
    let p = dir.path().join("depth.exr");
    write_exr(&p, &depth, &["Y"]).unwrap();
    let d = read_depth_map(&p, &lim()).unwrap();
    assert_eq!((d.format, d.bit_depth), (FileFormat::Exr, 32));
    assert_eq!(d.image, depth);
    // A grey EXR photo (Y only) expands to RGB.
    let photo = read_photo(&p, Transfer::Srgb, &lim()).unwrap();
    assert_eq!(photo.channels, 3);
    assert_eq!(photo.data[3..6], [11.0, 11.0, 11.0]);
}

#[test]
fn exr_depth_channel_priority_and_errors() {
    let dir = tmp();
    let z = Image::filled(3, 3, 1, 5.0);
    let y = Image::filled(3, 3, 1, 7.0);
    let r = Image::filled(3, 3, 1, 9.0);
    let p = dir.path().join("zyr.exr");
    write_exr(&p, &Image::stack(&[&r, &y, &z]), &["R", "Y", "Z"]).unwrap();
    assert_eq!(read_depth(&p, &lim()).unwrap().data[0], 5.0, "Z wins");
    let p = dir.path().join("yr.exr");
    write_exr(&p, &Image::stack(&[&r, &y]), &["R", "Y"]).unwrap();
    assert_eq!(read_depth(&p, &lim()).unwrap().data[0], 7.0, "then Y");
    let p = dir.path().join("single.exr");
    write_exr(&p, &r, &["distance"]).unwrap();
    assert_eq!(read_depth(&p, &lim()).unwrap().data[0], 9.0, "a single channel of any name");
    let p = dir.path().join("uv.exr");
    write_exr(&p, &Image::stack(&[&r, &y]), &["U", "V"]).unwrap();
    let e = err_of(read_depth(&p, &lim()));
    assert!(e.contains("uv.exr") && e.contains("U, V"), "{e}");
}

/// The parallel chunk reader gives what the `exr` crate's own reader gives, sample for
/// sample, for every compression, scan-line blocks and tiles (partial edge tiles included),
/// half / float / uint channels and both line orders.
#[test]
fn exr_parallel_reader_matches_the_crate_reader() {
    use exr::prelude::*;
    let dir = tmp();
    let (w, h) = (67usize, 45usize);
    let f = |i: usize, k: usize| ((i * 7 + k * 13) % 97) as f32 * 0.37 - 9.0;
    let compressions = [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
        Compression::B44A,
    ];
    for (n, compression) in compressions.into_iter().enumerate() {
        for blocks in [Blocks::ScanLines, Blocks::Tiles(Vec2(16, 8))] {
            for line_order in [LineOrder::Increasing, LineOrder::Decreasing] {
                // Half's special values among the samples (the reader converts halves by blocks).
                let specials = [f16::NAN, f16::INFINITY, f16::NEG_INFINITY, f16::MIN_POSITIVE_SUBNORMAL, f16::NEG_ZERO, f16::MAX];
                let half = |i: usize| if i % 53 < specials.len() { specials[i % 53] } else { f16::from_f32(f(i, 0)) };
                let channels = vec![
                    AnyChannel::new("B", FlatSamples::F16((0..w * h).map(half).collect())),
                    AnyChannel::new("G", FlatSamples::F32((0..w * h).map(|i| f(i, 1)).collect())),
                    AnyChannel::new("Z", FlatSamples::U32((0..w * h).map(|i| (i * 31 % 1000) as u32).collect())),
                ];
                let encoding = Encoding { compression, blocks, line_order };
                let layer = Layer::new((w, h), LayerAttributes::default(), encoding, AnyChannels::sort(SmallVec::from_vec(channels)));
                let p = dir.path().join(format!("c{n}.exr"));
                exr::prelude::Image::from_layer(layer).write().to_file(&p).unwrap();
                let want = read()
                    .no_deep_data()
                    .largest_resolution_level()
                    .all_channels()
                    .first_valid_layer()
                    .all_attributes()
                    .non_parallel()
                    .from_file(&p)
                    .unwrap();
                let got = io::read_exr_channels(&p, &lim()).unwrap();
                assert_eq!((got.width, got.height), (w, h));
                let list = &want.layer_data.channel_data.list;
                assert_eq!(got.channels.len(), list.len());
                for (g, c) in got.channels.iter().zip(list) {
                    let samples: Vec<f32> = c.sample_data.values_as_f32().collect();
                    assert_eq!(g.name, c.name.to_string());
                    assert_eq!(g.bits, if matches!(c.sample_data, FlatSamples::F16(_)) { 16 } else { 32 });
                    let same = g.data.iter().zip(&samples).all(|(a, b)| a.to_bits() == b.to_bits());
                    assert!(same, "{compression:?} {blocks:?} {line_order:?} channel {}", g.name);
                }
                // Picked channels interleaved (one skipped, the others reordered).
                for pick in [vec![2, 0], vec![1, 2, 0], vec![1]] {
                    let (img, bits) = io::read_exr_image(&p, &lim(), |_| Ok(pick.clone())).unwrap();
                    assert_eq!((img.width, img.height, img.channels), (w, h, pick.len()));
                    assert_eq!(bits, pick.iter().map(|&c| got.channels[c].bits).max().unwrap());
                    for (k, &c) in pick.iter().enumerate() {
                        let want = &got.channels[c].data;
                        let same = img.data.iter().skip(k).step_by(pick.len()).zip(want).all(|(a, b)| a.to_bits() == b.to_bits());
                        assert!(same, "{compression:?} {blocks:?} {line_order:?} pick {pick:?} channel {c}");
                    }
                }
            }
        }
    }
}

/// A file of several groups of chunks (each group is read while the one before is decompressed)
/// reads as the crate's reader reads it, as planes and interleaved, and a pick that names a
/// channel twice or one the file lacks is refused.
#[test]
fn exr_reader_across_groups_of_chunks() {
    use exr::prelude::*;
    let dir = tmp();
    let (w, h) = (1500usize, 1000usize);
    let val = |i: usize, k: usize| ((i * 2_654_435_761 + k * 97) % 100_003) as f32 / 7.0;
    let channels = (0..3).map(|k| AnyChannel::new(["B", "G", "R"][k], FlatSamples::F32((0..w * h).map(|i| val(i, k)).collect())));
    let encoding = Encoding { compression: Compression::Uncompressed, blocks: Blocks::ScanLines, line_order: LineOrder::Increasing };
    let layer = Layer::new((w, h), LayerAttributes::default(), encoding, AnyChannels::sort(channels.collect()));
    let p = dir.path().join("big.exr");
    exr::prelude::Image::from_layer(layer).write().to_file(&p).unwrap();
    assert!(std::fs::metadata(&p).unwrap().len() > 2 * (8 << 20), "the file must span several groups");
    let planes = io::read_exr_channels(&p, &lim()).unwrap();
    for (k, c) in planes.channels.iter().enumerate() {
        assert!(c.data.iter().enumerate().all(|(i, &v)| v == val(i, k)), "plane {}", c.name);
    }
    let (rgb, bits) =
        io::read_exr_image(&p, &lim(), |l| Ok(vec![l.find("R").unwrap(), l.find("G").unwrap(), l.find("B").unwrap()])).unwrap();
    assert_eq!((rgb.channels, bits), (3, 32));
    assert!(rgb.data.chunks(3).enumerate().all(|(i, px)| px == [val(i, 2), val(i, 1), val(i, 0)]));
    for bad in [vec![0, 0], vec![3]] {
        let e = err_of(io::read_exr_image(&p, &lim(), |_| Ok(bad.clone())));
        assert!(e.contains("asked for twice or out of range"), "{e}");
    }
    assert!(err_of(io::read_exr_image(&p, &lim(), |_| Ok(vec![]))).contains("no channel picked"));
}

/// ZIP chunks (drbokeh inflates them itself) read as the crate's reader reads them, those that
/// compression could not shrink (stored raw) included; a damaged one is refused with the file's
/// name, never read as other pixels.
#[test]
fn exr_zip_chunks_read_as_the_crate_reads_them() {
    use exr::prelude::*;
    let dir = tmp();
    let (w, h) = (203usize, 61usize);
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut noise = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        f32::from_bits((state >> 32) as u32 & 0x3fff_ffff)
    };
    // Rows 0-29 random bits (incompressible), the rest smooth.
    let g: Vec<f32> = (0..w * h).map(|i| if i < 30 * w { noise() } else { (i % w) as f32 * 0.25 }).collect();
    let b: Vec<f16> = (0..w * h)
        .map(|i| if i < 30 * w { f16::from_bits(noise().to_bits() as u16 & 0x7bff) } else { f16::from_f32((i % 977) as f32 * 0.01) })
        .collect();
    for compression in [Compression::ZIP1, Compression::ZIP16] {
        for blocks in [Blocks::ScanLines, Blocks::Tiles(Vec2(32, 16))] {
            let channels = vec![AnyChannel::new("B", FlatSamples::F16(b.clone())), AnyChannel::new("G", FlatSamples::F32(g.clone()))];
            let encoding = Encoding { compression, blocks, line_order: LineOrder::Increasing };
            let layer = Layer::new((w, h), LayerAttributes::default(), encoding, AnyChannels::sort(SmallVec::from_vec(channels)));
            let p = dir.path().join("zip.exr");
            exr::prelude::Image::from_layer(layer).write().to_file(&p).unwrap();
            let got = io::read_exr_channels(&p, &lim()).unwrap();
            assert!(got.channels[0].data.iter().zip(&b).all(|(a, b)| a.to_bits() == b.to_f32().to_bits()), "{compression:?} {blocks:?} B");
            assert!(got.channels[1].data.iter().zip(&g).all(|(a, b)| a.to_bits() == b.to_bits()), "{compression:?} {blocks:?} G");
            // A flipped byte in the middle of the file (compressed pixels): refused or read as the
            // crate reads it, never a panic.
            let mut bytes = std::fs::read(&p).unwrap();
            let len = bytes.len();
            for at in [len / 2, len - 40, len * 3 / 4] {
                bytes[at] ^= 0x5a;
                let bad = dir.path().join("bad.exr");
                std::fs::write(&bad, &bytes).unwrap();
                let crate_read =
                    read().no_deep_data().largest_resolution_level().all_channels().first_valid_layer().all_attributes().from_file(&bad);
                match io::read_exr_channels(&bad, &lim()) {
                    Ok(ours) => {
                        let theirs = crate_read.expect("we read a file the crate refuses");
                        for (o, t) in ours.channels.iter().zip(&theirs.layer_data.channel_data.list) {
                            assert!(o.data.iter().zip(t.sample_data.values_as_f32()).all(|(a, b)| a.to_bits() == b.to_bits()));
                        }
                    }
                    Err(e) => assert!(e.to_string().contains("bad.exr"), "{e}"),
                }
            }
        }
    }
}

/// A multi-part file reads its first part, as the crate's reader does, whatever the later
/// parts' sizes and compressions.
#[test]
fn exr_parallel_reader_takes_the_first_part() {
    use exr::prelude::*;
    let dir = tmp();
    let part = |name: &str, (w, h): (usize, usize), compression: Compression, v: f32| {
        let data: Vec<f32> = (0..w * h).map(|i| v + i as f32).collect();
        let ch = AnyChannel::new("Y", FlatSamples::F32(data));
        let enc = Encoding { compression, blocks: Blocks::ScanLines, line_order: LineOrder::Increasing };
        Layer::new((w, h), LayerAttributes::named(name), enc, AnyChannels::sort(SmallVec::from_vec(vec![ch])))
    };
    let layers = vec![part("first", (21, 13), Compression::ZIP16, 0.5), part("second", (40, 30), Compression::PIZ, 1000.0)];
    let p = dir.path().join("parts.exr");
    exr::prelude::Image::from_layers(ImageAttributes::new(IntegerBounds::from_dimensions((40, 30))), layers).write().to_file(&p).unwrap();
    let got = io::read_exr_channels(&p, &lim()).unwrap();
    assert_eq!((got.width, got.height, got.channels.len()), (21, 13, 1));
    let want: Vec<f32> = (0..21 * 13).map(|i| 0.5 + i as f32).collect();
    assert_eq!(got.channels[0].data, want);
}

#[test]
fn exr_half_channel_depth() {
    use exr::prelude::*;
    let dir = tmp();
    let p = dir.path().join("half.exr");
    let values: Vec<f16> = (0..6).map(|i| f16::from_f32(i as f32 * 0.5)).collect();
    let ch = AnyChannel::new("Z", FlatSamples::F16(values));
    let layer = Layer::new((3, 2), LayerAttributes::default(), Encoding::UNCOMPRESSED, AnyChannels::sort(SmallVec::from_vec(vec![ch])));
    exr::prelude::Image::from_layer(layer).write().to_file(&p).unwrap();
    let d = read_depth_map(&p, &lim()).unwrap();
    assert_eq!(d.bit_depth, 16);
    assert_eq!(d.image.data, vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5]);
}

#[test]
fn exr_layer_rgbad() {
    let dir = tmp();
    let mut layer = pattern(6, 3, 5);
    layer.data[4] = 0.75; // D
    let p = dir.path().join("layer.exr");
    write_exr(&p, &layer, &["R", "G", "B", "A", "D"]).unwrap();
    assert_eq!(read_layer(&p, &lim()).unwrap(), layer);
    // Case-insensitive channel names.
    let p = dir.path().join("lower.exr");
    write_exr(&p, &layer, &["r", "g", "b", "a", "d"]).unwrap();
    assert_eq!(read_layer(&p, &lim()).unwrap(), layer);
    // Missing D: the error lists what was found.
    let p = dir.path().join("nod.exr");
    write_exr(&p, &layer.select_channels(&[0, 1, 2, 3]), &["R", "G", "B", "A"]).unwrap();
    let e = err_of(read_layer(&p, &lim()));
    assert!(e.contains("nod.exr") && e.contains("missing D") && e.contains("found: A, B, G, R"), "{e}");
    // NaN in a layer.
    let mut bad = layer.clone();
    bad.data[5 * 4 + 4] = f32::NAN;
    let p = dir.path().join("nan.exr");
    write_exr(&p, &bad, &["R", "G", "B", "A", "D"]).unwrap();
    let e = err_of(read_layer(&p, &lim()));
    assert!(e.contains("nan.exr") && e.contains("non-finite") && e.contains("channel D") && e.contains("(4, 0)"), "{e}");
}

#[test]
fn exr_matte_channel_priority() {
    let dir = tmp();
    let a = Image::filled(2, 2, 1, 0.25);
    let y = Image::filled(2, 2, 1, 0.5);
    let p = dir.path().join("ya.exr");
    write_exr(&p, &Image::stack(&[&y, &a]), &["Y", "A"]).unwrap();
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![0.25; 4]);
    let p = dir.path().join("y.exr");
    write_exr(&p, &y, &["Y"]).unwrap();
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![0.5; 4]);
}

// ---------------------------------------------------------------------------------------------
// NPY

#[test]
fn npy_depth_matte_layer_photo() {
    let dir = tmp();
    let depth = Image::from_vec(3, 2, 1, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.5]).unwrap();
    let p = dir.path().join("depth.npy");
    save_npy(&p, &depth);
    assert_eq!(read_depth(&p, &lim()).unwrap(), depth);
    // H x W x 1 is accepted too.
    let p1 = dir.path().join("depth_hw1.npy");
    raw_npy(&p1, &[2, 3, 1], &depth.data);
    assert_eq!(read_depth(&p1, &lim()).unwrap(), depth);

    let layer = pattern(4, 3, 5);
    let p = dir.path().join("layer.npy");
    save_npy(&p, &layer);
    assert_eq!(read_layer(&p, &lim()).unwrap(), layer);
    let e = err_of(read_layer(&dir.path().join("depth.npy"), &lim()));
    assert!(e.contains("H x W x 5"), "{e}");

    let matte = pattern(4, 3, 1);
    let p = dir.path().join("matte.npy");
    save_npy(&p, &matte);
    assert_eq!(read_matte(&p, &lim()).unwrap(), matte);

    let rgb = pattern(4, 3, 3);
    let p = dir.path().join("photo.npy");
    save_npy(&p, &rgb);
    assert_eq!(read_photo(&p, Transfer::Srgb, &lim()).unwrap(), rgb, "NPY photos are linear");

    let p = dir.path().join("rgb_depth.npy");
    save_npy(&p, &rgb);
    let e = err_of(read_depth(&p, &lim()));
    assert!(e.contains("rgb_depth.npy") && e.contains("3 channels"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Mattes

#[test]
fn matte_from_rgba_la_and_grey() {
    let dir = tmp();
    let p = dir.path().join("rgba.png");
    image::RgbaImage::from_fn(3, 2, |x, y| image::Rgba([255, 0, 0, (x * 60 + y * 7) as u8])).save(&p).unwrap();
    let m = read_matte(&p, &lim()).unwrap();
    assert_eq!((m.width, m.height, m.channels), (3, 2, 1));
    assert_eq!(m.data, vec![0.0, 60.0 / 255.0, 120.0 / 255.0, 7.0 / 255.0, 67.0 / 255.0, 127.0 / 255.0]);

    let p = dir.path().join("la.png");
    image::GrayAlphaImage::from_pixel(2, 2, image::LumaA([10, 200])).save(&p).unwrap();
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![200.0 / 255.0; 4]);

    let p = dir.path().join("grey.png");
    image::GrayImage::from_fn(2, 1, |x, _| image::Luma([x as u8 * 255])).save(&p).unwrap();
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![0.0, 1.0], "no transfer function on mattes");

    // An opaque RGBA image whose colour is a grey ramp is a grey matte with a useless alpha.
    let p = dir.path().join("opaque_grey.png");
    image::RgbaImage::from_fn(2, 1, |x, _| image::Rgba([x as u8 * 100, x as u8 * 100, x as u8 * 100, 255])).save(&p).unwrap();
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![0.0, 100.0 / 255.0]);

    let p = dir.path().join("colour.png");
    image::RgbImage::from_pixel(2, 2, image::Rgb([1, 2, 3])).save(&p).unwrap();
    let e = err_of(read_matte(&p, &lim()));
    assert!(e.contains("colour.png") && e.contains("colour image"), "{e}");
}

#[test]
fn matte_out_of_range_and_nan_are_errors() {
    let dir = tmp();
    let p = dir.path().join("matte255.npy");
    save_npy(&p, &Image::from_vec(2, 1, 1, vec![0.0, 255.0]).unwrap());
    let e = err_of(read_matte(&p, &lim()));
    assert!(e.contains("matte255.npy") && e.contains("[0, 255]"), "{e}");

    let p = dir.path().join("neg.exr");
    write_exr(&p, &Image::from_vec(2, 1, 1, vec![-0.5, 0.5]).unwrap(), &["A"]).unwrap();
    let e = err_of(read_matte(&p, &lim()));
    assert!(e.contains("neg.exr") && e.contains("[-0.5, 0.5]"), "{e}");

    let p = dir.path().join("nan.npy");
    save_npy(&p, &Image::from_vec(2, 1, 1, vec![0.5, f32::NAN]).unwrap());
    let e = err_of(read_matte(&p, &lim()));
    assert!(e.contains("nan.npy") && e.contains("NaN") && e.contains("(1, 0)"), "{e}");

    // Within the tolerance: accepted and clamped.
    let p = dir.path().join("tol.npy");
    save_npy(&p, &Image::from_vec(2, 1, 1, vec![-0.0005, 1.0009]).unwrap());
    assert_eq!(read_matte(&p, &lim()).unwrap().data, vec![0.0, 1.0]);
}

// ---------------------------------------------------------------------------------------------
// Writers

#[test]
fn write_output_picks_format_from_extension() {
    let dir = tmp();
    let img = pattern(5, 4, 3);
    let p = dir.path().join("out.PNG");
    write_output(&p, &img, 16, Transfer::Srgb).unwrap();
    assert_close(&read_photo(&p, Transfer::Srgb, &lim()).unwrap().data, &img.data, 2e-4);
    let p = dir.path().join("out.exr");
    write_output(&p, &img, 8, Transfer::Srgb).unwrap();
    assert_eq!(read_photo(&p, Transfer::Srgb, &lim()).unwrap(), img, "EXR is raw float");
    let p = dir.path().join("out.npy");
    write_output(&p, &img, 8, Transfer::Srgb).unwrap();
    assert_eq!(read_decoded(&p, &lim()).unwrap().image, img, "NPY is raw float");
    // 8-bit sRGB: decoded values within half a code of the original.
    let p = dir.path().join("out8.png");
    write_output(&p, &img, 8, Transfer::Srgb).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    let enc: Vec<f32> = img.data.iter().map(|&v| drbokeh::color::linear_to_srgb(v)).collect();
    assert_close(&d.image.data, &enc, 0.5 / 255.0 + 1e-6);

    let e = err_of(write_output(&dir.path().join("out.bmp"), &img, 8, Transfer::Srgb));
    assert!(e.contains("'.bmp'") && e.contains(".png, .exr or .npy"), "{e}");
    assert_eq!(OutputFormat::from_path(Path::new("x.NpY")).unwrap(), OutputFormat::Npy);
    // Overwriting an existing output is fine.
    write_output(&dir.path().join("out.exr"), &pattern(2, 2, 3), 8, Transfer::Srgb).unwrap();
    assert_eq!(read_decoded(&dir.path().join("out.exr"), &lim()).unwrap().image.width, 2);
}

#[test]
fn png_clips_and_rounds() {
    let dir = tmp();
    let img = Image::from_vec(4, 1, 1, vec![-1.0, 0.5, 2.0, 100.4 / 255.0]).unwrap();
    let p = dir.path().join("clip.png");
    write_png(&p, &img, 8, Transfer::Linear).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!(d.image.data, vec![0.0, 128.0 / 255.0, 1.0, 100.0 / 255.0]);
    let e = err_of(write_png(&p, &img, 12, Transfer::Linear));
    assert!(e.contains("8 or 16"), "{e}");
}

#[test]
fn atomic_write_success_and_failure() {
    let dir = tmp();
    let img = pattern(3, 3, 3);
    // Missing folder: an error, and nothing is created.
    let missing = dir.path().join("no_such_folder").join("out.png");
    let e = err_of(write_png(&missing, &img, 8, Transfer::Srgb));
    assert!(e.contains("out.png") && e.contains("does not exist"), "{e}");
    assert!(!missing.exists() && !missing.parent().unwrap().exists());
    assert!(list_dir(dir.path()).is_empty());
    // An encoder-side failure (5 channels cannot be a PNG): no file, no temp file left behind.
    let p = dir.path().join("five.png");
    assert!(write_png(&p, &pattern(3, 3, 5), 8, Transfer::Srgb).is_err());
    assert!(list_dir(dir.path()).is_empty(), "{:?}", list_dir(dir.path()));
    let e = err_of(write_exr(&dir.path().join("bad.exr"), &img, &["R", "G"]));
    assert!(e.contains("bad.exr") && e.contains("2 channel names"), "{e}");
    assert!(list_dir(dir.path()).is_empty(), "{:?}", list_dir(dir.path()));
    // Success: exactly the file, no temp file.
    for name in ["ok.png", "ok.exr", "ok.npy"] {
        write_output(&dir.path().join(name), &img, 8, Transfer::Srgb).unwrap();
    }
    assert_eq!(list_dir(dir.path()), vec!["ok.exr", "ok.npy", "ok.png"]);
}

// ---------------------------------------------------------------------------------------------
// Errors on bad input

#[test]
fn missing_file() {
    let dir = tmp();
    let p = dir.path().join("nope.png");
    for e in [
        err_of(read_photo(&p, Transfer::Srgb, &lim())),
        err_of(read_depth(&p, &lim())),
        err_of(read_matte(&p, &lim())),
        err_of(read_layer(&p, &lim())),
    ] {
        assert!(e.contains("nope.png") && e.contains("cannot read") && e.contains("No such file"), "{e}");
    }
}

#[test]
fn garbage_bytes_with_every_extension() {
    let dir = tmp();
    let garbage: Vec<u8> = (0..2000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect();
    for (ext, expect) in
        [("png", "PNG"), ("exr", "EXR"), ("tif", "TIFF"), ("tiff", "TIFF"), ("jpg", "JPEG"), ("jpeg", "JPEG"), ("npy", "NPY")]
    {
        let p = dir.path().join(format!("garbage.{ext}"));
        std::fs::write(&p, &garbage).unwrap();
        for e in [err_of(read_photo(&p, Transfer::Srgb, &lim())), err_of(read_depth(&p, &lim())), err_of(read_matte(&p, &lim()))] {
            assert!(e.contains(&format!("garbage.{ext}")) && e.contains(expect), "{ext}: {e}");
        }
        let _ = read_layer(&p, &lim()).unwrap_err();
    }
    let p = dir.path().join("garbage.dat");
    std::fs::write(&p, &garbage).unwrap();
    let e = err_of(read_photo(&p, Transfer::Srgb, &lim()));
    assert!(e.contains("garbage.dat") && e.contains("unrecognised") && e.contains(".png") && e.contains(".exr"), "{e}");
    // A known but unsupported format is named.
    let p = dir.path().join("pic.bmp");
    std::fs::write(&p, bmp_1x1()).unwrap();
    let e = err_of(read_photo(&p, Transfer::Srgb, &lim()));
    assert!(e.contains("Bmp") && e.contains("not supported"), "{e}");
}

/// A 1x1 24-bit BMP (file header, BITMAPINFOHEADER, one padded row), written by hand: the
/// `image` crate here has no BMP encoder.
fn bmp_1x1() -> Vec<u8> {
    let mut b = Vec::new();
    b.extend_from_slice(b"BM");
    b.extend_from_slice(&58u32.to_le_bytes()); // file size
    b.extend_from_slice(&[0; 4]);
    b.extend_from_slice(&54u32.to_le_bytes()); // pixel data offset
    b.extend_from_slice(&40u32.to_le_bytes()); // info header size
    b.extend_from_slice(&1i32.to_le_bytes()); // width
    b.extend_from_slice(&1i32.to_le_bytes()); // height
    b.extend_from_slice(&1u16.to_le_bytes()); // planes
    b.extend_from_slice(&24u16.to_le_bytes()); // bits per pixel
    b.extend_from_slice(&[0; 24]); // no compression, sizes and palette left at 0
    b.extend_from_slice(&[0x20, 0x40, 0x80, 0]); // one BGR pixel, row padded to 4 bytes
    b
}

#[test]
fn detection_by_content_beats_extension() {
    let dir = tmp();
    let p = dir.path().join("actually_png.tif");
    image::GrayImage::from_pixel(2, 2, image::Luma([51])).save_with_format(&p, image::ImageFormat::Png).unwrap();
    let d = read_decoded(&p, &lim()).unwrap();
    assert_eq!(d.format, FileFormat::Png);
    assert_eq!(d.image.data[0], 0.2);
}

#[test]
fn truncated_files_are_corrupt_not_panics() {
    let dir = tmp();
    let img = pattern(64, 48, 3);
    let png = dir.path().join("full.png");
    write_png(&png, &img, 8, Transfer::Srgb).unwrap();
    let exr = dir.path().join("full.exr");
    write_exr(&exr, &img, &["R", "G", "B"]).unwrap();
    let tif = dir.path().join("full.tif");
    {
        let data: Vec<u16> = (0..64 * 48 * 3).map(|i| i as u16).collect();
        write_tiff::<tiff::encoder::colortype::RGB16>(&tif, 64, 48, &data);
    }
    let jpg = dir.path().join("full.jpg");
    image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8 * 3, y as u8 * 5, 7])).save(&jpg).unwrap();
    let npy = dir.path().join("full.npy");
    save_npy(&npy, &img);
    for (src, expect) in [(&png, "corrupt or truncated PNG"), (&exr, "EXR"), (&tif, "TIFF"), (&jpg, "JPEG"), (&npy, "truncated")] {
        let bytes = std::fs::read(src).unwrap();
        let name = format!("half_{}", src.file_name().unwrap().to_string_lossy());
        let p = dir.path().join(&name);
        std::fs::write(&p, &bytes[..bytes.len() / 2]).unwrap();
        let e = err_of(read_decoded(&p, &lim()));
        assert!(e.contains(&name) && e.contains(expect), "{e}");
    }
}

#[test]
fn zero_sized_inputs() {
    let dir = tmp();
    let p = dir.path().join("empty.png");
    std::fs::write(&p, b"").unwrap();
    let e = err_of(read_photo(&p, Transfer::Srgb, &lim()));
    assert!(e.contains("empty.png") && e.contains("empty"), "{e}");

    let p = dir.path().join("zero.npy");
    raw_npy(&p, &[0, 4], &[]);
    let e = err_of(read_depth(&p, &lim()));
    assert!(e.contains("zero.npy") && e.contains("empty"), "{e}");

    let p = dir.path().join("zero_width.png");
    std::fs::write(&p, png_header_only(0, 10)).unwrap();
    let e = err_of(read_photo(&p, Transfer::Srgb, &lim()));
    assert!(e.contains("zero_width.png"), "{e}");

    let e = err_of(write_png(&dir.path().join("w0.png"), &Image::new(0, 3, 3), 8, Transfer::Srgb));
    assert!(e.contains("0x3"), "{e}");
    let e = err_of(write_exr(&dir.path().join("w0.exr"), &Image::new(3, 0, 1), &["Y"]));
    assert!(e.contains("empty"), "{e}");
}

#[test]
fn decompression_bomb_is_refused_before_allocation() {
    let dir = tmp();
    let p = dir.path().join("bomb.png");
    let bytes = png_header_only(100_000, 100_000);
    assert!(bytes.len() < 100);
    std::fs::write(&p, &bytes).unwrap();
    // 10^10 pixels x 3 bytes would be 30 GB: refused from the header alone (the test would
    // abort on allocation failure or take minutes otherwise).
    let limits = ReadLimits { max_pixels: 200_000_000 };
    for e in [err_of(read_photo(&p, Transfer::Srgb, &limits)), err_of(read_depth(&p, &limits)), err_of(read_matte(&p, &limits))] {
        assert!(e.contains("bomb.png") && e.contains("100000x100000") && e.contains("limit of 200000000 pixels"), "{e}");
    }

    // Small limits apply to every format.
    let small = ReadLimits::new(100);
    let img = pattern(20, 10, 3);
    for name in ["big.png", "big.exr", "big.npy"] {
        let p = dir.path().join(name);
        write_output(&p, &img, 8, Transfer::Srgb).unwrap();
        let e = err_of(read_decoded(&p, &small));
        assert!(e.contains(name) && e.contains("limit") && e.contains("100"), "{e}");
        assert!(read_decoded(&p, &ReadLimits::new(200)).is_ok());
    }
    let p = dir.path().join("big.tif");
    write_tiff::<tiff::encoder::colortype::Gray32Float>(&p, 20, 10, &[0.0; 200]);
    let e = err_of(read_depth(&p, &small));
    assert!(e.contains("big.tif") && e.contains("limit of 100 pixels"), "{e}");
    let p = dir.path().join("big.jpg");
    image::RgbImage::new(20, 10).save(&p).unwrap();
    let e = err_of(read_photo(&p, Transfer::Srgb, &small));
    assert!(e.contains("big.jpg") && e.contains("limit of 100 pixels"), "{e}");
}

/// Byte-level mutations of valid files: every read must return (Ok or Err), never panic or hang.
#[test]
fn mutated_files_never_panic() {
    let dir = tmp();
    let img = pattern(24, 16, 4);
    let mut seeds: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    for name in ["m.png", "m.exr", "m.npy"] {
        let p = dir.path().join(name);
        if name.ends_with("png") {
            write_png(&p, &img, 16, Transfer::Srgb).unwrap();
        } else {
            write_exr_or_npy(&p, &img);
        }
        seeds.push((p.clone(), std::fs::read(&p).unwrap()));
    }
    let tif = dir.path().join("m.tif");
    write_tiff::<tiff::encoder::colortype::RGBA8>(&tif, 24, 16, &vec![7u8; 24 * 16 * 4]);
    seeds.push((tif.clone(), std::fs::read(&tif).unwrap()));
    let jpg = dir.path().join("m.jpg");
    image::RgbImage::from_fn(24, 16, |x, y| image::Rgb([x as u8 * 9, y as u8 * 13, 50])).save(&jpg).unwrap();
    seeds.push((jpg.clone(), std::fs::read(&jpg).unwrap()));

    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut rand = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let limits = ReadLimits::new(1 << 20);
    for (path, bytes) in &seeds {
        let target = path.with_file_name(format!("mut_{}", path.file_name().unwrap().to_string_lossy()));
        for _ in 0..150 {
            let mut b = bytes.clone();
            for _ in 0..1 + rand() % 4 {
                let i = (rand() % b.len() as u64) as usize;
                b[i] = rand() as u8;
            }
            if rand() % 5 == 0 {
                b.truncate((rand() % b.len() as u64) as usize);
            }
            std::fs::write(&target, &b).unwrap();
            let _ = read_decoded(&target, &limits);
            let _ = read_layer(&target, &limits);
        }
    }
}

fn write_exr_or_npy(p: &Path, img: &Image) {
    if p.extension().unwrap() == "exr" {
        write_exr(p, img, &["R", "G", "B", "A"]).unwrap();
    } else {
        save_npy(p, img);
    }
}

/// An NPY header claiming an absurd shape is refused even with no pixel limit (no overflow).
#[test]
fn npy_header_with_huge_shape_unlimited() {
    let dir = tmp();
    let p = dir.path().join("huge.npy");
    let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (4294967296, 4294967296, 3), }";
    let mut header = dict.to_string();
    while !(10 + header.len() + 1).is_multiple_of(64) {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    bytes.extend_from_slice(&[0u8; 64]);
    std::fs::write(&p, &bytes).unwrap();
    // Either our checked arithmetic ("too large") or, in debug builds where npyz's own shape
    // product overflows, the panic guard ("malformed data") answers: never a panic.
    let e = err_of(read_depth(&p, &ReadLimits::unlimited()));
    assert!(e.contains("huge.npy") && (e.contains("too large") || e.contains("malformed data")), "{e}");
    let e = err_of(read_depth(&p, &lim()));
    assert!(e.contains("pixel limit") || e.contains("malformed data"), "{e}");
}

// ---------------------------------------------------------------------------------------------
// Silent acceptance of broken data (issue 10): truncation, special files, doubtful values

/// Uncompressed 8-bit grey TIFF with its IFD *before* the pixel data (as some writers do; the
/// `tiff` encoder puts it last, so a cut file loses the IFD rather than pixels), one strip per
/// `rows` rows (`rows < h`: several strips, so their offsets and counts are arrays). Pixel i
/// is `i * 7 mod 256`.
fn tiff_ifd_first(w: u32, h: u32, rows: u32) -> Vec<u8> {
    let strips = h.div_ceil(rows);
    assert!(strips > 1, "one strip would store its offset inline");
    let entries = 9u16;
    let offsets_at = 8 + 2 + 12 * entries as u32 + 4;
    let counts_at = offsets_at + 4 * strips;
    let data_at = counts_at + 4 * strips;
    let mut out = b"II*\0".to_vec();
    out.extend(8u32.to_le_bytes());
    out.extend(entries.to_le_bytes());
    // (tag, type: 3 SHORT / 4 LONG, count, value or offset), sorted by tag.
    for (tag, typ, count, value) in [
        (256u16, 4u16, 1u32, w),
        (257, 4, 1, h),
        (258, 3, 1, 8),
        (259, 3, 1, 1),
        (262, 3, 1, 1),
        (273, 4, strips, offsets_at),
        (277, 3, 1, 1),
        (278, 4, 1, rows),
        (279, 4, strips, counts_at),
    ] {
        out.extend(tag.to_le_bytes());
        out.extend(typ.to_le_bytes());
        out.extend(count.to_le_bytes());
        out.extend(value.to_le_bytes());
    }
    out.extend(0u32.to_le_bytes());
    out.extend((0..strips).flat_map(|s| (data_at + s * w * rows).to_le_bytes()));
    out.extend((0..strips).flat_map(|s| (w * rows.min(h - s * rows)).to_le_bytes()));
    assert_eq!(out.len() as u32, data_at);
    out.extend((0..w * h).map(|i| (i * 7) as u8));
    out
}

/// Every format cut at 15 points (1/16 .. 15/16 of its length) is an error naming the file and
/// saying "truncated", through every reader; nothing is silently padded. (A PNG cut inside its
/// final 12-byte IEND chunk still has all its pixels and reads; no cut here lands there.)
#[test]
fn truncated_files_are_errors_in_every_format_at_every_cut() {
    let dir = tmp();
    let img = pattern(48, 40, 3);
    let mut files: Vec<(PathBuf, &str)> = Vec::new();
    let png = dir.path().join("t.png");
    write_png(&png, &img, 16, Transfer::Srgb).unwrap();
    files.push((png, "PNG"));
    let exr = dir.path().join("t.exr");
    write_exr(&exr, &img, &["R", "G", "B"]).unwrap();
    files.push((exr, "EXR"));
    let tif = dir.path().join("t.tif");
    write_tiff::<tiff::encoder::colortype::RGB16>(&tif, 48, 40, &(0..48 * 40 * 3).map(|i| i as u16).collect::<Vec<_>>());
    files.push((tif, "TIFF"));
    for rows in [1, 8] {
        let p = dir.path().join(format!("ifd_first_{rows}.tif"));
        std::fs::write(&p, tiff_ifd_first(48, 40, rows)).unwrap();
        assert_eq!(read_decoded(&p, &lim()).unwrap().image.data[3], 21.0 / 255.0);
        files.push((p, "TIFF"));
    }
    let jpg = dir.path().join("t.jpg");
    image::RgbImage::from_fn(48, 40, |x, y| image::Rgb([x as u8 * 5, y as u8 * 6, (x * y) as u8])).save(&jpg).unwrap();
    files.push((jpg, "JPEG"));
    let npy = dir.path().join("t.npy");
    save_npy(&npy, &img);
    files.push((npy, "NPY"));

    let mut failures = Vec::new();
    for (src, format) in &files {
        let bytes = std::fs::read(src).unwrap();
        let name = format!("cut_{}", src.file_name().unwrap().to_string_lossy());
        let p = dir.path().join(&name);
        for k in 1..16 {
            let cut = bytes.len() * k / 16;
            std::fs::write(&p, &bytes[..cut]).unwrap();
            for (reader, r) in [
                ("read_decoded", read_decoded(&p, &lim()).map(|_| ())),
                ("read_depth_map", read_depth_map(&p, &lim()).map(|_| ())),
                ("read_matte", read_matte(&p, &lim()).map(|_| ())),
            ] {
                match r {
                    Ok(()) => failures.push(format!("{name} cut at {cut}/{}: {reader} accepted it", bytes.len())),
                    Err(e) => {
                        let e = e.to_string();
                        if !(e.contains(&name) && e.contains(format) && e.contains("truncated")) {
                            failures.push(format!("{name} cut at {cut}: {reader}: {e}"));
                        }
                    }
                }
            }
        }
    }
    assert!(failures.is_empty(), "{} failures:\n{}", failures.len(), failures.join("\n"));
}

/// The JPEG decoder pads a cut-off picture with grey; the marker walk refuses it, but bytes
/// after the end-of-image marker (camera trailers) are fine, and the limit check still comes
/// first for a bomb.
#[test]
fn truncated_jpeg_is_refused_and_trailers_are_allowed() {
    let dir = tmp();
    let p = dir.path().join("photo.jpg");
    image::RgbImage::from_fn(128, 96, |x, y| image::Rgb([x as u8 * 3, y as u8 * 5, (x ^ y) as u8])).save(&p).unwrap();
    let full = std::fs::read(&p).unwrap();
    let good = read_photo(&p, Transfer::Srgb, &lim()).unwrap();

    let trailer = dir.path().join("trailer.jpg");
    std::fs::write(&trailer, [&full[..], b"vendor trailer \xFF\xD8 bytes"].concat()).unwrap();
    assert_eq!(read_photo(&trailer, Transfer::Srgb, &lim()).unwrap(), good);

    let cut = dir.path().join("cut.jpg");
    for drop in [2, 3, 100, full.len() / 2] {
        std::fs::write(&cut, &full[..full.len() - drop]).unwrap();
        let e = err_of(read_photo(&cut, Transfer::Srgb, &lim()));
        assert!(e.contains("cut.jpg") && e.contains("truncated JPEG") && e.contains("end-of-image"), "drop {drop}: {e}");
    }
    let e = err_of(read_photo(&cut, Transfer::Srgb, &ReadLimits::new(100)));
    assert!(e.contains("limit of 100 pixels"), "{e}");
}

/// Runs `f` on another thread and fails the test if it has not returned within 10 s (a
/// blocking `open` of a FIFO would otherwise hang the test forever).
fn within_10s<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(std::time::Duration::from_secs(10)).unwrap_or_else(|_| panic!("{what} blocked for 10 s"))
}

/// FIFOs, character devices and folders are refused from their metadata, before any `open`
/// could block, by every reader: images, depth, matte, layer, raw NPY, config, manifest.
#[cfg(unix)]
#[test]
fn special_files_are_refused_without_blocking() {
    let dir = tmp();
    let fifo = dir.path().join("pipe.png");
    let status = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo");
    assert!(status.success());
    let cases: [(PathBuf, &str); 3] =
        [(fifo, "FIFO"), (PathBuf::from("/dev/null"), "character device"), (dir.path().to_path_buf(), "folder")];
    for (p, kind) in cases {
        let name = p.display().to_string();
        let errors = within_10s(&name, move || {
            vec![
                err_of(read_photo(&p, Transfer::Srgb, &lim())),
                err_of(read_depth(&p, &lim())),
                err_of(read_matte(&p, &lim())),
                err_of(read_layer(&p, &lim())),
                err_of(io::read_npy(&p, 100)),
                err_of(drbokeh::config::Config::load(&p)),
                err_of(drbokeh::batch::read_manifest(&p)),
            ]
        });
        for e in errors {
            assert!(e.contains(&name) && e.contains(kind) && e.contains("not a regular file"), "{e}");
        }
    }
}

#[test]
fn eight_bit_depth_warns_about_precision() {
    let dir = tmp();
    let p = dir.path().join("depth8.png");
    image::GrayImage::from_fn(4, 4, |x, y| image::Luma([(x * 10 + y) as u8])).save(&p).unwrap();
    let d = read_depth_map(&p, &lim()).unwrap();
    assert_eq!(d.warnings.len(), 1, "{:?}", d.warnings);
    let w = &d.warnings[0];
    assert!(w.contains("depth8.png") && w.contains("8-bit") && w.contains("256 depth levels") && w.contains("16-bit"), "{w}");
    let jpg = dir.path().join("depth8.jpg");
    image::GrayImage::from_pixel(8, 8, image::Luma([90])).save(&jpg).unwrap();
    assert_eq!(read_depth_map(&jpg, &lim()).unwrap().warnings.len(), 1);
    // 16-bit, float TIFF, EXR (half and float) and NPY maps carry no warning.
    let p16 = dir.path().join("depth16.png");
    write_png(&p16, &pattern(4, 4, 1), 16, Transfer::Linear).unwrap();
    let tif = dir.path().join("depth.tif");
    write_tiff::<tiff::encoder::colortype::Gray32Float>(&tif, 2, 2, &[0.5; 4]);
    let exr = dir.path().join("depth.exr");
    write_exr(&exr, &pattern(4, 4, 1), &["Z"]).unwrap();
    let npy = dir.path().join("depth.npy");
    save_npy(&npy, &pattern(4, 4, 1));
    for p in [p16, tif, exr, npy] {
        let d = read_depth_map(&p, &lim()).unwrap();
        assert!(d.warnings.is_empty(), "{}: {:?}", p.display(), d.warnings);
    }
}

#[test]
fn layer_alpha_outside_unit_range_warns() {
    let dir = tmp();
    let layer = |alpha: f32| {
        let mut img = pattern(6, 4, 5);
        img.data.iter_mut().skip(3).step_by(5).for_each(|a| *a = 0.5);
        img.data[5 * 7 + 3] = alpha;
        img
    };
    for (name, alpha, warns) in
        [("in_range.npy", 1.0, false), ("round_off.npy", 1.0 + 1e-4, false), ("above.npy", 1.5, true), ("below.exr", -0.25, true)]
    {
        let p = dir.path().join(name);
        write_exr_or_npy_5(&p, &layer(alpha));
        let l = io::read_layer_file(&p, &lim()).unwrap();
        assert_eq!(l.image.data[5 * 7 + 3], alpha, "values are kept as stored");
        assert_eq!(l.image, read_layer(&p, &lim()).unwrap());
        if warns {
            assert_eq!(l.warnings.len(), 1, "{name}: {:?}", l.warnings);
            let w = &l.warnings[0];
            assert!(w.contains(name) && w.contains("alpha") && w.contains(&alpha.to_string()) && w.contains("[0, 1]"), "{w}");
        } else {
            assert!(l.warnings.is_empty(), "{name}: {:?}", l.warnings);
        }
    }
}

fn write_exr_or_npy_5(p: &Path, img: &Image) {
    if p.extension().unwrap() == "exr" {
        write_exr(p, img, &["R", "G", "B", "A", "D"]).unwrap();
    } else {
        save_npy(p, img);
    }
}
