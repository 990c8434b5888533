//! TIFF decoding with the `tiff` crate directly (the `image` crate does not read single-channel
//! float TIFFs, the usual container of float depth maps).
//!
//! Accepted: grey, grey+alpha, RGB and RGBA; 8, 16 or 32-bit unsigned integers (scaled to
//! [0,1]) or 16/32/64-bit floats (kept as is); chunky or planar; any compression the `tiff`
//! crate supports. Only the first image of a multi-page file is read. Refused with a message:
//! palette, CMYK, YCbCr, Lab, bilevel and other sub-byte depths, signed integers.

use super::format::{FileFormat, guarded, open};
use super::limits::ReadLimits;
use super::samples::{Encoding, Samples, Stored};
use crate::error::{Error, Result};
use std::path::Path;
use tiff::decoder::{Decoder, DecodingResult, Limits};
use tiff::tags::Tag;
use tiff::{ColorType, TiffError};

fn tiff_error(path: &Path, e: TiffError) -> Error {
    match e {
        TiffError::UnsupportedError(e) => Error::input(path, format!("unsupported TIFF variant: {e}")),
        TiffError::LimitsExceeded => Error::input(path, "TIFF decoder memory limit exceeded (corrupt strip or tile sizes?)"),
        TiffError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            Error::input(path, "corrupt or truncated TIFF: unexpected end of file")
        }
        TiffError::IoError(e) => Error::input(path, format!("cannot read TIFF data: {e}")),
        other => Error::input(path, format!("corrupt or truncated TIFF: {other}")),
    }
}

/// Decodes the first image of a TIFF file (see the module doc for what is accepted).
pub(crate) fn decode_tiff(path: &Path, limits: &ReadLimits) -> Result<Stored> {
    let reader = open(path)?;
    guarded(path, FileFormat::Tiff, || {
        let te = |e| tiff_error(path, e);
        let mut dec = Decoder::new(reader).map_err(te)?;
        let (w, h) = dec.dimensions().map_err(te)?;
        limits.check(path, w as u64, h as u64)?;
        let colour = dec.colortype().map_err(te)?;
        let (channels, bits) = match colour {
            ColorType::Gray(b) => (1usize, b),
            ColorType::GrayA(b) => (2, b),
            ColorType::RGB(b) => (3, b),
            ColorType::RGBA(b) => (4, b),
            other => {
                return Err(Error::input(path, format!("unsupported TIFF colour type {other:?}; use grey, grey+alpha, RGB or RGBA")));
            }
        };
        if !matches!(bits, 8 | 16 | 32 | 64) {
            return Err(Error::input(path, format!("unsupported TIFF sample size of {bits} bits; use 8, 16 or 32 bits")));
        }
        let planar = dec.find_tag_unsigned::<u16>(Tag::PlanarConfiguration).map_err(te)? == Some(2);
        let white_is_zero = dec.find_tag_unsigned::<u16>(Tag::PhotometricInterpretation).map_err(te)? == Some(0);
        let (w, h) = (w as usize, h as usize);
        let count = w
            .checked_mul(h)
            .and_then(|n| n.checked_mul(channels))
            .ok_or_else(|| Error::input(path, format!("TIFF image of {w}x{h} pixels is too large")))?;
        let mut tl = Limits::default();
        tl.decoding_buffer_size = count.saturating_mul(bits as usize / 8).saturating_add(1 << 20);
        let mut dec = dec.with_limits(tl);
        let mut buf = DecodingResult::U8(Vec::new());
        dec.read_image_to_buffer(&mut buf).map_err(te)?;

        // 8 and 16-bit samples stay integers (the decoder's buffer, converted to f32 once by the
        // caller); white-is-zero grey is inverted in [0, 1] as before (`1 - q / max`).
        let (samples, encoding) = match buf {
            DecodingResult::U8(v) if !white_is_zero => (Samples::U8(v), Encoding::Display),
            DecodingResult::U16(v) if !white_is_zero => (Samples::U16(v), Encoding::Display),
            DecodingResult::U8(v) => (Samples::F32(v.into_iter().map(|q| q as f32 / 255.0).collect()), Encoding::Display),
            DecodingResult::U16(v) => (Samples::F32(v.into_iter().map(|q| q as f32 / 65535.0).collect()), Encoding::Display),
            DecodingResult::U32(v) => {
                (Samples::F32(v.into_iter().map(|q| (q as f64 / u32::MAX as f64) as f32).collect()), Encoding::Display)
            }
            DecodingResult::F16(v) => (Samples::F32(v.into_iter().map(|x| x.to_f32()).collect()), Encoding::Linear),
            DecodingResult::F32(v) => (Samples::F32(v), Encoding::Linear),
            DecodingResult::F64(v) => (Samples::F32(v.into_iter().map(|x| x as f32).collect()), Encoding::Linear),
            _ => {
                return Err(Error::input(
                    path,
                    "unsupported TIFF sample format (signed or 64-bit integers); use unsigned 8/16-bit or float",
                ));
            }
        };
        let samples = match samples {
            Samples::U8(v) => Samples::U8(arrange(path, v, count, planar, channels)?),
            Samples::U16(v) => Samples::U16(arrange(path, v, count, planar, channels)?),
            Samples::F32(v) => {
                let mut data = arrange(path, v, count, planar, channels)?;
                if white_is_zero && encoding == Encoding::Display && channels <= 2 {
                    data.iter_mut().step_by(channels).for_each(|v| *v = 1.0 - *v);
                }
                Samples::F32(data)
            }
        };
        Ok(Stored {
            width: w,
            height: h,
            channels,
            samples,
            encoding,
            bit_depth: bits,
            has_alpha: matches!(channels, 2 | 4),
            format: FileFormat::Tiff,
        })
    })
}

/// The first `count` samples of `data`, interleaved when the file stores one plane per channel.
/// Refuses fewer than `count` samples (a truncated file). Allocates only for planar files.
fn arrange<T: Copy + Default>(path: &Path, mut data: Vec<T>, count: usize, planar: bool, channels: usize) -> Result<Vec<T>> {
    if data.len() < count {
        return Err(Error::input(path, format!("corrupt or truncated TIFF: decoded {} samples, expected {count}", data.len())));
    }
    data.truncate(count);
    if planar && channels > 1 {
        let plane = count / channels;
        let mut inter = vec![T::default(); count];
        for c in 0..channels {
            for (i, &v) in data[c * plane..(c + 1) * plane].iter().enumerate() {
                inter[i * channels + c] = v;
            }
        }
        data = inter;
    }
    Ok(data)
}
