//! What a photo file holds, for `drbokeh inspect`: its size, colour and bit depth from the
//! header, the depth map it embeds ([`super::embedded_depth`], [`super::heif_depth`]) with its
//! parameters, and its matte (a HEIF portrait matte) and other auxiliary images.
//!
//! The depth map and matte are decoded in full (their problems are errors, as in a render: a
//! file that claims a depth map never inspects as one without); the photo's pixels are not,
//! where the format's header says enough (PNG, JPEG, TIFF, HEIF).

use super::embedded::read_embedded;
use super::embedded_depth::{DepthInfo, EmbeddedDepth};
use super::format::{FileFormat, detect_format, guarded};
use super::heif_depth::{AuxInfo, EmbeddedMatte, MatteInfo};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// The embedded formats that are read today, and those that are not yet.
pub const EMBEDDED_READ: &[&str] = &[
    "Dynamic Depth 1.0 (JPEG container items)",
    "GDepth (XMP in JPEG)",
    "HEIF/HEIC depth images (ISO/IEC 23002-3) and Apple portrait mattes (with libheif)",
];
/// Embedded depth and matte formats not read yet (named in reports).
pub const EMBEDDED_NOT_READ: &[&str] = &["Apple semantic mattes (skin, hair, teeth, glasses: listed, not used)"];

/// What `inspect` reports of a photo (`--json` prints it as it is).
#[derive(Clone, Debug, serde::Serialize)]
pub struct Inspection {
    /// The file, as given.
    pub path: String,
    /// Its format ("JPEG", "PNG"...), detected from its content.
    pub format: &'static str,
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// Channels per pixel (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA).
    pub channels: usize,
    /// "grey", "grey+alpha", "rgb" or "rgba".
    pub colour: &'static str,
    /// Bits per sample.
    pub bit_depth: u8,
    /// The embedded depth map's parameters (`kind` and `container`: "gdepth" or
    /// "dynamic-depth"), or null.
    pub depth: Option<EmbeddedDepthReport>,
    /// The embedded matte (a HEIF portrait matte), or null.
    pub matte: Option<MatteInfo>,
    /// A HEIF file's auxiliary images other than depth and alpha (the matte among them).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub auxiliary: Vec<AuxInfo>,
    /// `GImage:Mime` when the file also keeps an original image (Lens Blur photos).
    pub original_image: Option<String>,
    /// What is looked for and what is not yet ([`EMBEDDED_READ`], [`EMBEDDED_NOT_READ`]).
    pub embedded_formats_read: &'static [&'static str],
    /// See [`EMBEDDED_NOT_READ`].
    pub embedded_formats_not_read: &'static [&'static str],
    /// What the user should know (each names the file).
    pub warnings: Vec<String>,
}

/// An embedded depth map in [`Inspection`].
#[derive(Clone, Debug, serde::Serialize)]
pub struct EmbeddedDepthReport {
    /// "gdepth" or "dynamic-depth" (as `container`).
    pub kind: super::embedded_depth::Container,
    /// Its parameters.
    #[serde(flatten)]
    pub info: DepthInfo,
    /// Smallest depth in the map, in its units.
    pub depth_min: f32,
    /// Largest depth in the map, in its units.
    pub depth_max: f32,
}

/// What [`inspect`] decoded besides the report: the embedded depth map and matte (for
/// `--extract-depth`, `--extract-matte`).
pub struct Extracted {
    /// The depth map, if embedded.
    pub depth: Option<EmbeddedDepth>,
    /// The matte, if embedded.
    pub matte: Option<EmbeddedMatte>,
}

/// Inspects the photo `path`; also returns what it embeds, decoded.
pub fn inspect(path: &Path, limits: &ReadLimits) -> Result<(Inspection, Extracted)> {
    let format = detect_format(path)?;
    let header = photo_header(path, format, limits)?;
    let embedded = read_embedded(path, limits)?;
    let (matte, auxiliary) = match format {
        FileFormat::Heif => super::heif_depth::read_matte_and_list(path, limits)?,
        _ => (None, Vec::new()),
    };
    let depth = embedded.as_ref().map(|e| {
        let (lo, hi) = e.depth.data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        EmbeddedDepthReport { kind: e.info.container, info: e.info.clone(), depth_min: lo, depth_max: hi }
    });
    let colour = match header.channels {
        1 => "grey",
        2 => "grey+alpha",
        3 => "rgb",
        _ => "rgba",
    };
    let inspection = Inspection {
        path: path.display().to_string(),
        format: format.name(),
        width: header.width,
        height: header.height,
        channels: header.channels,
        colour,
        bit_depth: header.bit_depth,
        depth,
        matte: matte.as_ref().map(|m| m.info.clone()),
        auxiliary,
        original_image: embedded.as_ref().and_then(|e| e.original_image.clone()),
        embedded_formats_read: EMBEDDED_READ,
        embedded_formats_not_read: EMBEDDED_NOT_READ,
        warnings: embedded.as_ref().map(|e| e.warnings.clone()).unwrap_or_default(),
    };
    Ok((inspection, Extracted { depth: embedded, matte }))
}

