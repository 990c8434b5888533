//! NPY arrays (`numpy.save` format) as [`Image`]s.
//!
//! Shape `H x W` reads as one channel, `H x W x C` as C interleaved channels. Accepted dtypes:
//! float32, float64 (narrowed to f32), uint8, uint16 (values kept, not rescaled), either byte
//! order, C order. The declared size is checked against the file length before anything is
//! allocated, so a lying header cannot exhaust memory.

use crate::error::{Error, Result};
use crate::image::Image;
use npyz::{TypeChar, WriterBuilder};
use std::io::Write;
use std::path::Path;

/// Reads an NPY file into an image (see the module doc for what is accepted).
pub fn read_npy(path: &Path, max_pixels: u64) -> Result<Image> {
    let bytes = super::format::read_input(path)?;
    decode_npy(&bytes, max_pixels).map_err(|msg| Error::input(path, msg))
}

/// Decodes NPY bytes; the error is a message without the file name.
pub fn decode_npy(bytes: &[u8], max_pixels: u64) -> std::result::Result<Image, String> {
    let (w, h, c, samples) = decode_npy_samples(bytes, max_pixels)?;
    let data: Vec<f32> = match samples {
        NpySamples::F32(v) => v,
        NpySamples::U8(v) => v.into_iter().map(f32::from).collect(),
        NpySamples::U16(v) => v.into_iter().map(f32::from).collect(),
    };
    Image::from_vec(w, h, c, data).ok_or_else(|| "NPY data length does not match its shape".into())
}

/// An NPY array's values in its own kind: integer arrays are kept as integers so that a reader
/// can take them for what an 8/16-bit image file holds (see `read_photo`).
pub(crate) enum NpySamples {
    /// uint8.
    U8(Vec<u8>),
    /// uint16.
    U16(Vec<u16>),
    /// float32, or float64 narrowed.
    F32(Vec<f32>),
}

/// (height, width, channels) of an NPY array's shape: H x W or H x W x C.
pub(crate) fn hwc(shape: &[u64]) -> std::result::Result<(u64, u64, u64), String> {
    match *shape {
        [h, w] => Ok((h, w, 1)),
        [h, w, c] => Ok((h, w, c)),
        _ => Err(format!("NPY array has shape {shape:?}; expected H x W or H x W x C")),
    }
}

/// Decodes NPY bytes to (width, height, channels, samples); checks as [`decode_npy`].
pub(crate) fn decode_npy_samples(bytes: &[u8], max_pixels: u64) -> std::result::Result<(usize, usize, usize, NpySamples), String> {
    let data_start = check_header_length(bytes)?;
    let npy = npyz::NpyFile::new(bytes).map_err(|e| format!("not a valid NPY file ({e})"))?;
    let shape = npy.shape().to_vec();
    let (h, w, c) = hwc(&shape)?;
    if h == 0 || w == 0 || c == 0 {
        return Err(format!("NPY array is empty (shape {shape:?})"));
    }
    if h.saturating_mul(w) > max_pixels {
        return Err(format!("NPY array of {w}x{h} exceeds the pixel limit of {max_pixels}"));
    }
    if c > 64 {
        return Err(format!("NPY array has {c} channels; at most 64 are supported"));
    }
    if npy.order() != npyz::Order::C {
        return Err("NPY array is in Fortran order; save it in C order (numpy.ascontiguousarray)".into());
    }
    let npyz::DType::Plain(ts) = npy.dtype() else {
        return Err("NPY array has a structured dtype; expected a plain numeric array".into());
    };
    // Checked: with an unlimited `max_pixels` a hostile header could overflow `h * w * c`.
    let count = h
        .checked_mul(w)
        .and_then(|n| n.checked_mul(c))
        .filter(|&n| usize::try_from(n).is_ok())
        .ok_or_else(|| format!("NPY array shape {shape:?} is too large"))?;
    let item = ts.num_bytes().unwrap_or(0) as u64;
    // The data must be in the file: refuse before allocating `count` values.
    let have = (bytes.len() - data_start) as u64;
    if have < count.saturating_mul(item) {
        return Err(format!(
            "NPY file is truncated: shape {shape:?} needs {} bytes of data, the file has {have}",
            count.saturating_mul(item)
        ));
    }
    let samples = match (ts.type_char(), item) {
        (TypeChar::Float, 4) => NpySamples::F32(npy.into_vec::<f32>().map_err(|e| e.to_string())?),
        (TypeChar::Float, 8) => NpySamples::F32(npy.into_vec::<f64>().map_err(|e| e.to_string())?.into_iter().map(|v| v as f32).collect()),
        (TypeChar::Uint, 1) => NpySamples::U8(npy.into_vec::<u8>().map_err(|e| e.to_string())?),
        (TypeChar::Uint, 2) => NpySamples::U16(npy.into_vec::<u16>().map_err(|e| e.to_string())?),
        _ => return Err(format!("NPY dtype '{ts}' is not supported; use float32, float64, uint8 or uint16")),
    };
    let len = match &samples {
        NpySamples::F32(v) => v.len(),
        NpySamples::U8(v) => v.len(),
        NpySamples::U16(v) => v.len(),
    };
    if len as u64 != count {
        return Err("NPY data length does not match its shape".into());
    }
    Ok((w as usize, h as usize, c as usize, samples))
}

