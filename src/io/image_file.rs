//! Raster image reading (PNG, JPEG, TIFF, EXR, NPY) into [`Decoded`], and photos as linear RGB.
//!
//! PNG and JPEG go through the `image` crate, TIFF through the `tiff` crate (see
//! [`super::tiff_file`]), EXR through the `exr` crate. Integer samples are scaled to [0, 1]
//! directly from their stored width (8-bit / 255, 16-bit / 65535), so 16-bit files keep their
//! full precision. EXIF orientation and ICC profiles are not applied: pixels are used in stored
//! order, so a photo and a depth map computed from the same stored pixels stay aligned.
//!
//! Truncated files are errors in every format. The PNG, TIFF, EXR and NPY decoders report
//! missing data themselves (a PNG cut inside its final IEND chunk has all its pixels and reads); the JPEG decoder (zune-jpeg, which the `image` crate runs in
//! lenient mode) fills a cut-off picture with grey and succeeds, so JPEG files are read into
//! memory and their marker structure is walked up to the end-of-image marker first
//! ([`jpeg_eoi_end`]).

use super::exr_file::read_exr_image;
use super::format::{FileFormat, detect_format, guarded, open, read_input};
use super::limits::ReadLimits;
pub use super::samples::Encoding;
use super::samples::{Samples, Stored};
use crate::color::{PhotoEncoding, Transfer};
use crate::error::{Error, Result};
use crate::image::Image;
use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader};
use std::io::{BufRead, Seek};
use std::mem::MaybeUninit;
use std::path::Path;

/// An image as stored in its file.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    /// 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA) interleaved channels. Integer formats are
    /// scaled to [0, 1]; float formats hold the raw values.
    pub image: Image,
    /// Whether the values are display-encoded (sRGB) or already linear.
    pub encoding: Encoding,
    /// Bits per sample in the file: 8 or 16 for integer formats, 16/32 for EXR (half/float),
    /// 32 for float TIFF and NPY.
    pub bit_depth: u8,
    /// True when the last channel is alpha (2 or 4 channels).
    pub has_alpha: bool,
    /// The format the file was decoded as (detected by content, else by extension).
    pub format: FileFormat,
}

/// Reads any supported image file as stored (see [`Decoded`]).
///
/// NPY arrays of shape H x W or H x W x C (C in 1..=4) are accepted: float arrays as linear
/// images with their values unchanged, uint8 / uint16 arrays as 8/16-bit display-encoded
/// images (scaled to [0, 1], like a PNG's samples). EXR files need channels R,G,B (optionally A), or Y (optionally A), or a
/// single channel of any name.
pub fn read_decoded(path: &Path, limits: &ReadLimits) -> Result<Decoded> {
    read_stored(path, limits).map(Stored::into_decoded)
}

/// Pixels per parallel task of the sample conversions: 64 K pixels (0.75 MB of RGB floats) keep
/// a 12 MP image at ~190 tasks, enough to balance any core count, few enough that the
/// scheduling cost is nil.
const PIXELS_PER_TASK: usize = 1 << 16;

impl Stored {
    /// [`Decoded`]: integers scaled to [0, 1] (8-bit / 255, 16-bit / 65535), floats as they are.
    /// One parallel pass over the samples; allocates the `f32` image.
    fn into_decoded(self) -> Decoded {
        let identity: Vec<usize> = (0..self.channels).collect();
        let (w, h, c) = (self.width, self.height, self.channels);
        let data = match self.samples {
            Samples::U8(v) => convert(&v, c, &identity, |q| q as f32 / 255.0),
            Samples::U16(v) => convert(&v, c, &identity, |q| q as f32 / 65535.0),
            Samples::F32(v) => v,
        };
        let image = Image::from_vec(w, h, c, data).expect("decoders deliver width * height * channels samples");
        Decoded { image, encoding: self.encoding, bit_depth: self.bit_depth, has_alpha: self.has_alpha, format: self.format }
    }
}

