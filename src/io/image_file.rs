//! Raster image reading (PNG, JPEG, TIFF, EXR, NPY) into [`Decoded`], and photos as linear RGB.
//!
//! PNG and JPEG go through the `image` crate, TIFF through the `tiff` crate (see
//! [`super::tiff_file`]), EXR through the `exr` crate. Integer samples are scaled to [0, 1]
//! directly from their stored width (8-bit / 255, 16-bit / 65535), so 16-bit files keep their
//! full precision. EXIF orientation and ICC profiles are not applied: pixels are used in stored
//! order, so a photo and a depth map computed from the same stored pixels stay aligned.

use super::exr_file::read_exr_channels;
use super::format::{detect_format, guarded, open, FileFormat};
use super::limits::ReadLimits;
use crate::color::Transfer;
use crate::error::{Error, Result};
use crate::image::Image;
use image::{DynamicImage, ImageDecoder, ImageError, ImageFormat, ImageReader};
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
        f @ (FileFormat::Png | FileFormat::Jpeg) => decode_with_image_crate(path, f, limits),
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

fn decode_with_image_crate(path: &Path, format: FileFormat, limits: &ReadLimits) -> Result<Decoded> {
    let reader = open(path)?;
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
        return Err(Error::input(
            path,
            format!("EXR image needs channels R,G,B, or Y, or a single channel; found: {}", exr.names()),
        ));
    };
    if let Some(a) = alpha.filter(|a| !which.contains(a)) {
        which.push(a);
    }
    let image = exr.to_image(&which);
    let has_alpha = matches!(which.len(), 2 | 4);
    Ok(Decoded { image, encoding: Encoding::Linear, bit_depth: exr.bits(&which), has_alpha, format: FileFormat::Exr })
}