/// Refuses a header whose declared length runs past the end of the file. npyz allocates the
/// declared length (up to 4 GiB for format 2/3) before reading it; found by fuzzing. Returns
/// the offset of the array data (the end of the header).
fn check_header_length(bytes: &[u8]) -> std::result::Result<usize, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a valid NPY file (no NPY magic number)".into());
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(format!("not a valid NPY file (unsupported format version {v})")),
    };
    if start + len > bytes.len() {
        return Err(format!("NPY file is truncated: its header declares {len} bytes, the file has {}", bytes.len() - start));
    }
    check_header_text(&bytes[start..start + len])?;
    Ok(start + len)
}

/// Longest header accepted (numpy's own `max_header_size` default).
const MAX_HEADER_BYTES: usize = 10_000;
/// Deepest bracket nesting accepted: a plain array needs 2 (`{'shape': (..)}`), a structured
/// dtype 3-4.
const MAX_HEADER_DEPTH: usize = 4;

/// Refuses headers that are too long or nested too deeply before npyz parses them: its
/// Python-literal parser backtracks exponentially on deep nesting (a 273-byte file with 140
/// `[` ran for over ten minutes; found by fuzzing).
fn check_header_text(header: &[u8]) -> std::result::Result<(), String> {
    if header.len() > MAX_HEADER_BYTES {
        return Err(format!("not a valid NPY file (header of {} bytes; at most {MAX_HEADER_BYTES} are allowed)", header.len()));
    }
    let (mut depth, mut quote) = (0usize, None);
    for &b in header {
        match (quote, b) {
            (Some(q), _) if b == q => quote = None,
            (Some(_), _) => {}
            (None, b'\'' | b'"') => quote = Some(b),
            (None, b'{' | b'[' | b'(') => {
                depth += 1;
                if depth > MAX_HEADER_DEPTH {
                    return Err(format!("not a valid NPY file (header nests brackets deeper than {MAX_HEADER_DEPTH})"));
                }
            }
            (None, b'}' | b']' | b')') => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    Ok(())
}

/// Writes `img` as little-endian float32, shape `H x W` (one channel) or `H x W x C`.
pub fn write_npy<W: Write>(w: &mut W, img: &Image) -> std::io::Result<()> {
    let shape: Vec<u64> = if img.channels == 1 {
        vec![img.height as u64, img.width as u64]
    } else {
        vec![img.height as u64, img.width as u64, img.channels as u64]
    };
    let mut writer = npyz::WriteOptions::new().default_dtype().shape(&shape).writer(w).begin_nd()?;
    writer.extend(img.data.iter().copied())?;
    writer.finish()
}

/// Writes `img` to `path` as NPY, atomically.
pub fn save_npy(path: &Path, img: &Image) -> Result<()> {
    super::atomic::write_atomic(path, |w| write_npy(w, img).map_err(|e| Error::io(path, e)))
}

/// Reads an NPY file ([`read_npy`]) behind the same panic guard as the other decoders
/// ([`super::format::guarded`]).
pub(crate) fn read_npy_guarded(path: &Path, limits: &super::limits::ReadLimits) -> Result<Image> {
    super::format::guarded(path, super::format::FileFormat::Npy, || read_npy(path, limits.max_pixels))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip() {
        let img = Image::from_vec(3, 2, 2, (0..12).map(|v| v as f32 * 0.5).collect()).unwrap();
        let mut buf = Vec::new();
        write_npy(&mut buf, &img).unwrap();
        assert_eq!(decode_npy(&buf, u64::MAX).unwrap(), img);
    }

    #[test]
    fn lying_header_length_is_refused_before_allocation() {
        // Fuzzer find: format 2.0 with a 2.5 GB header length in a 16-byte file.
        let bytes = [0x93, b'N', b'U', b'M', b'P', b'Y', 2, 0, 0x46, 0x93, 0x93, 0x93, 0x93, 0x93, 0x66, 0x64];
        assert!(decode_npy(&bytes, u64::MAX).unwrap_err().contains("truncated"));
        assert!(decode_npy(b"\x93NUMPY", u64::MAX).is_err());
    }

    #[test]
    fn deeply_nested_header_is_refused_quickly() {
        // Fuzzer find (timeout): 140 nested '[' made the header parser backtrack for minutes.
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        let header = format!("{{'descr': {}'<f4', 'fortran_order': False, 'shape': (2, 2), }}", "[".repeat(140));
        bytes.extend((header.len() as u16).to_le_bytes());
        bytes.extend(header.as_bytes());
        bytes.extend([0u8; 16]);
        let t = std::time::Instant::now();
        assert!(decode_npy(&bytes, u64::MAX).unwrap_err().contains("deeper"));
        assert!(t.elapsed().as_secs() < 1);
        // Ordinary headers (depth 2) still parse.
        let img = Image::new(2, 2, 3);
        let mut buf = Vec::new();
        write_npy(&mut buf, &img).unwrap();
        assert_eq!(decode_npy(&buf, u64::MAX).unwrap(), img);
    }

    #[test]
    fn truncated_is_refused() {
        let img = Image::new(64, 64, 1);
        let mut buf = Vec::new();
        write_npy(&mut buf, &img).unwrap();
        let full = buf.clone();
        buf.truncate(buf.len() / 2);
        assert!(decode_npy(&buf, u64::MAX).unwrap_err().contains("truncated"));
        // Missing fewer bytes than the header's length: the data size alone is compared.
        let e = decode_npy(&full[..full.len() - 4], u64::MAX).unwrap_err();
        assert!(e.contains("truncated") && e.contains("needs 16384 bytes of data, the file has 16380"), "{e}");
    }
}