/// Maps interleaved `src` (`src_channels` per pixel) to a new interleaved buffer with
/// `which.len()` channels per pixel, output channel k being `f(src[which[k]])`. Parallel over
/// [`PIXELS_PER_TASK`]-pixel blocks (rayon); allocates the output only.
fn convert<T: Copy + Sync>(src: &[T], src_channels: usize, which: &[usize], f: impl Fn(T) -> f32 + Sync) -> Vec<f32> {
    use rayon::prelude::*;
    let n = which.len();
    let mut out = Vec::<f32>::with_capacity(src.len() / src_channels.max(1) * n);
    let dst = &mut out.spare_capacity_mut()[..src.len() / src_channels.max(1) * n];
    dst.par_chunks_mut(PIXELS_PER_TASK * n)
        .zip(src.par_chunks(PIXELS_PER_TASK * src_channels))
        .for_each(|(d, s)| convert_into(d, s, src_channels, which, &f));
    let len = dst.len();
    // SAFETY: the zip above wrote every element of `dst` (both sides hold the same number of
    // pixels), which is the first `len` elements of `out`'s capacity.
    unsafe { out.set_len(len) };
    out
}

/// [`convert`] of one block, on the calling thread: writes every element of `dst` (as many
/// pixels as `src` holds).
fn convert_into<T: Copy>(dst: &mut [MaybeUninit<f32>], src: &[T], src_channels: usize, which: &[usize], f: impl Fn(T) -> f32) {
    let n = which.len();
    debug_assert_eq!(dst.len() / n.max(1), src.len() / src_channels.max(1));
    if n == src_channels && which.iter().enumerate().all(|(k, &c)| k == c) {
        // A flat map the compiler vectorizes (the common 3-channel case).
        dst.iter_mut().zip(src).for_each(|(d, &q)| {
            d.write(f(q));
        });
    } else {
        for (d, s) in dst.chunks_exact_mut(n).zip(src.chunks_exact(src_channels)) {
            for (d, &c) in d.iter_mut().zip(which) {
                d.write(f(s[c]));
            }
        }
    }
}

/// [`convert_into`] of one band of a PNG's decoded rows (`bits` 8 or 16; 16-bit samples
/// big-endian, as stored): 8-bit samples through `f8`, 16-bit ones through `f16`.
fn png_band_into(
    dst: &mut [MaybeUninit<f32>],
    raw: &[u8],
    channels: usize,
    which: &[usize],
    bits: u8,
    f8: impl Fn(u8) -> f32,
    f16: impl Fn(u16) -> f32,
) {
    match bits {
        8 => convert_into(dst, raw, channels, which, f8),
        _ => convert_into(dst, raw.as_chunks::<2>().0, channels, which, |q| f16(u16::from_be_bytes(q))),
    }
}

/// Reads any supported image file into its decoder's sample type (see [`Stored`]).
pub(crate) fn read_stored(path: &Path, limits: &ReadLimits) -> Result<Stored> {
    read_stored_as(path, detect_format(path)?, limits)
}

/// [`read_stored`] of a file whose format is known.
fn read_stored_as(path: &Path, format: FileFormat, limits: &ReadLimits) -> Result<Stored> {
    match format {
        FileFormat::Png => {
            // Row by row, each sample scaled as `into_decoded` scales the whole-image route's.
            let band = |raw: &[u8], c: usize, bits: u8, dst: &mut [MaybeUninit<f32>]| {
                let all: Vec<usize> = (0..c).collect();
                png_band_into(dst, raw, c, &all, bits, |q| q as f32 / 255.0, |q| q as f32 / 65535.0)
            };
            match super::png_rows::read_png_rows(path, limits, |c| c, band)? {
                Some(png) => Ok(Stored::from_image(png.image, Encoding::Display, png.bits, FileFormat::Png)),
                None => decode_with_image_crate(path, FileFormat::Png, open(path)?, limits, || Ok(())),
            }
        }
        FileFormat::Jpeg => {
            // In memory for the marker walk (one pass over the file's bytes); a JPEG file is
            // far smaller than its decoded pixels.
            let bytes = read_input(path)?;
            let complete = || match jpeg_eoi_end(&bytes) {
                Some(_) => Ok(()),
                None => Err(Error::input(
                    path,
                    format!(
                        "truncated JPEG: the data stops after {} bytes, before the end-of-image marker (incomplete copy or download?)",
                        bytes.len()
                    ),
                )),
            };
            decode_with_image_crate(path, FileFormat::Jpeg, std::io::Cursor::new(&bytes[..]), limits, complete)
        }
        FileFormat::Tiff => super::tiff_file::decode_tiff(path, limits),
        FileFormat::Exr => decode_exr(path, limits),
        FileFormat::Heif => decode_heif(path, limits),
        FileFormat::Npy => {
            let bytes = super::format::read_input(path)?;
            let (width, height, channels, samples) = super::format::guarded(path, FileFormat::Npy, || {
                super::npy::decode_npy_samples(&bytes, limits.max_pixels).map_err(|m| Error::input(path, m))
            })?;
            if channels > 4 {
                return Err(Error::input(path, format!("NPY array has {channels} channels; an image needs 1 to 4 (H x W, or H x W x C)")));
            }
            // uint8 / uint16 arrays are what an 8/16-bit image file holds (display-encoded, full
            // range); float arrays are linear values.
            let (samples, encoding, bit_depth) = match samples {
                super::npy::NpySamples::U8(v) => (Samples::U8(v), Encoding::Display, 8),
                super::npy::NpySamples::U16(v) => (Samples::U16(v), Encoding::Display, 16),
                super::npy::NpySamples::F32(v) => (Samples::F32(v), Encoding::Linear, 32),
            };
            let has_alpha = matches!(channels, 2 | 4);
            Ok(Stored { width, height, channels, samples, encoding, bit_depth, has_alpha, format: FileFormat::Npy })
        }
    }
}

