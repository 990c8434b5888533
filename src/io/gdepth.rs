//! Google's GDepth XMP (<https://developers.google.com/depthmap-metadata>): the depth map of
//! portrait-mode and "Lens Blur" JPEGs, a depth image base64 in the XMP.
//!
//! Contract of [`read_gdepth`]:
//! - GDepth properties (namespace `http://ns.google.com/photos/1.0/depthmap/`, any prefix,
//!   attributes or elements, in the standard or the extended packet, put together by
//!   [`super::xmp`]): `Format` (`RangeInverse` | `RangeLinear`), `Near`, `Far` (depths in
//!   `Units`, 0 ≤ Near < Far, both finite; Near > 0 for RangeInverse), `Mime` (`image/png` |
//!   `image/jpeg`) and `Data` (the base64 depth image) are required; `Units`, `MeasureType` and
//!   the confidence map's `ConfidenceMime` are reported. A property given twice with different
//!   values is an error. None of them: `Ok(None)`.
//! - The depth image (8 or 16-bit grey PNG, or JPEG) is decoded under the same [`ReadLimits`] as
//!   any input (its header's size is checked before its pixels are), must have the photo's
//!   aspect ratio, and becomes metric depth by [`super::embedded_depth`]'s laws.
//! - Every problem is an [`Error::Input`] naming the photo and the XMP field at fault
//!   (`GDepth:Near`, `GDepth:Data`...): a photo that claims a depth map never reads as one
//!   without depth.

use super::embedded_depth::{Container, DepthImage, DepthInfo, EmbeddedDepth, Packets, Range};
use super::limits::ReadLimits;
use super::xmp::JpegXmp;
use crate::error::{Error, Result};
use std::path::Path;

/// The GDepth namespace.
pub const NS_GDEPTH: &str = "http://ns.google.com/photos/1.0/depthmap/";
/// The GImage namespace (the original photo a Lens Blur JPEG keeps next to its blurred one).
pub const NS_GIMAGE: &str = "http://ns.google.com/photos/1.0/image/";

/// The GDepth map of the JPEG bytes `b`, if its XMP has GDepth properties.
pub(super) fn read_gdepth(path: &Path, b: &[u8], xmp: &JpegXmp, packets: &Packets, limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
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
    let range = Range::checked(path, Container::GDepth, &required(format, "Format")?, &required(near, "Near")?, &required(far, "Far")?)?;
    let mime = required(mime, "Mime")?;
    let bytes = decode_base64(path, &required(data, "Data")?)?;
    let image = DepthImage::decode(path, b, &bytes, &mime, "GDepth:Data", "GDepth:Mime", limits)?;
    let mut warnings = Vec::new();
    let original_image = packets.value(path, NS_GIMAGE, "Mime", "GImage:Mime")?;
    if original_image.is_some() {
        warnings.push(format!(
            "{} also keeps an original image (GImage:Data, as a Lens Blur photo does, whose primary image may already be blurred); the primary image is the one rendered",
            path.display()
        ));
    }
    let info = DepthInfo {
        container: Container::GDepth,
        format: range.format,
        near: range.near,
        far: range.far,
        units: units.map(|u| u.trim().to_owned()),
        measure_type: measure_type.map(|m| m.trim().to_owned()),
        mime,
        width: image.n.width,
        height: image.n.height,
        bit_depth: image.bit_depth,
        data_bytes: Some(bytes.len()),
        confidence_mime: confidence_mime.map(|m| m.trim().to_owned()),
        item: None,
        heif: None,
        xmp: Some(xmp.layout.clone()),
    };
    Ok(Some(EmbeddedDepth::new(path, &image, info, original_image, warnings)))
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

#[cfg(test)]
mod tests {
    use super::*;

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