/// Writes an embedded matte for other tools, the format from `out`'s extension, atomically:
/// `.png` 8 or 16-bit grey as the file stores it, `.exr` one float channel `A`, `.npy` H x W
/// float32; values in [0, 1] at the matte's own size. Returns a description of what was written.
pub fn write_extracted_matte(out: &Path, m: &EmbeddedMatte) -> Result<String> {
    let bits = if m.info.bit_depth > 8 { 16 } else { 8 };
    write_map(out, &m.matte, "matte", "A", || Ok((std::borrow::Cow::Borrowed(&m.matte), bits, format!("{bits}-bit grey"))))
}

/// Writes the one-channel `map` to `out`, the format from its extension, atomically: `.exr`
/// one float channel `channel`, `.npy` H x W float32, `.png` the image, bits and description
/// `png` gives. Returns "`what`, WxH, " and the format's description.
fn write_map<'a>(
    out: &Path,
    map: &'a Image,
    what: &str,
    channel: &str,
    png: impl FnOnce() -> Result<(std::borrow::Cow<'a, Image>, u8, String)>,
) -> Result<String> {
    let (w, h) = (map.width, map.height);
    let how = match super::write::OutputFormat::from_path(out)? {
        super::write::OutputFormat::Exr => {
            super::exr_file::write_exr(out, map, &[channel])?;
            format!("float channel {channel}")
        }
        super::write::OutputFormat::Npy => {
            super::npy::save_npy(out, map)?;
            "float32".to_owned()
        }
        super::write::OutputFormat::Png => {
            let (img, bits, how) = png()?;
            super::write::write_png(out, &img, bits, crate::color::Transfer::Linear)?;
            how
        }
    };
    Ok(format!("{what}, {w}x{h}, {how}"))
}

/// The size (width, height) of the raster `path`, from its header (PNG, JPEG, TIFF, HEIF, EXR
/// and NPY: no pixels decoded; a TIFF the header reader declines is decoded in full); checked
/// against `limits`. The size is the one the readers decode: an EXR's first part with flat
/// samples, an NPY array's first two axes (H x W or H x W x C).
pub fn raster_size(path: &Path, limits: &ReadLimits) -> Result<(usize, usize)> {
    let format = detect_format(path)?;
    let (width, height) = match format {
        FileFormat::Exr => {
            let meta = exr::meta::MetaData::read_from_file(path, false)
                .map_err(|e| Error::input(path, format!("cannot read the EXR header: {e}")))?;
            let part = &meta.headers[super::exr_file::flat_part(path, &meta.headers)?];
            (part.layer_size.0, part.layer_size.1)
        }
        FileFormat::Npy => {
            let npy = npyz::NpyFile::new(super::format::open(path)?)
                .map_err(|e| Error::input(path, format!("cannot read the NPY header: {e}")))?;
            let (h, w, _) = super::npy::hwc(npy.shape()).map_err(|e| Error::input(path, e))?;
            (w as usize, h as usize)
        }
        _ => {
            let h = photo_header(path, format, limits)?;
            (h.width, h.height)
        }
    };
    limits.check(path, width as u64, height as u64)?;
    Ok((width, height))
}

/// [`raster_size`] without limits, for estimates and checks made before a file is read (memory
/// needed, matching aspect ratios, an existing output's size): None when the path is not a
/// regular file (opening a FIFO would block) or its header cannot be read; the reader then
/// reports the problem.
pub fn probe_size(path: &Path) -> Option<(u64, u64)> {
    super::format::check_regular_file(path).ok()?;
    let (w, h) = raster_size(path, &ReadLimits::unlimited()).ok()?;
    Some((w as u64, h as u64))
}

/// A raster's size and sample layout.
struct Header {
    width: usize,
    height: usize,
    channels: usize,
    bit_depth: u8,
}