/// A HEIF file's primary image through libheif ([`super::heif`]): RGB, display-encoded, in
/// stored orientation.
fn decode_heif(path: &Path, limits: &ReadLimits) -> Result<Stored> {
    let file = super::heif::HeifFile::open(path)?;
    let (width, height, rgb, bit_depth) = file.primary()?.decode_rgb(limits)?;
    let samples = match rgb {
        super::heif::Rgb::U8(v) => Samples::U8(v),
        super::heif::Rgb::Scaled(v) => Samples::F32(v),
    };
    Ok(Stored { width, height, channels: 3, samples, encoding: Encoding::Display, bit_depth, has_alpha: false, format: FileFormat::Heif })
}

/// Decodes a PNG or JPEG held in memory (an image embedded in another file), with the same
/// limits, panic guard and JPEG truncation check as a file of that format; `path` is the file
/// that holds the bytes, for messages.
pub(crate) fn decode_image_bytes(path: &Path, format: FileFormat, bytes: &[u8], limits: &ReadLimits) -> Result<Decoded> {
    let complete = || match format {
        FileFormat::Jpeg if jpeg_eoi_end(bytes).is_none() => {
            Err(Error::input(path, format!("truncated JPEG: the data stops after {} bytes, before the end-of-image marker", bytes.len())))
        }
        _ => Ok(()),
    };
    match format {
        FileFormat::Png | FileFormat::Jpeg => {
            decode_with_image_crate(path, format, std::io::Cursor::new(bytes), limits, complete).map(Stored::into_decoded)
        }
        other => Err(Error::input(path, format!("an embedded {} image is not supported (PNG or JPEG only)", other.name()))),
    }
}

/// Reads a photo as linear RGB (3 channels).
///
/// Integer formats are decoded with `transfer` (pass [`Transfer::Srgb`] for ordinary photos,
/// `Transfer::Gamma(2.2)` for the official naive-gamma mode), uint8/uint16 NPY arrays too (they
/// hold what an 8/16-bit PNG holds); EXR, float TIFF and float NPY values are kept as stored. Grey images are expanded to RGB and alpha is dropped. NaN or infinite values
/// are an error (naming the first offending pixel).
pub fn read_photo(path: &Path, transfer: Transfer, limits: &ReadLimits) -> Result<Image> {
    read_photo_file(path, transfer, limits).map(|p| p.image)
}

/// A photo read by [`read_photo_file`], with what the caller should tell the user.
#[derive(Clone, Debug)]
pub struct Photo {
    /// Linear RGB.
    pub image: Image,
    /// How the file stored it (integer samples clip the light above white; the highlights
    /// stage, `stages::light_recovery`, reads this).
    pub encoding: PhotoEncoding,
    /// Usable but doubtful (an alpha channel that is not opaque everywhere, which is dropped).
    pub warnings: Vec<String>,
}

/// True when an alpha channel (the last of `c` interleaved samples, `bits` wide, big-endian as
/// PNG stores 16-bit samples) is below its maximum somewhere in `raw`. O(samples), no allocation.
fn translucent_raw(raw: &[u8], c: usize, bits: u8) -> bool {
    match (c, bits) {
        (2 | 4, 8) => raw.iter().skip(c - 1).step_by(c).any(|&a| a != u8::MAX),
        (2 | 4, _) => raw.as_chunks::<2>().0.iter().skip(c - 1).step_by(c).any(|a| *a != [u8::MAX; 2]),
        _ => false,
    }
}

