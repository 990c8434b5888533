//! Depth maps that a photo carries inside itself: Google's GDepth XMP in a JPEG (the depth
//! metadata of portrait-mode and "Lens Blur" photos; <https://developers.google.com/depthmap-metadata>).
//!
//! Contract of [`read_gdepth`]:
//! - Input: a JPEG file. Its XMP is read from the APP1 segments, the standard packet and the
//!   extended one put together by offset and checked against `xmpNote:HasExtendedXMP`
//!   ([`super::xmp`]). Any other format, or a JPEG without GDepth properties, is `Ok(None)`:
//!   nothing is embedded.
//! - GDepth properties (namespace `http://ns.google.com/photos/1.0/depthmap/`, any prefix,
//!   attributes or elements, in either packet): `Format` (`RangeInverse` | `RangeLinear`),
//!   `Near`, `Far` (depths in `Units`, 0 ≤ Near < Far, both finite; Near > 0 for RangeInverse),
//!   `Mime` (`image/png` | `image/jpeg`) and `Data` (the base64 depth image) are required;
//!   `Units`, `MeasureType` and the confidence map's `ConfidenceMime` are reported. A property
//!   given twice with different values is an error.
//! - The depth image (8 or 16-bit grey PNG, or JPEG) is decoded under the same [`ReadLimits`] as
//!   any input (its header's size is checked before its pixels are), and must have the photo's
//!   aspect ratio (within [`ASPECT_TOLERANCE`]). A sample `q` of `b` bits is normalized,
//!   `n = q / (2^b - 1)`, then turned into depth by the format's definition:
//!   RangeLinear `d = n·(far − near) + near`, RangeInverse `d = far·near / (far − n·(far − near))`
//!   (so n = 0 is Near and n = 1 is Far in both).
//! - Output ([`EmbeddedDepth`]): the metric depth at the depth image's own size, one channel
//!   of f32 (computed in f64), exactly what a float depth file (`--depth`, `--depth-kind
//!   depth`) of those values holds: the caller normalizes and resizes it the same way
//!   ([`crate::job`]). And [`GDepthInfo`], the parameters, for reports.
//! - Every problem is an [`Error::Input`] naming the photo and the XMP field at fault
//!   (`GDepth:Near`, `GDepth:Data`, `xmpNote:HasExtendedXMP`...): a photo that claims a depth
//!   map never reads as one without depth.
//!
//! Not read yet: Dynamic Depth 1.0 (depth images as container items after the primary JPEG)
//! and HEIC/HEIF auxiliary depth and matte images.

use super::format::{FileFormat, detect_format, guarded, read_input};
use super::image_file::decode_image_bytes;
use super::limits::ReadLimits;
use super::xmp::{JpegXmp, Packet, XmpLayout, read_jpeg_xmp, single};
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// The GDepth namespace.
pub const NS_GDEPTH: &str = "http://ns.google.com/photos/1.0/depthmap/";
/// The GImage namespace (the original photo a Lens Blur JPEG keeps next to its blurred one).
pub const NS_GIMAGE: &str = "http://ns.google.com/photos/1.0/image/";

/// Largest relative difference of aspect ratios (width / height) between a depth map or matte
/// and its photo that is taken as the same framing (rounding of a downscaled map).
pub const ASPECT_TOLERANCE: f64 = 0.01;

/// True when sizes `a` and `b` (width, height) have the same aspect ratio within
/// [`ASPECT_TOLERANCE`].
pub fn same_aspect(a: (usize, usize), b: (usize, usize)) -> bool {
    let (ra, rb) = (a.0 as f64 / a.1 as f64, b.0 as f64 / b.1 as f64);
    (ra / rb - 1.0).abs() <= ASPECT_TOLERANCE
}

/// How a GDepth image stores depth (`GDepth:Format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum RangeFormat {
    /// `d = n·(far − near) + near`.
    RangeLinear,
    /// `d = far·near / (far − n·(far − near))`: more levels near the camera.
    RangeInverse,
}

