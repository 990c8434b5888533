//! The depth map a photo carries inside itself, whatever the format: a JPEG's Dynamic Depth
//! items ([`super::dynamic_depth`]) or GDepth XMP ([`super::gdepth`]), a HEIF's depth image
//! ([`super::heif_depth`]). What every embedding shares is in [`super::embedded_depth`].
//!
//! Contract of [`read_embedded`]: a JPEG's XMP is read from the APP1 segments ([`super::xmp`]);
//! where a file has both JPEG formats, the Dynamic Depth map is read (a warning says the GDepth
//! one is not). A HEIF is read through libheif. Any other format, or a photo that embeds
//! nothing, is `Ok(None)`. Every problem is an error naming the photo and the field or item at
//! fault: a photo that claims a depth map never reads as one without depth.

use super::embedded_depth::{EmbeddedDepth, Packets};
use super::format::{FileFormat, detect_format, read_input};
use super::gdepth::{NS_GDEPTH, read_gdepth};
use super::limits::ReadLimits;
use super::xmp::read_jpeg_xmp;
use super::{dynamic_depth, heif_depth};
use crate::error::Result;
use std::path::Path;

/// Reads the depth map the photo `path` embeds (see the module doc): `Ok(None)` when the file
/// is not a JPEG or embeds none.
pub fn read_embedded(path: &Path, limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    match detect_format(path)? {
        FileFormat::Jpeg => read_embedded_bytes(path, &read_input(path)?, limits),
        FileFormat::Heif => heif_depth::read_depth(path, limits),
        _ => Ok(None),
    }
}

/// [`read_embedded`] of the JPEG bytes `b` of the file `path`.
pub fn read_embedded_bytes(path: &Path, b: &[u8], limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    let xmp = read_jpeg_xmp(path, b)?;
    let packets = Packets::parse(path, &xmp)?;
    match dynamic_depth::read(path, b, &xmp, &packets, limits)? {
        Some(mut dd) => {
            // Named, not decoded: the GDepth map is not used.
            let gdepth = ["Format", "Data"].iter().any(|n| packets.docs.iter().any(|d| !d.values(NS_GDEPTH, n).is_empty()));
            if gdepth {
                dd.warnings.push(format!("{} also has GDepth depth metadata; the Dynamic Depth map is the one used", path.display()));
            }
            Ok(Some(dd))
        }
        None => read_gdepth(path, b, &xmp, &packets, limits),
    }
}
