//! Renderer layers: 5 channels R, G, B, A, D (linear colour, alpha, normalized disparity).
//!
//! Accepted files: EXR with channels named R, G, B, A, D (case-insensitive; exact names win;
//! other channels are ignored), or NPY `H x W x 5` (float32/float64). Values are returned
//! unchanged; NaN or infinity anywhere is an error naming the channel and pixel. Alpha outside
//! [0, 1] (beyond [`MATTE_TOLERANCE`] of float round-off) is kept but earns a warning in
//! [`LayerFile::warnings`]: the renderer assumes coverage in [0, 1].

use super::exr_file::read_exr_image;
use super::format::{FileFormat, detect_format};
use super::image_file::pixel_of;
use super::limits::ReadLimits;
use super::matte::MATTE_TOLERANCE;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::layer::A;
use rayon::prelude::*;
use std::path::Path;

/// Channel names of a layer, in [`read_layer`]'s output order.
pub const LAYER_CHANNELS: [&str; 5] = ["R", "G", "B", "A", "D"];

/// A layer as read from its file, with the warnings it deserves.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerFile {
    /// 5 channels R, G, B, A, D, values as stored (see the module doc).
    pub image: Image,
    /// What the caller should tell the user (each names the file): alpha outside [0, 1].
    pub warnings: Vec<String>,
}

/// Reads a layer as a 5-channel R,G,B,A,D image (see the module doc), without its warnings:
/// use [`read_layer_file`] where they can be shown.
pub fn read_layer(path: &Path, limits: &ReadLimits) -> Result<Image> {
    read_layer_file(path, limits).map(|l| l.image)
}

/// Reads a layer (see the module doc) with its warnings. One extra pass over the alpha channel.
pub fn read_layer_file(path: &Path, limits: &ReadLimits) -> Result<LayerFile> {
    let image = read_layer_image(path, limits)?;
    let mut warnings = Vec::new();
    // Parallel over blocks of pixels (a sequential pass took ~40 ms of a 12.2 MP layer's read).
    let n = LAYER_CHANNELS.len();
    let (lo, hi) = image
        .data
        .par_chunks(n << 14)
        .map(|c| c.chunks_exact(n).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), px| (lo.min(px[A]), hi.max(px[A]))))
        .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    if lo < -MATTE_TOLERANCE || hi > 1.0 + MATTE_TOLERANCE {
        warnings.push(format!(
            "{} has layer alpha in [{lo}, {hi}], outside [0, 1]; used as stored, but the renderer expects coverage in [0, 1]",
            path.display()
        ));
    }
    Ok(LayerFile { image, warnings })
}

fn read_layer_image(path: &Path, limits: &ReadLimits) -> Result<Image> {
    let img = match detect_format(path)? {
        FileFormat::Exr => {
            read_exr_image(path, limits, |exr| {
                let found: Vec<Option<usize>> = LAYER_CHANNELS.iter().map(|n| exr.find(n)).collect();
                let missing: Vec<&str> = LAYER_CHANNELS.iter().zip(&found).filter(|(_, f)| f.is_none()).map(|(n, _)| *n).collect();
                if !missing.is_empty() {
                    return Err(Error::input(
                        path,
                        format!("EXR layer needs channels R, G, B, A, D; missing {} (found: {})", missing.join(", "), exr.names()),
                    ));
                }
                Ok(found.into_iter().flatten().collect())
            })?
            .0
        }
        FileFormat::Npy => {
            let image = super::npy::read_npy_guarded(path, limits)?;
            if image.channels != 5 {
                return Err(Error::input(
                    path,
                    format!("NPY layer has {} channel(s); expected shape H x W x 5 (R, G, B, A, D)", image.channels),
                ));
            }
            image
        }
        other => {
            return Err(Error::input(
                path,
                format!("a layer must be an EXR with channels R, G, B, A, D or an NPY array H x W x 5; this is a {} file", other.name()),
            ));
        }
    };
    if let Some(i) = img.data.iter().position(|v| !v.is_finite()) {
        let (x, y) = pixel_of(&img, i);
        return Err(Error::input(
            path,
            format!("layer channel {} has a non-finite value ({}) at pixel ({x}, {y})", LAYER_CHANNELS[i % 5], img.data[i]),
        ));
    }
    Ok(img)
}
