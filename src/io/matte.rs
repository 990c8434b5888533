//! Mattes (alpha / segmentation masks): one channel in [0, 1].
//!
//! Accepted files:
//! - a grey image (8/16-bit PNG/TIFF/JPEG scaled to [0, 1], float TIFF as stored); no transfer
//!   function is applied, a matte is coverage, not light;
//! - the alpha channel of a grey+alpha or RGBA image. Exception: a fully opaque image (alpha 1
//!   everywhere) whose colour is grey (R = G = B) and not constant is a grey matte saved with an
//!   alpha channel, and its grey is used;
//! - an RGB image with R = G = B everywhere (a grey matte saved as colour);
//! - EXR: channel `A`, else `Y`, else `R`, else the only channel;
//! - NPY `H x W` or `H x W x 1`.
//!
//! Values may stray outside [0, 1] by up to [`MATTE_TOLERANCE`] (float round-off) and are then
//! clamped; anything further out, and NaN or infinity, is an error naming the file and the
//! range found.

use super::depth::{is_grey, single_grey_channel};
use super::exr_file::read_exr_image;
use super::format::{FileFormat, detect_format};
use super::image_file::{first_non_finite, pixel_of, read_decoded};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// How far outside [0, 1] a matte value may be and still be accepted (then clamped).
pub const MATTE_TOLERANCE: f32 = 1e-3;

/// Reads a matte as one channel in [0, 1] (see the module doc).
pub fn read_matte(path: &Path, limits: &ReadLimits) -> Result<Image> {
    let mut img = match detect_format(path)? {
        FileFormat::Exr => {
            read_exr_image(path, limits, |exr| {
                let i = exr.find_first(&["A", "Y", "R"]).or((exr.names.len() == 1).then_some(0)).ok_or_else(|| {
                    Error::input(path, format!("EXR matte needs a channel named A, Y or R, or a single channel; found: {}", exr.names()))
                })?;
                Ok(vec![i])
            })?
            .0
        }
        FileFormat::Npy => {
            let image = super::npy::read_npy_guarded(path, limits)?;
            if image.channels != 1 {
                return Err(Error::input(path, format!("NPY matte has {} channels; expected shape H x W or H x W x 1", image.channels)));
            }
            image
        }
        _ => {
            let d = read_decoded(path, limits)?.image;
            match d.channels {
                2 | 4 => {
                    let alpha = d.channel(d.channels - 1);
                    let opaque = alpha.data.iter().all(|&a| a == 1.0);
                    let grey = d.channels == 2 || is_grey(&d);
                    let first = d.data[0];
                    let varies = d.data.iter().step_by(d.channels).any(|&v| v != first);
                    if opaque && grey && varies { d.channel(0) } else { alpha }
                }
                _ => single_grey_channel(path, d, "matte")?,
            }
        }
    };
    validate_unit_range(path, &mut img, "matte")?;
    Ok(img)
}

/// Checks that every value is finite and within [0, 1] up to [`MATTE_TOLERANCE`], then clamps
/// to [0, 1]. `what` names the data in messages ("matte", "layer alpha").
pub(crate) fn validate_unit_range(path: &Path, img: &mut Image, what: &str) -> Result<()> {
    use rayon::prelude::*;
    if let Some(i) = first_non_finite(&img.data) {
        let (x, y) = pixel_of(img, i);
        return Err(Error::input(path, format!("{what} contains a non-finite value ({}) at pixel ({x}, {y})", img.data[i])));
    }
    let (lo, hi) = img
        .data
        .par_chunks(1 << 16)
        .map(|c| c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v))))
        .reduce(|| (f32::INFINITY, f32::NEG_INFINITY), |a, b| (a.0.min(b.0), a.1.max(b.1)));
    if lo < -MATTE_TOLERANCE || hi > 1.0 + MATTE_TOLERANCE {
        return Err(Error::input(
            path,
            format!("{what} values must be in [0, 1]; found the range [{lo}, {hi}] (an 8-bit array saved as NPY must be divided by 255)"),
        ));
    }
    if lo < 0.0 || hi > 1.0 {
        img.data.par_iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
    }
    Ok(())
}
