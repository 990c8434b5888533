//! What an embedded depth map is, whatever holds it: its sample laws ([`RangeFormat`]), its
//! parameters for reports ([`DepthInfo`]), the decoded map ([`EmbeddedDepth`]) and the checks
//! every embedding shares (Near/Far, the depth image's aspect ratio). The readers build on it:
//! [`super::gdepth`] (GDepth XMP), [`super::dynamic_depth`] (Dynamic Depth items),
//! [`super::heif_depth`] (a HEIF's depth image); [`super::embedded`] picks one by the file's
//! format.
//!
//! A sample `q` of `b` bits is normalized, `n = q / (2^b - 1)`, then turned into depth by the
//! format's definition (RangeLinear `d = n·(far − near) + near`, RangeInverse
//! `d = far·near / (far − n·(far − near))`, so n = 0 is Near and n = 1 is Far in both; the ISO
//! 23002-3 laws of HEIF beside them). [`EmbeddedDepth`] holds the metric depth at the depth
//! image's own size, one channel of f32 (computed in f64), exactly what a float depth file
//! (`--depth`, `--depth-kind depth`) of those values holds: the caller normalizes and resizes it
//! the same way ([`crate::job`]).

use super::format::{FileFormat, guarded};
use super::image_file::decode_image_bytes;
use super::limits::ReadLimits;
use super::xmp::{JpegXmp, Packet, XmpLayout, single};
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// Largest relative difference of aspect ratios (width / height) between a depth map or matte
/// and its photo that is taken as the same framing (rounding of a downscaled map).
pub const ASPECT_TOLERANCE: f64 = 0.01;

/// True when sizes `a` and `b` (width, height) have the same aspect ratio within
/// [`ASPECT_TOLERANCE`].
pub fn same_aspect(a: (usize, usize), b: (usize, usize)) -> bool {
    let (ra, rb) = (a.0 as f64 / a.1 as f64, b.0 as f64 / b.1 as f64);
    (ra / rb - 1.0).abs() <= ASPECT_TOLERANCE
}

/// How an embedded depth image stores depth: GDepth's `Format` (also Dynamic Depth's), or a
/// HEIF depth image's ISO/IEC 23002-3 representation type. `n` is the normalized sample in
/// [0, 1]; `near` < `far` are the depths the range covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum RangeFormat {
    /// `d = n·(far − near) + near`.
    RangeLinear,
    /// `d = far·near / (far − n·(far − near))`: more levels near the camera.
    RangeInverse,
    /// ISO 23002-3 type 0: `1/d` uniform, the largest sample nearest:
    /// `1/d = 1/far + n·(1/near − 1/far)`.
    UniformInverseZ,
    /// ISO 23002-3 type 1: disparity `D = d_min + n·(d_max − d_min)` uniform, depth `1/D`; kept
    /// as near = 1/d_max, far = 1/d_min (infinite when d_min = 0), the same law as type 0.
    UniformDisparity,
    /// ISO 23002-3 type 2: `d = near + n·(far − near)` (as RangeLinear).
    UniformZ,
}

impl RangeFormat {
    /// The XMP value.
    pub fn name(self) -> &'static str {
        match self {
            RangeFormat::RangeLinear => "RangeLinear",
            RangeFormat::RangeInverse => "RangeInverse",
            RangeFormat::UniformInverseZ => "uniform inverse Z",
            RangeFormat::UniformDisparity => "uniform disparity",
            RangeFormat::UniformZ => "uniform Z",
        }
    }

    /// The format named `v` (`field` in errors); `any_case`: as Dynamic Depth's reference
    /// reader, which compares without case.
    pub fn parse(path: &Path, v: &str, field: &str, any_case: bool) -> Result<RangeFormat> {
        let v = v.trim();
        let is = |name: &str| if any_case { v.eq_ignore_ascii_case(name) } else { v == name };
        if is("RangeInverse") {
            Ok(RangeFormat::RangeInverse)
        } else if is("RangeLinear") {
            Ok(RangeFormat::RangeLinear)
        } else {
            Err(Error::input(path, format!("{field} is '{}'; expected RangeInverse or RangeLinear", shorten(v))))
        }
    }

    /// Depth of the normalized sample `n` in [0, 1] (infinite where an unbounded far range
    /// puts it).
    pub fn depth(self, n: f64, near: f64, far: f64) -> f64 {
        match self {
            RangeFormat::RangeLinear | RangeFormat::UniformZ => n * (far - near) + near,
            RangeFormat::RangeInverse => far * near / (far - n * (far - near)),
            // In disparity, so that far = ∞ (d_min = 0) stays exact: 1/d = (1 − n)/far + n/near.
            RangeFormat::UniformInverseZ | RangeFormat::UniformDisparity => 1.0 / ((1.0 - n) / far + n / near),
        }
    }

    /// The normalized sample in [0, 1] of depth `d` in [near, far] (what a writer stores).
    pub fn normalized(self, d: f64, near: f64, far: f64) -> f64 {
        match self {
            RangeFormat::RangeLinear | RangeFormat::UniformZ => (d - near) / (far - near),
            RangeFormat::RangeInverse => far * (d - near) / (d * (far - near)),
            RangeFormat::UniformInverseZ | RangeFormat::UniformDisparity => (1.0 / d - 1.0 / far) / (1.0 / near - 1.0 / far),
        }
    }
}