/// [`read_photo`], and a warning when the file's alpha channel, which the photo leaves out, is
/// not opaque everywhere (a cut-out subject: its matte belongs in `--matte`).
pub fn read_photo_file(path: &Path, transfer: Transfer, limits: &ReadLimits) -> Result<Photo> {
    let translucent = std::sync::atomic::AtomicBool::new(false);
    let (image, encoding) = read_photo_rgb(path, transfer, limits, &translucent)?;
    let warnings = if translucent.into_inner() {
        vec![format!(
            "{} has an alpha channel that is not opaque everywhere; it is ignored (the photo is read as RGB): pass a matte with --matte to cut out the subject",
            path.display()
        )]
    } else {
        Vec::new()
    };
    Ok(Photo { image, encoding, warnings })
}

/// [`read_photo`]'s work, and how the file stored the photo; sets `translucent` when the
/// file's alpha is below its maximum somewhere.
fn read_photo_rgb(
    path: &Path,
    transfer: Transfer,
    limits: &ReadLimits,
    translucent: &std::sync::atomic::AtomicBool,
) -> Result<(Image, PhotoEncoding)> {
    use std::sync::atomic::Ordering::Relaxed;
    let format = detect_format(path)?;
    // Integer samples go through a table of `transfer.decode(q / max)` straight to linear RGB
    // (bit-identical to scaling first, then decoding: `decode_table`); a table with only finite
    // entries makes the finiteness scan below unnecessary.
    let which = |channels: usize| -> &'static [usize] {
        match channels {
            1 | 2 => &[0, 0, 0],
            _ => &[0, 1, 2],
        }
    };
    if format == FileFormat::Png {
        let (lut8, lut16) = (decode_table(transfer, 8), std::sync::OnceLock::new());
        let band = |raw: &[u8], c: usize, bits: u8, dst: &mut [MaybeUninit<f32>]| {
            // The 16-bit table only for a 16-bit file (built once, by the first band).
            let lut16: &[f32] = if bits == 16 { lut16.get_or_init(|| decode_table(transfer, 16)) } else { &[] };
            if !translucent.load(Relaxed) && translucent_raw(raw, c, bits) {
                translucent.store(true, Relaxed);
            }
            png_band_into(dst, raw, c, which(c), bits, |q| lut8[q as usize], |q| lut16[q as usize])
        };
        if let Some(png) = super::png_rows::read_png_rows(path, limits, |_| 3, band)? {
            let finite = lut8.iter().chain(lut16.get().into_iter().flatten()).all(|v| v.is_finite());
            return Ok((finish_photo(path, png.image, finite)?, PhotoEncoding::Integer { bits: png.bits, transfer }));
        }
    }
    // An interlaced PNG (the row route declined it) goes to the whole-image decoder directly.
    let d = match format {
        FileFormat::Png => decode_with_image_crate(path, FileFormat::Png, open(path)?, limits, || Ok(()))?,
        _ => read_stored_as(path, format, limits)?,
    };
    let c = d.channels;
    let encoding = match d.encoding {
        Encoding::Display => PhotoEncoding::Integer { bits: d.bit_depth, transfer },
        Encoding::Linear => PhotoEncoding::Linear,
    };
    if d.has_alpha {
        let alpha = |k: usize| (c - 1..).step_by(c).take(k);
        let n = d.width * d.height;
        let below = match &d.samples {
            Samples::U8(v) => alpha(n).any(|i| v[i] != u8::MAX),
            Samples::U16(v) => alpha(n).any(|i| v[i] != u16::MAX),
            Samples::F32(v) => alpha(n).any(|i| v[i] < 1.0),
        };
        translucent.store(below, Relaxed);
    }
    let which = which(c);
    let (data, checked) = match d.samples {
        Samples::U8(v) => {
            let lut = decode_table(transfer, 8);
            (convert(&v, c, which, |q| lut[q as usize]), lut.iter().all(|v| v.is_finite()))
        }
        Samples::U16(v) => {
            let lut = decode_table(transfer, 16);
            (convert(&v, c, which, |q| lut[q as usize]), lut.iter().all(|v| v.is_finite()))
        }
        Samples::F32(v) => {
            let mut data = if c == 3 { v } else { convert(&v, c, which, |x| x) };
            if d.encoding == Encoding::Display {
                apply_decode(&mut data, transfer, d.bit_depth);
            }
            (data, false)
        }
    };
    Ok((finish_photo(path, Image::from_vec(d.width, d.height, 3, data).expect("three channels per pixel"), checked)?, encoding))
}

