//! Output writers: PNG (8/16-bit, transfer-encoded), EXR and NPY (float32). Every writer goes
//! through [`super::atomic::write_atomic`]: the destination is replaced only once the whole file
//! is written; an existing file is overwritten (the caller refuses output == input).

use super::exr_file::write_exr;
use crate::color::Transfer;
use crate::error::{Error, Result};
use crate::image::Image;
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};
use std::io::Write;
use std::path::Path;

/// Output file formats, chosen from the extension (serialized lowercase, as the extension:
/// "png", "exr", "npy").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputFormat {
    /// 8- or 16-bit PNG, transfer-encoded (sRGB or the naive gamma), clipped to [0, 1].
    Png,
    /// OpenEXR, 32-bit float, linear, unclipped.
    Exr,
    /// NumPy `.npy`, float32, linear, unclipped (H x W or H x W x C).
    Npy,
}

impl OutputFormat {
    /// The file extension, without the dot (lowercase; also the serialized name).
    pub fn extension(self) -> &'static str {
        match self {
            OutputFormat::Png => "png",
            OutputFormat::Exr => "exr",
            OutputFormat::Npy => "npy",
        }
    }

    /// `.png`, `.exr` or `.npy` (case-insensitive); anything else is an error naming the
    /// extension and the supported ones.
    pub fn from_path(path: &Path) -> Result<OutputFormat> {
        let ext = path.extension().map(|e| e.to_string_lossy().into_owned());
        match ext.as_deref().map(str::to_ascii_lowercase).as_deref() {
            Some("png") => Ok(OutputFormat::Png),
            Some("exr") => Ok(OutputFormat::Exr),
            Some("npy") => Ok(OutputFormat::Npy),
            Some(other) => Err(Error::input(path, format!("unsupported output extension '.{other}'; use .png, .exr or .npy"))),
            None => Err(Error::input(path, "output file has no extension; use .png, .exr or .npy")),
        }
    }
}

/// Bits per sample of a PNG output. Serialized as the number (8 or 16), so `output.bit_depth`
/// reads and writes as before; any other number is refused when the config is parsed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "u8", into = "u8")]
pub enum BitDepth {
    /// 8 bits per sample: 256 levels, enough for display.
    #[default]
    Eight,
    /// 16 bits per sample: 65536 levels, for further editing without banding.
    Sixteen,
}

impl BitDepth {
    /// The number of bits, 8 or 16, as [`write_png`] takes it.
    pub fn bits(self) -> u8 {
        match self {
            BitDepth::Eight => 8,
            BitDepth::Sixteen => 16,
        }
    }
}

impl From<BitDepth> for u8 {
    fn from(b: BitDepth) -> u8 {
        b.bits()
    }
}

impl TryFrom<u8> for BitDepth {
    type Error = String;
    fn try_from(bits: u8) -> std::result::Result<BitDepth, String> {
        match bits {
            8 => Ok(BitDepth::Eight),
            16 => Ok(BitDepth::Sixteen),
            other => Err(format!("output.bit_depth must be 8 or 16, got {other}")),
        }
    }
}

/// Default EXR channel names for an image with `channels` channels: Y, YA, RGB, RGBA, RGBAD.
pub fn default_channel_names(channels: usize) -> Option<&'static [&'static str]> {
    match channels {
        1 => Some(&["Y"]),
        2 => Some(&["Y", "A"]),
        3 => Some(&["R", "G", "B"]),
        4 => Some(&["R", "G", "B", "A"]),
        5 => Some(&["R", "G", "B", "A", "D"]),
        _ => None,
    }
}

/// Quantizes `img` to 8 or 16-bit samples: colour channels go through `transfer.encode`
/// (alpha, the last channel of 2/4-channel images, is written linearly), then are clipped to
/// [0, 1] (NaN becomes 0) and rounded to nearest. 16-bit samples are native-endian bytes as
/// `ImageEncoder::write_image` expects.
fn quantize(img: &Image, bit_depth: u8, transfer: Transfer) -> Vec<u8> {
    let c = img.channels;
    let alpha = if c == 2 || c == 4 { Some(c - 1) } else { None };
    let max = if bit_depth == 16 { 65535.0 } else { 255.0 };
    let q = |i: usize, v: f32| -> f32 {
        let e = if Some(i % c) == alpha { v } else { transfer.encode(v) };
        let e = if e.is_nan() { 0.0 } else { e.clamp(0.0, 1.0) };
        (e * max).round()
    };
    if bit_depth == 16 {
        img.data.iter().enumerate().flat_map(|(i, &v)| (q(i, v) as u16).to_ne_bytes()).collect()
    } else {
        img.data.iter().enumerate().map(|(i, &v)| q(i, v) as u8).collect()
    }
}