/// The header of `path` through the `image` crate's decoder (no pixels decoded), checked
/// against `limits`; formats it cannot describe (EXR, NPY, float TIFF) are decoded in full.
fn photo_header(path: &Path, format: FileFormat, limits: &ReadLimits) -> Result<Header> {
    use image::ImageDecoder;
    if format == FileFormat::Heif {
        let file = super::heif::HeifFile::open(path)?;
        let primary = file.primary()?;
        let (width, height) = primary.size();
        limits.check(path, width as u64, height as u64)?;
        let channels = if primary.has_alpha() { 4 } else { 3 };
        return Ok(Header { width, height, channels, bit_depth: primary.luma_bits().unwrap_or(8) });
    }
    if matches!(format, FileFormat::Png | FileFormat::Jpeg | FileFormat::Tiff) {
        let header = guarded(path, format, || {
            let dec = image::ImageReader::open(path)
                .map_err(|e| Error::io(path, e))?
                .with_guessed_format()
                .map_err(|e| Error::io(path, e))?
                .into_decoder()
                .map_err(|e| Error::input(path, format!("cannot read the {} header: {e}", format.name())))?;
            let (w, h) = dec.dimensions();
            let c = dec.color_type();
            let channels = c.channel_count() as usize;
            Ok(Header {
                width: w as usize,
                height: h as usize,
                channels,
                bit_depth: (c.bytes_per_pixel() as usize * 8 / channels.max(1)) as u8,
            })
        });
        if let Ok(h) = header {
            limits.check(path, h.width as u64, h.height as u64)?;
            return Ok(h);
        }
    }
    let d = super::image_file::read_decoded(path, limits)?;
    Ok(Header { width: d.image.width, height: d.image.height, channels: d.image.channels, bit_depth: d.bit_depth })
}

/// Writes an embedded depth map for other tools, the format from `out`'s extension, atomically:
/// `.exr` (one float channel `Z`) and `.npy` (H x W float32) hold the metric depth as decoded
/// (in the map's units); `.png` holds it as a 16-bit grey image of depth / Far (so values in
/// (Near/Far, 1]; multiply by Far for the units). A `--depth` of any of them gives the scene
/// the embedded map gives (disparity is normalized, so a scale does not change it; the PNG
/// within its 16-bit steps). Returns a description of what was written.
pub fn write_extracted_depth(out: &Path, e: &EmbeddedDepth) -> Result<String> {
    write_map(out, &e.depth, "metric depth", "Z", || {
        let far = e.info.far;
        if !far.is_finite() {
            return Err(Error::input(
                out,
                "the embedded depth reaches infinity (a disparity range from 0), which a PNG of depth / Far cannot hold; write .exr or .npy",
            ));
        }
        let mut scaled = e.depth.clone();
        scaled.map_inplace(|d| d / far as f32);
        Ok((std::borrow::Cow::Owned(scaled), 16, format!("16-bit grey of depth / Far (Far = {far})")))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::color::Transfer;

    /// Every format's size comes from its header, as the readers decode it; what is not a
    /// readable raster (text, a folder, a FIFO) probes as unknown instead of failing or blocking.
    #[test]
    fn sizes_come_from_every_format_header() {
        let dir = tempfile::tempdir().unwrap();
        let p = |name: &str| dir.path().join(name);
        let img = Image::filled(7, 5, 3, 0.25);
        crate::io::write_png(&p("a.png"), &img, 8, Transfer::Srgb).unwrap();
        crate::io::write_exr(&p("a.exr"), &img, &["R", "G", "B"]).unwrap();
        crate::io::save_npy(&p("a.npy"), &Image::filled(7, 5, 1, 0.5)).unwrap();
        let grey = vec![90u8; 7 * 5 * 3];
        for name in ["a.jpg", "a.tif"] {
            image::save_buffer(p(name), &grey, 7, 5, image::ExtendedColorType::Rgb8).unwrap();
        }
        for name in ["a.png", "a.exr", "a.npy", "a.jpg", "a.tif"] {
            assert_eq!(raster_size(&p(name), &ReadLimits::unlimited()).unwrap(), (7, 5), "{name}");
            assert_eq!(probe_size(&p(name)), Some((7, 5)), "{name}");
            let read = crate::io::read_decoded(&p(name), &ReadLimits::unlimited()).unwrap().image;
            assert_eq!((read.width, read.height), (7, 5), "{name}");
        }
        let small = ReadLimits { max_pixels: 34 };
        for name in ["a.png", "a.exr", "a.npy"] {
            let e = raster_size(&p(name), &small).unwrap_err().to_string();
            assert!(e.contains(name), "{e}");
        }
        std::fs::write(p("notes.txt"), "not an image").unwrap();
        assert_eq!(probe_size(&p("notes.txt")), None);
        assert_eq!(probe_size(dir.path()), None);
        #[cfg(unix)]
        {
            let fifo = p("pipe.png");
            let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
            // SAFETY: a valid NUL-terminated path.
            assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
            assert_eq!(probe_size(&fifo), None);
        }
    }
}