/// The photo `img` of `path`, or the error naming its first NaN or infinite value; `finite`:
/// every value is known to be finite (no scan).
fn finish_photo(path: &Path, img: Image, finite: bool) -> Result<Image> {
    if let Some(i) = if finite { None } else { first_non_finite(&img.data) } {
        let (x, y) = pixel_of(&img, i);
        return Err(Error::input(path, format!("photo contains a non-finite value ({}) at pixel ({x}, {y})", img.data[i])));
    }
    Ok(img)
}

/// Index of the first NaN or infinite value of `data`. Parallel over blocks of
/// [`PIXELS_PER_TASK`] values, each scanned sequentially: rayon's per-item `position_first`
/// made a 12 MP EXR read ~0.6 s slower.
pub(crate) fn first_non_finite(data: &[f32]) -> Option<usize> {
    use rayon::prelude::*;
    data.par_chunks(PIXELS_PER_TASK)
        .enumerate()
        .find_map_first(|(k, block)| block.iter().position(|v| !v.is_finite()).map(|i| k * PIXELS_PER_TASK + i))
}

/// `(x, y)` of the sample at `index` of `img.data`.
pub(crate) fn pixel_of(img: &Image, index: usize) -> (usize, usize) {
    let p = index / img.channels.max(1);
    (p % img.width.max(1), p / img.width.max(1))
}

/// `transfer.decode(q / max)` for every `q` in `0..=max`, `max = 2^bits - 1` (`bits` 8 or 16):
/// 256 or 65536 entries, built in O(entries) `decode` calls.
fn decode_table(transfer: Transfer, bits: u8) -> Vec<f32> {
    let max = (1u32 << bits) - 1;
    (0..=max).map(|q| transfer.decode(q as f32 / max as f32)).collect()
}

/// Applies `transfer.decode` to `data`, values that for 8 and 16 `bits` are exact multiples of
/// 1/(2^bits - 1): those go through [`decode_table`] (bit-identical to calling `decode` per
/// value), other depths call `decode`. Parallel (rayon), in place.
fn apply_decode(data: &mut [f32], transfer: Transfer, bits: u8) {
    use rayon::prelude::*;
    if transfer == Transfer::Linear {
        return;
    }
    if bits != 8 && bits != 16 {
        data.par_iter_mut().for_each(|v| *v = transfer.decode(*v));
        return;
    }
    let lut = decode_table(transfer, bits);
    let m = ((1u32 << bits) - 1) as f32;
    data.par_iter_mut().for_each(|v| *v = lut[((*v * m).round().clamp(0.0, m)) as usize]);
}

fn image_format(f: FileFormat) -> ImageFormat {
    match f {
        FileFormat::Jpeg => ImageFormat::Jpeg,
        FileFormat::Tiff => ImageFormat::Tiff,
        FileFormat::Exr => ImageFormat::OpenExr,
        _ => ImageFormat::Png,
    }
}

fn image_error(path: &Path, format: FileFormat, limits: &ReadLimits, e: ImageError) -> Error {
    let name = format.name();
    match e {
        ImageError::Limits(e) => Error::input(
            path,
            format!("{name} decoder refused the image: {e} (memory budget derived from the limit of {} pixels)", limits.max_pixels),
        ),
        ImageError::Unsupported(e) => Error::input(path, format!("unsupported {name} variant: {e}")),
        ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::input(path, format!("corrupt or truncated {name}: unexpected end of file"))
        }
        ImageError::IoError(e) => Error::input(path, format!("cannot read {name} data: {e}")),
        other => Error::input(path, format!("corrupt or truncated {name}: {other}")),
    }
}

