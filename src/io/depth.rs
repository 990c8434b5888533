//! Depth and disparity maps: one channel of raw values.
//!
//! No normalization or validation of the values happens here (the caller converts depth to
//! disparity, and holes such as NaN or 0 are the fill-depth stage's business). Accepted files:
//! - EXR: a single channel of any name, else the first of the channels named `Z`, `Y`, `R`
//!   (in that priority; exact names first, then case-insensitive);
//! - 16-bit PNG or TIFF: value / 65535, so the map is in [0, 1] (rescale if the file stores
//!   e.g. millimetres);
//! - 32-bit float TIFF: values as stored;
//! - 8-bit PNG/TIFF/JPEG: value / 255. Allowed, but only 256 levels: [`read_depth_map`] puts
//!   a precision warning in [`DepthMap::warnings`];
//! - NPY `H x W` or `H x W x 1` (values as stored, integer dtypes not rescaled).
//!
//! Grey+alpha images use the grey channel; RGB(A) images are accepted only when R = G = B
//! everywhere (a grey map saved as colour).

use super::exr_file::read_exr_image;
use super::format::{FileFormat, detect_format};
use super::image_file::read_decoded;
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// A depth (or disparity) map with what is known of its precision.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthMap {
    /// One channel, raw values (see the module doc).
    pub image: Image,
    /// Bits per sample in the file (8, 16, 32, 64). 8 means only 256 depth levels: worth a warning.
    pub bit_depth: u8,
    /// The file's format (detected from its content).
    pub format: FileFormat,
    /// What the caller should tell the user (each names the file): today the precision warning
    /// of an 8-bit map.
    pub warnings: Vec<String>,
}

/// Bit depths at or below this get [`precision_warning`]: 8 bits are 256 depth levels, few
/// enough to show as steps in the blur of a smooth surface.
const LOW_PRECISION_BITS: u8 = 8;

/// The warning for a depth map stored with only `bits` bits per sample.
fn precision_warning(path: &Path, bits: u8) -> String {
    format!(
        "{} is an {bits}-bit depth map: only {} depth levels, which can show as steps in the blur; \
         a 16-bit PNG/TIFF or a float EXR/TIFF/NPY keeps the depth's precision",
        path.display(),
        1u32 << bits
    )
}

/// Reads a depth or disparity map (see the module doc), with its bit depth and the warnings it
/// deserves (an 8-bit map).
pub fn read_depth_map(path: &Path, limits: &ReadLimits) -> Result<DepthMap> {
    let mut map = read_depth_map_raw(path, limits)?;
    if map.bit_depth <= LOW_PRECISION_BITS {
        map.warnings.push(precision_warning(path, map.bit_depth));
    }
    Ok(map)
}

fn read_depth_map_raw(path: &Path, limits: &ReadLimits) -> Result<DepthMap> {
    let warnings = Vec::new();
    match detect_format(path)? {
        FileFormat::Exr => {
            let (image, bit_depth) = read_exr_image(path, limits, |exr| {
                let i = if exr.names.len() == 1 { Some(0) } else { exr.find_first(&["Z", "Y", "R"]) };
                let i = i.ok_or_else(|| {
                    Error::input(path, format!("EXR depth map needs a single channel or a channel named Z, Y or R; found: {}", exr.names()))
                })?;
                Ok(vec![i])
            })?;
            Ok(DepthMap { image, bit_depth, format: FileFormat::Exr, warnings })
        }
        FileFormat::Npy => {
            let image = super::npy::read_npy_guarded(path, limits)?;
            if image.channels != 1 {
                return Err(Error::input(
                    path,
                    format!("NPY depth map has {} channels; expected shape H x W or H x W x 1", image.channels),
                ));
            }
            Ok(DepthMap { image, bit_depth: 32, format: FileFormat::Npy, warnings })
        }
        _ => {
            let d = read_decoded(path, limits)?;
            let (bit_depth, format) = (d.bit_depth, d.format);
            let image = single_grey_channel(path, d.image, "depth map")?;
            Ok(DepthMap { image, bit_depth, format, warnings })
        }
    }
}

/// Reads a depth or disparity map as one channel of raw values (see the module doc), without
/// its warnings: use [`read_depth_map`] where they can be shown.
pub fn read_depth(path: &Path, limits: &ReadLimits) -> Result<Image> {
    read_depth_map(path, limits).map(|d| d.image)
}

/// The grey channel of a 1/2-channel image, or of an RGB(A) image whose R, G, B are equal
/// (a one-channel image is returned as it is, no copy).
pub(crate) fn single_grey_channel(path: &Path, img: Image, what: &str) -> Result<Image> {
    match img.channels {
        1 => Ok(img),
        2 => Ok(img.channel(0)),
        3 | 4 if is_grey(&img) => Ok(img.channel(0)),
        c => Err(Error::input(
            path,
            format!("{what} is a colour image ({c} channels with different R, G, B); expected a single-channel (greyscale) image"),
        )),
    }
}

/// True if channels 0, 1, 2 are equal in every pixel.
pub(crate) fn is_grey(img: &Image) -> bool {
    img.channels >= 3 && img.data.chunks_exact(img.channels).all(|p| p[0] == p[1] && p[1] == p[2])
}
