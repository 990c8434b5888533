//! Samples as a decoder delivers them ([`Stored`]), before their conversion to `f32` images:
//! the one type every raster decoder (PNG, JPEG, TIFF, EXR, NPY, HEIF) returns, so that
//! [`super::image_file`] scales them for [`super::image_file::Decoded`] or turns them into
//! linear RGB in one pass.

use super::format::FileFormat;
use crate::image::Image;

/// How the decoded values relate to light.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Encoding {
    /// Display-encoded integer samples (8/16-bit PNG, JPEG, TIFF) scaled to [0, 1]; a transfer
    /// function (sRGB or gamma) must be decoded to get linear light.
    Display,
    /// Already linear values (EXR, float TIFF, NPY), kept as stored.
    Linear,
}

/// Samples as the decoder delivered them. Integer samples are display-encoded and span their
/// full width (0..=255, 0..=65535); `F32` holds float formats' values, or integer formats
/// already scaled to [0, 1] where the reader had to transform them (32-bit or white-is-zero
/// TIFF).
pub(crate) enum Samples {
    /// 8-bit integers.
    U8(Vec<u8>),
    /// 16-bit integers.
    U16(Vec<u16>),
    /// Floats: linear values, or display values in [0, 1] (see [`Stored::encoding`]).
    F32(Vec<f32>),
}

/// A decoded file before its conversion to `f32` images: `read_decoded` scales it to a
/// `Decoded` image, `read_photo` turns it into linear RGB in one pass (no [0, 1] copy between;
/// both in [`super::image_file`]).
pub(crate) struct Stored {
    pub width: usize,
    pub height: usize,
    /// Interleaved channels per pixel (1 to 4 for images).
    pub channels: usize,
    /// `width * height * channels` samples.
    pub samples: Samples,
    pub encoding: Encoding,
    pub bit_depth: u8,
    pub has_alpha: bool,
    pub format: FileFormat,
}

impl Stored {
    /// Float samples of `image` (its channels; alpha when 2 or 4).
    pub(crate) fn from_image(image: Image, encoding: Encoding, bit_depth: u8, format: FileFormat) -> Stored {
        let (width, height, channels) = (image.width, image.height, image.channels);
        let has_alpha = matches!(channels, 2 | 4);
        Stored { width, height, channels, samples: Samples::F32(image.data), encoding, bit_depth, has_alpha, format }
    }
}