/// Decodes a PNG or JPEG from `reader` (the whole file). `check_data` runs once the header's
/// dimensions passed the limits and before the pixels are decoded (the JPEG truncation check),
/// so a bomb is refused by its size and a truncated file costs no decoding.
fn decode_with_image_crate<R: BufRead + Seek>(
    path: &Path,
    format: FileFormat,
    reader: R,
    limits: &ReadLimits,
    check_data: impl FnOnce() -> Result<()>,
) -> Result<Stored> {
    guarded(path, format, || {
        let ie = |e| image_error(path, format, limits, e);
        let mut r = ImageReader::with_format(reader, image_format(format));
        let mut l = image::Limits::default();
        l.max_alloc = Some(limits.alloc_budget());
        r.limits(l);
        // `into_decoder` reads only the header; nothing proportional to the size is allocated
        // before the dimensions are checked.
        let dec = r.into_decoder().map_err(ie)?;
        let (w, h) = dec.dimensions();
        limits.check(path, w as u64, h as u64)?;
        check_data()?;
        let img = DynamicImage::from_decoder(dec).map_err(ie)?;
        let (w, h) = (w as usize, h as usize);
        // The decoder's buffer is kept as it is (no copy); conversion to f32 comes later.
        let (samples, channels, bits) = match img {
            DynamicImage::ImageLuma8(b) => (Samples::U8(b.into_raw()), 1, 8),
            DynamicImage::ImageLumaA8(b) => (Samples::U8(b.into_raw()), 2, 8),
            DynamicImage::ImageRgb8(b) => (Samples::U8(b.into_raw()), 3, 8),
            DynamicImage::ImageRgba8(b) => (Samples::U8(b.into_raw()), 4, 8),
            DynamicImage::ImageLuma16(b) => (Samples::U16(b.into_raw()), 1, 16),
            DynamicImage::ImageLumaA16(b) => (Samples::U16(b.into_raw()), 2, 16),
            DynamicImage::ImageRgb16(b) => (Samples::U16(b.into_raw()), 3, 16),
            DynamicImage::ImageRgba16(b) => (Samples::U16(b.into_raw()), 4, 16),
            DynamicImage::ImageRgb32F(b) => (Samples::F32(b.into_raw()), 3, 32),
            DynamicImage::ImageRgba32F(b) => (Samples::F32(b.into_raw()), 4, 32),
            other => {
                return Err(Error::input(path, format!("unsupported {} pixel layout {:?}", format.name(), other.color())));
            }
        };
        let len = match &samples {
            Samples::U8(v) => v.len(),
            Samples::U16(v) => v.len(),
            Samples::F32(v) => v.len(),
        };
        if len != w * h * channels {
            return Err(Error::input(path, format!("corrupt {}: decoded data size mismatch", format.name())));
        }
        let encoding = if bits == 32 { Encoding::Linear } else { Encoding::Display };
        Ok(Stored { width: w, height: h, channels, samples, encoding, bit_depth: bits, has_alpha: matches!(channels, 2 | 4), format })
    })
}

fn decode_exr(path: &Path, limits: &ReadLimits) -> Result<Stored> {
    let (image, bits) = read_exr_image(path, limits, |exr| {
        let rgb = [exr.find("R"), exr.find("G"), exr.find("B")];
        let mut which: Vec<usize> = if let [Some(r), Some(g), Some(b)] = rgb {
            vec![r, g, b]
        } else if let Some(y) = exr.find("Y") {
            vec![y]
        } else if exr.names.len() == 1 {
            vec![0]
        } else {
            return Err(Error::input(path, format!("EXR image needs channels R,G,B, or Y, or a single channel; found: {}", exr.names())));
        };
        if let Some(a) = exr.find("A").filter(|a| !which.contains(a)) {
            which.push(a);
        }
        Ok(which)
    })?;
    Ok(Stored::from_image(image, Encoding::Linear, bits, FileFormat::Exr))
}