/// Where in a photo its depth map was found.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Container {
    /// Google's GDepth XMP: the depth image base64 in the XMP.
    #[serde(rename = "gdepth")]
    GDepth,
    /// Google's Dynamic Depth 1.0: the depth image a container item after the primary JPEG.
    #[serde(rename = "dynamic-depth")]
    DynamicDepth,
    /// A HEIF (HEIC) photo's depth auxiliary image (iPhone portrait mode...).
    #[serde(rename = "heif")]
    Heif,
}

impl Container {
    /// The name people know.
    pub fn name(self) -> &'static str {
        match self {
            Container::GDepth => "GDepth",
            Container::DynamicDepth => "Dynamic Depth",
            Container::Heif => "HEIF depth image",
        }
    }

    /// The XMP prefix of its depth-map fields, as errors and `inspect` name them.
    pub fn prefix(self) -> &'static str {
        match self {
            Container::GDepth => "GDepth",
            Container::DynamicDepth => "DepthMap",
            Container::Heif => "HEIF depth",
        }
    }
}

/// Where a Dynamic Depth depth image was found, for reports.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ItemInfo {
    /// `Item:DataURI` (= `DepthMap:DepthURI`).
    pub uri: String,
    /// Its index in `Container:Directory` (0 is the primary image).
    pub index: usize,
    /// Its first byte in the file.
    pub offset: usize,
    /// `Item:Length`.
    pub length: usize,
    /// `Item:Padding`.
    pub padding: usize,
    /// The camera whose `DepthMap` it is (index in `Device:Cameras`).
    pub camera: usize,
    /// `DepthMap:ConfidenceURI`, when given (reported, not used).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub confidence_uri: Option<String>,
}

/// A HEIF depth item and its representation, as `inspect` and the render's report show them.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct HeifDepthItem {
    /// The depth image's item id.
    pub item_id: u32,
    /// The representation type as the file states it (`uniform_disparity`...), or null when
    /// the file states none.
    pub representation: Option<&'static str>,
    /// `z_near`, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_near: Option<f64>,
    /// `z_far`, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub z_far: Option<f64>,
    /// `d_min`, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub d_min: Option<f64>,
    /// `d_max`, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub d_max: Option<f64>,
}

/// The parameters of an embedded depth map, as `inspect` and the render's report show them.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct DepthInfo {
    /// The embedding.
    pub container: Container,
    /// `Format`.
    pub format: RangeFormat,
    /// `Near`, in `units`.
    pub near: f64,
    /// `Far`, in `units`.
    pub far: f64,
    /// `Units` ("m", "Meters", "Diopters"...), when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub units: Option<String>,
    /// `MeasureType` (`OpticalAxis`, the default, or `OpticalRay`), when given.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub measure_type: Option<String>,
    /// The depth image's MIME type (`GDepth:Mime`; a Dynamic Depth item's `Item:Mime`).
    pub mime: String,
    /// The depth image's size.
    pub width: usize,
    /// The depth image's size.
    pub height: usize,
    /// Bits per sample of the depth image (8 or 16).
    pub bit_depth: u8,
    /// Bytes of the depth image (after base64 for GDepth); not known for HEIF.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub data_bytes: Option<usize>,
    /// `GDepth:ConfidenceMime`, when a confidence map is embedded (reported, not used).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub confidence_mime: Option<String>,
    /// Dynamic Depth: the container item that holds the depth image, and its camera.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub item: Option<ItemInfo>,
    /// HEIF: the depth item and its ISO 23002-3 representation as the file states it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub heif: Option<HeifDepthItem>,
    /// Where the XMP came from (standard packet, extended segments); none for HEIF.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub xmp: Option<XmpLayout>,
}