impl RangeFormat {
    /// The XMP value.
    pub fn name(self) -> &'static str {
        match self {
            RangeFormat::RangeLinear => "RangeLinear",
            RangeFormat::RangeInverse => "RangeInverse",
        }
    }

    /// Depth of the normalized sample `n` in [0, 1].
    pub fn depth(self, n: f64, near: f64, far: f64) -> f64 {
        match self {
            RangeFormat::RangeLinear => n * (far - near) + near,
            RangeFormat::RangeInverse => far * near / (far - n * (far - near)),
        }
    }

    /// The normalized sample in [0, 1] of depth `d` in [near, far] (what a writer stores).
    pub fn normalized(self, d: f64, near: f64, far: f64) -> f64 {
        match self {
            RangeFormat::RangeLinear => (d - near) / (far - near),
            RangeFormat::RangeInverse => far * (d - near) / (d * (far - near)),
        }
    }
}

/// The parameters of an embedded GDepth map, as `inspect` and the render's report show them.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct GDepthInfo {
    /// `GDepth:Format`.
    pub format: RangeFormat,
    /// `GDepth:Near`, in `units`.
    pub near: f64,
    /// `GDepth:Far`, in `units`.
    pub far: f64,
    /// `GDepth:Units` ("m", "mm"...), when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<String>,
    /// `GDepth:MeasureType` (`OpticalAxis`, the default, or `OpticalRay`), when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measure_type: Option<String>,
    /// `GDepth:Mime` of the depth image.
    pub mime: String,
    /// The depth image's size.
    pub width: usize,
    /// The depth image's size.
    pub height: usize,
    /// Bits per sample of the depth image (8 or 16).
    pub bit_depth: u8,
    /// Bytes of the depth image (after base64).
    pub data_bytes: usize,
    /// `GDepth:ConfidenceMime`, when a confidence map is embedded (reported, not used).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub confidence_mime: Option<String>,
    /// Where the XMP came from (standard packet, extended segments).
    pub xmp: XmpLayout,
}

impl GDepthInfo {
    /// One line for people: "GDepth RangeInverse, near 0.5, far 4 m, image/png 240x160 8-bit".
    pub fn describe(&self) -> String {
        let units = self.units.as_deref().map(|u| format!(" {u}")).unwrap_or_default();
        format!(
            "GDepth {}, near {}, far {}{units}, {} {}x{} {}-bit",
            self.format.name(),
            self.near,
            self.far,
            self.mime,
            self.width,
            self.height,
            self.bit_depth
        )
    }
}

/// A depth map read from a photo (see the module doc).
#[derive(Clone, Debug)]
pub struct EmbeddedDepth {
    /// Metric depth (in `info.units`), one channel, the embedded image's size.
    pub depth: Image,
    /// Its parameters.
    pub info: GDepthInfo,
    /// `GImage:Mime` when the file also keeps an original image (a Lens Blur JPEG whose
    /// primary image may already be blurred).
    pub original_image: Option<String>,
    /// What the caller should tell the user (each names the photo).
    pub warnings: Vec<String>,
}

/// Reads the GDepth map of the photo `path` (see the module doc): `Ok(None)` when the file is
/// not a JPEG or holds no GDepth properties.
pub fn read_gdepth(path: &Path, limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    if detect_format(path)? != FileFormat::Jpeg {
        return Ok(None);
    }
    read_gdepth_bytes(path, &read_input(path)?, limits)
}