/// Offset just past the end-of-image (EOI) marker of the JPEG stream `b`, or `None` when the
/// bytes end first (a truncated file). Bytes after EOI (trailers some cameras append) are
/// allowed.
///
/// Walks the marker segments from SOI: each segment's length is skipped (so an EXIF thumbnail's
/// own EOI inside APP1 is not mistaken for the end), and after each start-of-scan the
/// entropy-coded data is scanned up to the next marker that is not a stuffed `FF 00`, a restart
/// marker or fill bytes. Malformed segments are the decoder's business; this only answers
/// whether the stream reaches its end. O(file size), no allocation.
pub(crate) fn jpeg_eoi_end(b: &[u8]) -> Option<usize> {
    const SOS: u8 = 0xDA;
    const EOI: u8 = 0xD9;
    let mut i = 2; // after SOI
    loop {
        // The next marker: an 0xFF, possibly several (fill bytes), then the marker code.
        i += b.get(i..)?.iter().position(|&x| x == 0xFF)?;
        while *b.get(i)? == 0xFF {
            i += 1;
        }
        let marker = b[i];
        i += 1;
        match marker {
            EOI => return Some(i),
            // Stray stuffed byte, TEM, restart markers, SOI: no length field.
            0x00 | 0x01 | 0xD0..=0xD8 => {}
            _ => {
                let len = u16::from_be_bytes([*b.get(i)?, *b.get(i + 1)?]) as usize;
                i += len;
                if i > b.len() {
                    return None;
                }
                if marker == SOS {
                    // Entropy-coded data: 0xFF is followed by 0x00 (a stuffed byte), a restart
                    // marker or another 0xFF; anything else is the next marker.
                    loop {
                        i += b.get(i..)?.iter().position(|&x| x == 0xFF)?;
                        match *b.get(i + 1)? {
                            0x00 | 0xD0..=0xD7 | 0xFF => i += 1,
                            _ => break,
                        }
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SOI, an APP1 segment holding a thumbnail's own EOI, SOS with entropy data containing a
    /// stuffed byte, a restart marker and fill bytes, then EOI and a trailer.
    fn stream() -> Vec<u8> {
        let mut b = vec![0xFF, 0xD8];
        b.extend([0xFF, 0xE1, 0x00, 0x06, 0xFF, 0xD9, 0xFF, 0xD9]);
        b.extend([0xFF, 0xDA, 0x00, 0x03, 0x01]);
        b.extend([0x12, 0xFF, 0x00, 0x34, 0xFF, 0xD0, 0x56, 0xFF, 0xFF, 0xD1, 0x78]);
        b.extend([0xFF, 0xD9]);
        b
    }

    #[test]
    fn jpeg_walk_finds_the_real_eoi() {
        let mut b = stream();
        let end = b.len();
        assert_eq!(jpeg_eoi_end(&b), Some(end));
        b.extend(b"trailer");
        assert_eq!(jpeg_eoi_end(&b), Some(end));
    }

    /// The direct table decode of `read_photo` equals the old two steps (scale to [0, 1],
    /// then the table of `apply_decode` indexed by rounding back), and the formula, exactly.
    #[test]
    fn decode_table_equals_scale_then_decode() {
        for transfer in [Transfer::Srgb, Transfer::Gamma(2.2), Transfer::Linear] {
            for bits in [8u8, 16] {
                let max = ((1u32 << bits) - 1) as f32;
                let lut = decode_table(transfer, bits);
                let mut scaled: Vec<f32> = (0..=max as u32).map(|q| q as f32 / max).collect();
                apply_decode(&mut scaled, transfer, bits);
                for (q, (&a, &b)) in lut.iter().zip(&scaled).enumerate() {
                    assert_eq!(a.to_bits(), b.to_bits(), "{transfer:?} {bits}-bit level {q}");
                    assert_eq!(a.to_bits(), transfer.decode(q as f32 / max).to_bits());
                }
            }
        }
    }

    #[test]
    fn convert_selects_channels_and_first_non_finite_finds_the_first() {
        let src: Vec<u8> = (0..8).collect(); // 2 RGBA pixels
        assert_eq!(convert(&src, 4, &[0, 1, 2], |q| q as f32), vec![0.0, 1.0, 2.0, 4.0, 5.0, 6.0]);
        assert_eq!(convert(&src[..2], 1, &[0, 0, 0], |q| q as f32), vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
        let mut v = vec![0.0f32; 3 * PIXELS_PER_TASK];
        assert_eq!(first_non_finite(&v), None);
        v[2 * PIXELS_PER_TASK + 5] = f32::INFINITY;
        v[PIXELS_PER_TASK + 7] = f32::NAN;
        assert_eq!(first_non_finite(&v), Some(PIXELS_PER_TASK + 7));
    }

    #[test]
    fn jpeg_walk_refuses_every_cut() {
        let b = stream();
        for cut in 0..b.len() {
            assert_eq!(jpeg_eoi_end(&b[..cut]), None, "cut at {cut}");
        }
    }
}
