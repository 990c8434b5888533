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

use super::exr_file::read_exr_channels;
use super::format::{FileFormat, detect_format, guarded, open, read_input};
use super::limits::ReadLimits;
use crate::color::Transfer;
use crate::error::{Error, Result};
use crate::image::Image;
use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader};
use std::io::{BufRead, Seek};
use std::path::Path;

/// How the decoded values relate to light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Display-encoded integer samples (8/16-bit PNG, JPEG, TIFF) scaled to [0, 1]; a transfer
    /// function (sRGB or gamma) must be decoded to get linear light.
    Display,
    /// Already linear values (EXR, float TIFF, NPY), kept as stored.
    Linear,
}

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
/// NPY arrays of shape H x W or H x W x C (C in 1..=4) are accepted as linear images with their
/// values unchanged. EXR files need channels R,G,B (optionally A), or Y (optionally A), or a
/// single channel of any name.
pub fn read_decoded(path: &Path, limits: &ReadLimits) -> Result<Decoded> {
    match detect_format(path)? {
        FileFormat::Png => decode_with_image_crate(path, FileFormat::Png, open(path)?, limits, || Ok(())),
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
        FileFormat::Npy => {
            let image = super::format::read_npy_guarded(path, limits)?;
            if image.channels > 4 {
                return Err(Error::input(
                    path,
                    format!("NPY array has {} channels; an image needs 1 to 4 (H x W, or H x W x C)", image.channels),
                ));
            }
            let has_alpha = matches!(image.channels, 2 | 4);
            Ok(Decoded { image, encoding: Encoding::Linear, bit_depth: 32, has_alpha, format: FileFormat::Npy })
        }
    }
}

/// Reads a photo as linear RGB (3 channels).
///
/// Integer formats are decoded with `transfer` (pass [`Transfer::Srgb`] for ordinary photos,
/// `Transfer::Gamma(2.2)` for the official naive-gamma mode); EXR, float TIFF and NPY values are
/// kept as stored. Grey images are expanded to RGB and alpha is dropped. NaN or infinite values
/// are an error (naming the first offending pixel).
pub fn read_photo(path: &Path, transfer: Transfer, limits: &ReadLimits) -> Result<Image> {
    let d = read_decoded(path, limits)?;
    let mut img = match d.image.channels {
        3 => d.image,
        1 | 2 => d.image.select_channels(&[0, 0, 0]),
        _ => d.image.select_channels(&[0, 1, 2]),
    };
    if d.encoding == Encoding::Display {
        apply_decode(&mut img, transfer, d.bit_depth);
    }
    if let Some(i) = img.data.iter().position(|v| !v.is_finite()) {
        let (x, y) = pixel_of(&img, i);
        return Err(Error::input(path, format!("photo contains a non-finite value ({}) at pixel ({x}, {y})", img.data[i])));
    }
    Ok(img)
}

/// `(x, y)` of the sample at `index` of `img.data`.
pub(crate) fn pixel_of(img: &Image, index: usize) -> (usize, usize) {
    let p = index / img.channels.max(1);
    (p % img.width.max(1), p / img.width.max(1))
}

/// Applies `transfer.decode` to values that are exact multiples of 1/(2^bits - 1), through a
/// lookup table for 8 and 16-bit data (bit-identical to calling `decode` per value).
fn apply_decode(img: &mut Image, transfer: Transfer, bits: u8) {
    if transfer == Transfer::Linear {
        return;
    }
    let max = match bits {
        8 => 255u32,
        16 => 65535,
        _ => {
            img.map_inplace(|v| transfer.decode(v));
            return;
        }
    };
    let lut: Vec<f32> = (0..=max).map(|q| transfer.decode(q as f32 / max as f32)).collect();
    let m = max as f32;
    img.map_inplace(|v| lut[((v * m).round().clamp(0.0, m)) as usize]);
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
) -> Result<Decoded> {
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
        fn scale<T: Copy + Into<f32>>(v: &[T], max: f32) -> Vec<f32> {
            v.iter().map(|&q| q.into() / max).collect()
        }
        let (data, channels, bits, encoding) = match &img {
            DynamicImage::ImageLuma8(b) => (scale(b.as_raw(), 255.0), 1, 8, Encoding::Display),
            DynamicImage::ImageLumaA8(b) => (scale(b.as_raw(), 255.0), 2, 8, Encoding::Display),
            DynamicImage::ImageRgb8(b) => (scale(b.as_raw(), 255.0), 3, 8, Encoding::Display),
            DynamicImage::ImageRgba8(b) => (scale(b.as_raw(), 255.0), 4, 8, Encoding::Display),
            DynamicImage::ImageLuma16(b) => (scale(b.as_raw(), 65535.0), 1, 16, Encoding::Display),
            DynamicImage::ImageLumaA16(b) => (scale(b.as_raw(), 65535.0), 2, 16, Encoding::Display),
            DynamicImage::ImageRgb16(b) => (scale(b.as_raw(), 65535.0), 3, 16, Encoding::Display),
            DynamicImage::ImageRgba16(b) => (scale(b.as_raw(), 65535.0), 4, 16, Encoding::Display),
            DynamicImage::ImageRgb32F(b) => (b.as_raw().clone(), 3, 32, Encoding::Linear),
            DynamicImage::ImageRgba32F(b) => (b.as_raw().clone(), 4, 32, Encoding::Linear),
            other => {
                return Err(Error::input(path, format!("unsupported {} pixel layout {:?}", format.name(), other.color())));
            }
        };
        let image = Image::from_vec(w, h, channels, data)
            .ok_or_else(|| Error::input(path, format!("corrupt {}: decoded data size mismatch", format.name())))?;
        Ok(Decoded { image, encoding, bit_depth: bits, has_alpha: matches!(channels, 2 | 4), format })
    })
}

fn decode_exr(path: &Path, limits: &ReadLimits) -> Result<Decoded> {
    let exr = read_exr_channels(path, limits)?;
    let rgb = [exr.find("R"), exr.find("G"), exr.find("B")];
    let alpha = exr.find("A");
    let mut which: Vec<usize> = if let [Some(r), Some(g), Some(b)] = rgb {
        vec![r, g, b]
    } else if let Some(y) = exr.find("Y") {
        vec![y]
    } else if exr.channels.len() == 1 {
        vec![0]
    } else {
        return Err(Error::input(path, format!("EXR image needs channels R,G,B, or Y, or a single channel; found: {}", exr.names())));
    };
    if let Some(a) = alpha.filter(|a| !which.contains(a)) {
        which.push(a);
    }
    let image = exr.to_image(&which);
    let has_alpha = matches!(which.len(), 2 | 4);
    Ok(Decoded { image, encoding: Encoding::Linear, bit_depth: exr.bits(&which), has_alpha, format: FileFormat::Exr })
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

    #[test]
    fn jpeg_walk_refuses_every_cut() {
        let b = stream();
        for cut in 0..b.len() {
            assert_eq!(jpeg_eoi_end(&b[..cut]), None, "cut at {cut}");
        }
    }
}