/// [`read_gdepth`] of the JPEG bytes `b` of the file `path`.
pub fn read_gdepth_bytes(path: &Path, b: &[u8], limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    let xmp = read_jpeg_xmp(path, b)?;
    let packets = Packets::parse(path, &xmp)?;
    let field = |name: &str| packets.value(path, NS_GDEPTH, name, &format!("GDepth:{name}"));
    let names = ["Format", "Near", "Far", "Mime", "Data", "Units", "MeasureType", "ConfidenceMime", "Confidence"];
    let mut values = Vec::with_capacity(names.len());
    for n in names {
        values.push(field(n)?);
    }
    if values.iter().all(Option::is_none) {
        return Ok(None);
    }
    let [format, near, far, mime, data, units, measure_type, confidence_mime, _confidence] =
        <[Option<String>; 9]>::try_from(values).expect("nine names");
    let required = |v: Option<String>, name: &str| {
        v.map(|s| s.trim().to_owned()).ok_or_else(|| {
            Error::input(path, format!("the photo has GDepth metadata but no GDepth:{name} (required by the GDepth format)"))
        })
    };
    let format = match required(format, "Format")?.as_str() {
        "RangeInverse" => RangeFormat::RangeInverse,
        "RangeLinear" => RangeFormat::RangeLinear,
        other => {
            return Err(Error::input(path, format!("GDepth:Format is '{}'; expected RangeInverse or RangeLinear", shorten(other))));
        }
    };
    let number = |v: String, name: &str| -> Result<f64> {
        let x: f64 = v.parse().map_err(|_| Error::input(path, format!("GDepth:{name} is '{}', not a number", shorten(&v))))?;
        if !x.is_finite() || x < 0.0 {
            return Err(Error::input(path, format!("GDepth:{name} is {v}; it must be a finite depth ≥ 0")));
        }
        Ok(x)
    };
    let near = number(required(near, "Near")?, "Near")?;
    let far = number(required(far, "Far")?, "Far")?;
    if near >= far {
        return Err(Error::input(path, format!("GDepth:Near ({near}) must be less than GDepth:Far ({far})")));
    }
    if format == RangeFormat::RangeInverse && near <= 0.0 {
        return Err(Error::input(path, "GDepth:Near is 0; RangeInverse needs Near > 0 (its depths are far·near / (far − n·(far − near)))"));
    }
    let mime = required(mime, "Mime")?;
    let declared = match mime.to_ascii_lowercase().as_str() {
        "image/png" => FileFormat::Png,
        "image/jpeg" | "image/jpg" => FileFormat::Jpeg,
        _ => return Err(Error::input(path, format!("GDepth:Mime is '{}'; expected image/png or image/jpeg", shorten(&mime)))),
    };
    let bytes = decode_base64(path, &required(data, "Data")?)?;
    let found = FileFormat::from_magic(&bytes);
    if found != Some(declared) {
        let what = found.map_or("neither a PNG nor a JPEG".to_owned(), |f| format!("a {}", f.name()));
        return Err(Error::input(path, format!("GDepth:Data holds {what}, but GDepth:Mime says {mime}")));
    }
    let decoded = decode_image_bytes(path, declared, &bytes, limits)
        .map_err(|e| in_field(e, &format!("GDepth:Data (the embedded {mime} depth image)")))?;
    let img = super::depth::single_grey_channel(path, decoded.image, "GDepth:Data (the embedded depth image)")?;
    let photo = photo_size(path, b)?;
    if !same_aspect((img.width, img.height), photo) {
        return Err(Error::input(
            path,
            format!(
                "GDepth:Data: the embedded depth image is {}x{} but the photo is {}x{} (a different aspect ratio)",
                img.width, img.height, photo.0, photo.1
            ),
        ));
    }
    let mut warnings = Vec::new();
    if measure_type.as_deref().map(str::trim) == Some("OpticalRay") {
        warnings.push(format!(
            "{}: GDepth:MeasureType is OpticalRay (distances along each pixel's ray); it is used as depth along the optical axis",
            path.display()
        ));
    }
    let original_image = packets.value(path, NS_GIMAGE, "Mime", "GImage:Mime")?;
    if original_image.is_some() {
        warnings.push(format!(
            "{} also keeps an original image (GImage:Data, as a Lens Blur photo does, whose primary image may already be blurred); the primary image is the one rendered",
            path.display()
        ));
    }
    let depth = to_depth(&img, format, near, far);
    let info = GDepthInfo {
        format,
        near,
        far,
        units: units.map(|u| u.trim().to_owned()),
        measure_type: measure_type.map(|m| m.trim().to_owned()),
        mime,
        width: img.width,
        height: img.height,
        bit_depth: decoded.bit_depth,
        data_bytes: bytes.len(),
        confidence_mime: confidence_mime.map(|m| m.trim().to_owned()),
        xmp: xmp.layout.clone(),
    };
    Ok(Some(EmbeddedDepth { depth, info, original_image, warnings }))
}

/// Metric depth of the normalized samples `n` (see [`RangeFormat::depth`]), in f64, stored as f32.
fn to_depth(n: &Image, format: RangeFormat, near: f64, far: f64) -> Image {
    use rayon::prelude::*;
    let data = n.data.par_iter().map(|&v| format.depth(v as f64, near, far) as f32).collect();
    Image::from_vec(n.width, n.height, 1, data).expect("same size")
}

