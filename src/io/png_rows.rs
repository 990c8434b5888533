//! A PNG decoded row by row straight to `f32`, the conversion overlapping the decode.
//!
//! A PNG is one deflate stream: its inflate and row filters run on one thread whatever the
//! decoder. [`read_png_rows`] keeps that thread on the stream only: each band of [`BAND_ROWS`]
//! decoded rows goes to a rayon job that converts it into its part of the output while the next
//! band is decoded (a photo to linear RGB, any other raster to its stored channels scaled to
//! [0, 1]: [`super::image_file`]). So the conversion and the output's page faults run on the
//! other cores instead of after the decode, and no integer copy of the image is kept (12.2 MP:
//! see README, *Decode and encode*). The values are those of the whole-image route through the
//! `image` crate, bit for bit: the same `png` decoder and transformation (`EXPAND`: palettes and
//! 1/2/4-bit grey to 8 bits, `tRNS` to alpha), the same conversion (`tests/io_formats.rs`
//! compares both routes on every colour type and depth).
//!
//! Interlaced files (Adam7 delivers its rows in seven passes) are left to the whole-image
//! route: [`read_png_rows`] returns `None` for them.

use super::format::{FileFormat, guarded, open};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use std::mem::MaybeUninit;
use std::path::Path;
use std::sync::Mutex;

/// Rows per conversion job: 32 rows of a 4032-pixel 16-bit RGB photo are 0.77 MB of samples
/// (in cache while converted), ~95 jobs for 12 MP.
const BAND_ROWS: usize = 32;

/// A PNG decoded by [`read_png_rows`]: the converted image and the file's bits per sample.
pub(crate) struct PngRows {
    /// `out_channels(channels)` values per pixel, as the caller's conversion wrote them.
    pub image: Image,
    /// 8 or 16.
    pub bits: u8,
}

/// The PNG `path` (already detected as one), decoded row by row: `convert(raw band, channels,
/// bits, output band)` turns each band of decoded rows (`channels` interleaved samples per
/// pixel after `EXPAND`, `bits` 8 or 16, 16-bit samples big-endian as stored) into its
/// `width * rows * out_channels(channels)` output values, and must write all of them.
/// `Ok(None)` for an interlaced file (the caller decodes it whole). Errors as the whole-image
/// route: dimensions over `limits` before any pixel is decoded, a corrupt or truncated stream, a
/// decoder panic. Allocates the output and a few band buffers (recycled).
pub(crate) fn read_png_rows(
    path: &Path,
    limits: &ReadLimits,
    out_channels: impl Fn(usize) -> usize,
    convert: impl Fn(&[u8], usize, u8, &mut [MaybeUninit<f32>]) + Sync,
) -> Result<Option<PngRows>> {
    guarded(path, FileFormat::Png, || {
        let pe = |e| png_error(path, limits, e);
        let budget = usize::try_from(limits.alloc_budget()).unwrap_or(usize::MAX);
        let mut decoder = png::Decoder::new_with_limits(open(path)?, png::Limits { bytes: budget });
        // As the `image` crate sets it up (so a malformed text chunk fails here as there).
        decoder.set_ignore_text_chunk(false);
        let info = decoder.read_header_info().map_err(pe)?;
        let (w, h) = (info.width, info.height);
        limits.check(path, w as u64, h as u64)?;
        if info.interlaced {
            return Ok(None);
        }
        decoder.set_transformations(png::Transformations::EXPAND);
        let mut reader = decoder.read_info().map_err(pe)?;
        let (colour, depth) = reader.output_color_type();
        let bits = match depth {
            png::BitDepth::Eight => 8,
            png::BitDepth::Sixteen => 16,
            other => return Err(Error::input(path, format!("unsupported PNG variant: {colour:?} at {other:?} bits after expansion"))),
        };
        let channels = colour.samples();
        let (w, h, n) = (w as usize, h as usize, out_channels(channels));
        let line = w * channels * usize::from(bits / 8);
        let mut out = Vec::<f32>::with_capacity(w * h * n);
        let dst = &mut out.spare_capacity_mut()[..w * h * n];
        let spare: Mutex<Vec<Vec<u8>>> = Mutex::new(Vec::new());
        let (convert, spare) = (&convert, &spare);
        rayon::scope(|s| -> Result<()> {
            for band in dst.chunks_mut((BAND_ROWS * w * n).max(1)) {
                let rows = band.len() / (w * n);
                let mut raw = spare.lock().ok().and_then(|mut v| v.pop()).unwrap_or_default();
                raw.clear();
                for _ in 0..rows {
                    match reader.next_row().map_err(pe)? {
                        Some(row) if row.data().len() == line => raw.extend_from_slice(row.data()),
                        _ => return Err(Error::input(path, "corrupt or truncated PNG: fewer rows than its header says")),
                    }
                }
                s.spawn(move |_| {
                    convert(&raw, channels, bits, band);
                    if let Ok(mut v) = spare.lock() {
                        v.push(raw);
                    }
                });
            }
            // The end of the image data (the zlib stream's checksum), which the whole-image
            // route reads too: a stream cut after its last pixel is as corrupt here as there.
            match reader.next_row().map_err(pe)? {
                None => Ok(()),
                Some(_) => Err(Error::input(path, "corrupt PNG: more rows than its header says")),
            }
        })?;
        let len = dst.len();
        // SAFETY: every band of `dst` went to one job, which wrote all of it (`convert`'s
        // contract); `rayon::scope` returned, so every job has finished. `dst` is the first
        // `len` elements of `out`'s capacity.
        unsafe { out.set_len(len) };
        let image = Image::from_vec(w, h, n, out).expect("out_channels values per pixel");
        Ok(Some(PngRows { image, bits }))
    })
}

/// The whole-image route's messages for the `png` crate's errors.
fn png_error(path: &Path, limits: &ReadLimits, e: png::DecodingError) -> Error {
    match e {
        png::DecodingError::LimitsExceeded => Error::input(
            path,
            format!(
                "PNG decoder refused the image: memory limit exceeded (memory budget derived from the limit of {} pixels)",
                limits.max_pixels
            ),
        ),
        png::DecodingError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::input(path, "corrupt or truncated PNG: unexpected end of file")
        }
        png::DecodingError::IoError(e) => Error::input(path, format!("cannot read PNG data: {e}")),
        other => Error::input(path, format!("corrupt or truncated PNG: {other}")),
    }
}