impl DepthInfo {
    /// One line for people: "GDepth RangeInverse, near 0.5, far 4 m, image/png 240x160 8-bit".
    pub fn describe(&self) -> String {
        let units = self.units.as_deref().map(|u| format!(" {u}")).unwrap_or_default();
        format!(
            "{} {}, near {}, far {}{units}, {} {}x{} {}-bit",
            self.container.name(),
            self.format.name(),
            self.near,
            self.far,
            self.mime,
            self.width,
            self.height,
            self.bit_depth
        )
    }

    /// The field that holds the depth image, for messages: `GDepth:Data`, or the Dynamic
    /// Depth item with its URI.
    pub fn data_field(&self) -> String {
        match (&self.item, &self.heif) {
            (Some(i), _) => format!("Container:Item {} ('{}')", i.index, i.uri),
            (_, Some(h)) => format!("the HEIF depth image (item {})", h.item_id),
            (None, None) => "GDepth:Data".to_owned(),
        }
    }
}

/// A depth map read from a photo (see the module doc).
#[derive(Clone, Debug)]
pub struct EmbeddedDepth {
    /// Metric depth (in `info.units`), one channel, the embedded image's size.
    pub depth: Image,
    /// Its parameters.
    pub info: DepthInfo,
    /// `GImage:Mime` when the file also keeps an original image (a Lens Blur JPEG whose
    /// primary image may already be blurred).
    pub original_image: Option<String>,
    /// What the caller should tell the user (each names the photo).
    pub warnings: Vec<String>,
}

/// `Format`, `Near` and `Far` of an embedded depth map, checked.
pub(super) struct Range {
    pub format: RangeFormat,
    pub near: f64,
    pub far: f64,
}

impl Range {
    /// The fields as the XMP gives them (trimmed), checked: a known format, finite depths
    /// 0 ≤ Near < Far, Near > 0 for RangeInverse. Errors name `container`'s fields.
    pub fn checked(path: &Path, container: Container, format: &str, near: &str, far: &str) -> Result<Range> {
        let prefix = container.prefix();
        let format = RangeFormat::parse(path, format, &format!("{prefix}:Format"), container == Container::DynamicDepth)?;
        let number = |v: &str, name: &str| -> Result<f64> {
            let x: f64 = v.parse().map_err(|_| Error::input(path, format!("{prefix}:{name} is '{}', not a number", shorten(v))))?;
            if !x.is_finite() || x < 0.0 {
                return Err(Error::input(path, format!("{prefix}:{name} is {v}; it must be a finite depth ≥ 0")));
            }
            Ok(x)
        };
        let (near, far) = (number(near, "Near")?, number(far, "Far")?);
        if near >= far {
            return Err(Error::input(path, format!("{prefix}:Near ({near}) must be less than {prefix}:Far ({far})")));
        }
        if format == RangeFormat::RangeInverse && near <= 0.0 {
            return Err(Error::input(
                path,
                format!("{prefix}:Near is 0; RangeInverse needs Near > 0 (its depths are far·near / (far − n·(far − near)))"),
            ));
        }
        Ok(Range { format, near, far })
    }
}

/// An embedded depth image, decoded: samples normalized to [0, 1].
pub(crate) struct DepthImage {
    /// One grey channel, `q / (2^b − 1)`.
    pub n: Image,
    /// Bits per sample in the file.
    pub bit_depth: u8,
}