/// The parsed standard and extended packets of a file.
struct Packets<'a> {
    docs: Vec<Packet<'a>>,
}

impl<'a> Packets<'a> {
    fn parse(path: &Path, xmp: &'a JpegXmp) -> Result<Packets<'a>> {
        let mut docs = Vec::new();
        if let Some(s) = &xmp.standard {
            docs.push(Packet::parse(path, s, "standard XMP packet")?);
        }
        if let Some(s) = &xmp.extended {
            docs.push(Packet::parse(path, s, "extended XMP packet")?);
        }
        Ok(Packets { docs })
    }

    /// The one value of `ns`:`name` over both packets (see [`single`]).
    fn value(&self, path: &Path, ns: &str, name: &str, field: &str) -> Result<Option<String>> {
        single(path, self.docs.iter().flat_map(|d| d.values(ns, name)).collect(), field)
    }
}

/// The bytes of the base64 text `s` (ASCII whitespace between characters is allowed, padding
/// optional), or an error naming `GDepth:Data`.
fn decode_base64(path: &Path, s: &str) -> Result<Vec<u8>> {
    use base64::Engine;
    let compact: Vec<u8> = s.bytes().filter(|c| !c.is_ascii_whitespace()).collect();
    if compact.is_empty() {
        return Err(Error::input(path, "GDepth:Data is empty"));
    }
    base64::engine::general_purpose::STANDARD_PAD_INDIFFERENT.decode(&compact).map_err(|e| {
        Error::input(path, format!("GDepth:Data is not valid base64 ({e}; {} characters: truncated or damaged?)", compact.len()))
    })
}

/// The photo's width and height from its JPEG header.
fn photo_size(path: &Path, b: &[u8]) -> Result<(usize, usize)> {
    guarded(path, FileFormat::Jpeg, || {
        let r = image::ImageReader::with_format(std::io::Cursor::new(b), image::ImageFormat::Jpeg);
        r.into_dimensions()
            .map(|(w, h)| (w as usize, h as usize))
            .map_err(|e| Error::input(path, format!("cannot read the JPEG's size from its header: {e}")))
    })
}

/// `e` with `field` in front of its message (the file stays the one named).
fn in_field(e: Error, field: &str) -> Error {
    match e {
        Error::Input { path, msg } => Error::Input { path, msg: format!("{field}: {msg}") },
        other => other,
    }
}

/// `s`, cut to 40 characters for a message.
fn shorten(s: &str) -> String {
    if s.chars().count() > 40 { format!("{}…", s.chars().take(40).collect::<String>()) } else { s.to_owned() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formats_follow_their_definitions() {
        let (near, far) = (0.5, 4.0);
        for f in [RangeFormat::RangeLinear, RangeFormat::RangeInverse] {
            assert_eq!(f.depth(0.0, near, far), near);
            assert_eq!(f.depth(1.0, near, far), far);
            for d in [0.5, 0.7, 1.0, 2.5, 4.0] {
                assert!((f.depth(f.normalized(d, near, far), near, far) - d).abs() < 1e-12, "{f:?} {d}");
            }
        }
        // RangeInverse is linear in 1/d: half way in n is half way in disparity.
        let d = RangeFormat::RangeInverse.depth(0.5, near, far);
        assert!((1.0 / d - 0.5 * (1.0 / near + 1.0 / far)).abs() < 1e-12);
        assert_eq!(RangeFormat::RangeLinear.depth(0.5, near, far), 2.25);
    }

    #[test]
    fn aspect_tolerance() {
        assert!(same_aspect((480, 320), (240, 160)));
        assert!(same_aspect((480, 320), (241, 160)));
        assert!(!same_aspect((480, 320), (100, 100)));
    }

    #[test]
    fn base64_errors_name_the_field() {
        let p = Path::new("p.jpg");
        assert_eq!(decode_base64(p, "aGk=\n").unwrap(), b"hi");
        assert_eq!(decode_base64(p, "aGk").unwrap(), b"hi");
        for bad in ["", "a", "@@@@", "aGk=aGk="] {
            let e = decode_base64(p, bad).unwrap_err().to_string();
            assert!(e.contains("p.jpg") && e.contains("GDepth:Data"), "{bad}: {e}");
        }
    }
}