/// Encodes `img` (1, 2, 3 or 4 channels) as PNG into `w`; see [`write_png`].
pub fn encode_png<W: Write>(w: W, img: &Image, bit_depth: u8, transfer: Transfer) -> std::result::Result<(), String> {
    let ct = match (img.channels, bit_depth) {
        (1, 8) => ExtendedColorType::L8,
        (2, 8) => ExtendedColorType::La8,
        (3, 8) => ExtendedColorType::Rgb8,
        (4, 8) => ExtendedColorType::Rgba8,
        (1, 16) => ExtendedColorType::L16,
        (2, 16) => ExtendedColorType::La16,
        (3, 16) => ExtendedColorType::Rgb16,
        (4, 16) => ExtendedColorType::Rgba16,
        (_, 8 | 16) => return Err(format!("cannot write a {}-channel image as PNG (1 to 4 channels)", img.channels)),
        _ => return Err(format!("PNG bit depth must be 8 or 16, not {bit_depth}")),
    };
    if img.is_empty() || img.width > u32::MAX as usize || img.height > u32::MAX as usize {
        return Err(format!("cannot write a {}x{} image as PNG", img.width, img.height));
    }
    let bytes = quantize(img, bit_depth, transfer);
    PngEncoder::new(w).write_image(&bytes, img.width as u32, img.height as u32, ct).map_err(|e| format!("PNG encoder failed: {e}"))
}

/// Writes `img` (1 = grey, 2 = grey+alpha, 3 = RGB, 4 = RGBA channels) as an 8 or 16-bit PNG,
/// atomically. Colour values are encoded with `transfer` (`Transfer::Linear` writes the values
/// as they are; alpha is never encoded), clipped to [0, 1] and rounded to nearest.
pub fn write_png(path: &Path, img: &Image, bit_depth: u8, transfer: Transfer) -> Result<()> {
    if bit_depth != 8 && bit_depth != 16 {
        return Err(Error::usage(format!("PNG bit depth must be 8 or 16, not {bit_depth}")));
    }
    super::atomic::write_atomic(path, |w| {
        encode_png(w, img, bit_depth, transfer).map_err(|msg| {
            if msg.starts_with("PNG encoder failed") { Error::io(path, std::io::Error::other(msg)) } else { Error::input(path, msg) }
        })
    })
}

/// Writes a result image, the format picked from the extension ([`OutputFormat::from_path`]):
/// PNG is quantized to `bit_depth` after encoding with `transfer`; EXR (channels named by
/// [`default_channel_names`]) and NPY store the float32 values unchanged (`bit_depth` and
/// `transfer` are ignored).
pub fn write_output(path: &Path, img: &Image, bit_depth: u8, transfer: Transfer) -> Result<()> {
    match OutputFormat::from_path(path)? {
        OutputFormat::Png => write_png(path, img, bit_depth, transfer),
        OutputFormat::Exr => {
            let names = default_channel_names(img.channels)
                .ok_or_else(|| Error::input(path, format!("cannot write a {}-channel image as EXR (1 to 5 channels)", img.channels)))?;
            write_exr(path, img, names)
        }
        OutputFormat::Npy => {
            if img.is_empty() {
                return Err(Error::input(path, format!("cannot write an empty {}x{} image", img.width, img.height)));
            }
            super::npy::save_npy(path, img)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_clips_and_keeps_alpha_linear() {
        let img = Image::from_vec(2, 1, 2, vec![0.5, 0.5, f32::NAN, 2.0]).unwrap();
        assert_eq!(quantize(&img, 8, Transfer::Linear), vec![128, 128, 0, 255]);
        let srgb = quantize(&img, 8, Transfer::Srgb);
        assert_eq!(srgb[1], 128, "alpha is not encoded");
        assert_eq!(srgb[0], 188, "linear 0.5 is sRGB 187.5 -> 188");
        let q16 = quantize(&Image::from_vec(1, 1, 1, vec![1.0]).unwrap(), 16, Transfer::Linear);
        assert_eq!(u16::from_ne_bytes([q16[0], q16[1]]), 65535);
    }

    #[test]
    fn output_format_from_extension() {
        assert_eq!(OutputFormat::from_path(Path::new("a.PNG")).unwrap(), OutputFormat::Png);
        assert_eq!(OutputFormat::from_path(Path::new("a.Exr")).unwrap(), OutputFormat::Exr);
        assert_eq!(OutputFormat::from_path(Path::new("a.npy")).unwrap(), OutputFormat::Npy);
        let e = OutputFormat::from_path(Path::new("a.bmp")).unwrap_err().to_string();
        assert!(e.contains(".bmp") && e.contains(".png"), "{e}");
        assert!(OutputFormat::from_path(Path::new("a")).is_err());
    }
}