impl DepthImage {
    /// Decodes `bytes`, declared as the MIME type `mime` (`mime_field` names the declaration,
    /// `field` the data, in errors), under `limits`, and checks it against the photo's aspect
    /// ratio (the photo's size read from the JPEG bytes `photo`).
    pub fn decode(
        path: &Path,
        photo: &[u8],
        bytes: &[u8],
        mime: &str,
        field: &str,
        mime_field: &str,
        limits: &ReadLimits,
    ) -> Result<DepthImage> {
        let declared = match mime.to_ascii_lowercase().as_str() {
            "image/png" => FileFormat::Png,
            "image/jpeg" | "image/jpg" => FileFormat::Jpeg,
            _ => return Err(Error::input(path, format!("{mime_field} is '{}'; expected image/png or image/jpeg", shorten(mime)))),
        };
        let found = FileFormat::from_magic(bytes);
        if found != Some(declared) {
            let what = found.map_or("neither a PNG nor a JPEG".to_owned(), |f| format!("a {}", f.name()));
            return Err(Error::input(path, format!("{field} holds {what}, but {mime_field} says {mime}")));
        }
        let decoded = decode_image_bytes(path, declared, bytes, limits)
            .map_err(|e| e.within(&format!("{field} (the embedded {mime} depth image)")))?;
        let n = super::depth::single_grey_channel(path, decoded.image, &format!("{field} (the embedded depth image)"))?;
        let photo = photo_size(path, photo)?;
        if !same_aspect((n.width, n.height), photo) {
            return Err(Error::input(
                path,
                format!(
                    "{field}: the embedded depth image is {}x{} but the photo is {}x{} (a different aspect ratio)",
                    n.width, n.height, photo.0, photo.1
                ),
            ));
        }
        Ok(DepthImage { n, bit_depth: decoded.bit_depth })
    }
}

impl EmbeddedDepth {
    /// The depth map of `image` under `info`'s format and range (Dynamic Depth in diopters:
    /// turned into metres), with the warnings every embedding shares added.
    pub(super) fn new(
        path: &Path,
        image: &DepthImage,
        info: DepthInfo,
        original_image: Option<String>,
        mut warnings: Vec<String>,
    ) -> EmbeddedDepth {
        if info.measure_type.as_deref().is_some_and(|m| m.eq_ignore_ascii_case("OpticalRay") || m.eq_ignore_ascii_case("OpticRay")) {
            warnings.push(format!(
                "{}: {}:MeasureType is {} (distances along each pixel's ray); it is used as depth along the optical axis",
                path.display(),
                info.container.prefix(),
                info.measure_type.as_deref().unwrap_or_default()
            ));
        }
        let mut depth = to_depth(&image.n, info.format, info.near, info.far);
        if info.units.as_deref().is_some_and(|u| u.eq_ignore_ascii_case("Diopters")) {
            // Diopters are inverse metres; 0 D is infinitely far (the largest finite depth).
            depth.map_inplace(|d| if d > 0.0 { 1.0 / d } else { f32::MAX });
        }
        EmbeddedDepth { depth, info, original_image, warnings }
    }
}

/// Metric depth of the normalized samples `n` (see [`RangeFormat::depth`]), in f64, stored as
/// f32; an infinite depth (a disparity of 0) as the largest f32, a valid depth the
/// normalization turns into disparity 0, not a hole to fill.
fn to_depth(n: &Image, format: RangeFormat, near: f64, far: f64) -> Image {
    use rayon::prelude::*;
    let data = n.data.par_iter().map(|&v| format.depth(v as f64, near, far).min(f32::MAX as f64) as f32).collect();
    Image::from_vec(n.width, n.height, 1, data).expect("same size")
}

/// The parsed standard and extended packets of a file.
pub(super) struct Packets<'a> {
    pub docs: Vec<Packet<'a>>,
}

impl<'a> Packets<'a> {
    /// The standard and extended packets of `xmp`, parsed.
    pub fn parse(path: &Path, xmp: &'a JpegXmp) -> Result<Packets<'a>> {
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
    pub fn value(&self, path: &Path, ns: &str, name: &str, field: &str) -> Result<Option<String>> {
        single(path, self.docs.iter().flat_map(|d| d.values(ns, name)).collect(), field)
    }
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

/// `s`, cut to 40 characters for a message.
pub(super) fn shorten(s: &str) -> String {
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
        // The ISO 23002-3 laws: type 2 is RangeLinear; types 0 and 1 are RangeInverse read from
        // the far end (the largest sample nearest), also with an unbounded far range.
        for n in [0.0, 0.25, 0.5, 1.0] {
            assert_eq!(RangeFormat::UniformZ.depth(n, near, far), RangeFormat::RangeLinear.depth(n, near, far));
            for f in [RangeFormat::UniformInverseZ, RangeFormat::UniformDisparity] {
                let d = f.depth(n, near, far);
                assert!((d - RangeFormat::RangeInverse.depth(1.0 - n, near, far)).abs() < 1e-12, "{f:?} {n}");
                assert!((f.normalized(d, near, far) - n).abs() < 1e-12);
                // d_min = 0: disparity n·d_max.
                let d = f.depth(n, near, f64::INFINITY);
                assert!((1.0 / d - n / near).abs() < 1e-12, "{f:?} {n} {d}");
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
}
