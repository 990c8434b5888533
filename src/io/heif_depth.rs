//! The depth image and the portrait matte a HEIF photo carries (iPhone portrait mode and other
//! cameras that store an auxiliary depth or disparity image), through libheif ([`super::heif`]).
//!
//! Contract of [`read_depth`]:
//! - The primary image's depth image (the `auxl`-linked item whose `auxC` type is depth), its
//!   first one if there are several (a warning says so). `Ok(None)` when it has none.
//! - Its ISO/IEC 23002-3 depth representation decides what a sample means ([`RangeFormat`]):
//!   type 0 uniform inverse Z (`z_near`, `z_far`), type 1 uniform disparity (`d_min`, `d_max`;
//!   Apple's, disparity in 1/m, so depth 1/D), type 2 uniform Z. Type 3 (non-uniform disparity)
//!   is refused, as are missing or impossible bounds (NaN, negative, min ≥ max, z_near = 0 for
//!   type 0). Without a stated representation the samples are read as relative disparity
//!   (brighter nearer, as every portrait camera stores them), and a warning says so.
//! - Samples (8 to 16 bits) are normalized to [0, 1] and turned into depth as the JPEG
//!   embeddings' are ([`EmbeddedDepth`]): the caller normalizes and resizes it to the photo. The
//!   depth image must have the photo's aspect ratio (both in stored orientation).
//!
//! Contract of [`read_matte`]: Apple's portrait effects matte ([`APPLE_PORTRAIT_MATTE`]), the
//! subject's matte, as one channel in [0, 1] at its own size (usually half the photo's), which
//! must have the photo's aspect ratio; `Ok(None)` when the file has none. Other auxiliary
//! images (HDR gain maps, Apple's skin/hair/teeth/glasses mattes) are listed by
//! [`read_matte_and_list`]
//! and not used.
//!
//! Errors name the photo and the item (`the HEIF depth image (item 52)`), never a panic, and a
//! file that claims a depth image never reads as one without.

use super::embedded_depth::{Container, DepthImage, DepthInfo, EmbeddedDepth, HeifDepthItem, RangeFormat, same_aspect};
use super::heif::{APPLE_PORTRAIT_MATTE, HeifFile, ImageHandle, Representation};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// A matte a photo embeds.
#[derive(Clone, Debug)]
pub struct EmbeddedMatte {
    /// One channel in [0, 1], the embedded image's size.
    pub matte: Image,
    /// Where it came from.
    pub info: MatteInfo,
}

/// An embedded matte's origin, as `inspect` and the render's report show it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct MatteInfo {
    /// The embedding: "heif".
    pub container: Container,
    /// The auxiliary image's type URN.
    pub aux_type: String,
    /// Its item id.
    pub item_id: u32,
    /// Its size.
    pub width: usize,
    /// Its size.
    pub height: usize,
    /// Bits per sample.
    pub bit_depth: u8,
}

impl MatteInfo {
    /// One line for people.
    pub fn describe(&self) -> String {
        format!("HEIF auxiliary image {} ({}), {}x{} {}-bit", self.item_id, self.aux_type, self.width, self.height, self.bit_depth)
    }
}

/// An auxiliary image of a HEIF photo, for `inspect`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct AuxInfo {
    /// Item id.
    pub item_id: u32,
    /// Type URN (`urn:com:apple:photo:2020:aux:hdrgainmap`...).
    pub aux_type: String,
    /// Size.
    pub width: usize,
    /// Size.
    pub height: usize,
    /// What drbokeh does with it: "matte" (used as the matte) or "not used".
    pub used_as: &'static str,
}

/// ISO 23002-3's name of representation type `t`.
fn representation_name(t: i32) -> Option<&'static str> {
    match t {
        0 => Some("uniform_inverse_Z"),
        1 => Some("uniform_disparity"),
        2 => Some("uniform_Z"),
        3 => Some("nonuniform_disparity"),
        _ => None,
    }
}

/// Reads the depth image of the HEIF photo `path` (see the module doc).
pub fn read_depth(path: &Path, limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    let file = HeifFile::open(path)?;
    let primary = file.primary()?;
    let ids = primary.depth_ids();
    let Some(&id) = ids.first() else { return Ok(None) };
    let mut warnings = Vec::new();
    if ids.len() > 1 {
        warnings.push(format!("{} has {} depth images; the first (item {id}) is used", path.display(), ids.len()));
    }
    let what = format!("the HEIF depth image (item {id})");
    let rep = primary.depth_representation(id);
    let (format, near, far) = law(path, rep.as_ref(), &what)?;
    if rep.is_none() {
        warnings.push(format!(
            "{}: {what} states no depth representation (ISO/IEC 23002-3); its samples are read as relative disparity, brighter nearer",
            path.display()
        ));
    }
    let plane = checked_plane(path, &primary, &primary.depth_image(id)?, limits, &what)?;
    let info = DepthInfo {
        container: Container::Heif,
        format,
        near,
        far,
        units: None,
        measure_type: None,
        mime: "image/heic".to_owned(),
        width: plane.image.width,
        height: plane.image.height,
        bit_depth: plane.bits,
        data_bytes: None,
        confidence_mime: None,
        item: None,
        heif: Some(HeifDepthItem {
            item_id: id,
            representation: rep.and_then(|r| representation_name(r.kind)),
            z_near: rep.and_then(|r| r.z_near),
            z_far: rep.and_then(|r| r.z_far),
            d_min: rep.and_then(|r| r.d_min),
            d_max: rep.and_then(|r| r.d_max),
        }),
        xmp: None,
    };
    let image = DepthImage { n: plane.image, bit_depth: plane.bits };
    Ok(Some(EmbeddedDepth::new(path, &image, info, None, warnings)))
}

/// The sample law of `rep` (see the module doc) as a [`RangeFormat`] with the depths `near`
/// and `far` the samples span (far infinite for a disparity range from 0); `what` names the
/// depth image in errors.
fn law(path: &Path, rep: Option<&Representation>, what: &str) -> Result<(RangeFormat, f64, f64)> {
    let Some(r) = rep else {
        // Relative disparity n: d_min = 0, d_max = 1.
        return Ok((RangeFormat::UniformDisparity, 1.0, f64::INFINITY));
    };
    let need = |v: Option<f64>, name: &str| {
        v.ok_or_else(|| {
            Error::input(path, format!("{what}: its depth representation ({}) lacks {name}", representation_name(r.kind).unwrap_or("?")))
        })
    };
    let bounds = |lo: f64, hi: f64, names: (&str, &str)| {
        if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo < hi) {
            return Err(Error::input(
                path,
                format!("{what}: {} = {lo} and {} = {hi}; expected finite 0 ≤ {} < {}", names.0, names.1, names.0, names.1),
            ));
        }
        Ok(())
    };
    match r.kind {
        0 | 2 => {
            let (near, far) = (need(r.z_near, "z_near")?, need(r.z_far, "z_far")?);
            bounds(near, far, ("z_near", "z_far"))?;
            if r.kind == 0 && near == 0.0 {
                return Err(Error::input(path, format!("{what}: z_near is 0; a uniform inverse Z range needs z_near > 0")));
            }
            Ok((if r.kind == 0 { RangeFormat::UniformInverseZ } else { RangeFormat::UniformZ }, near, far))
        }
        1 => {
            let (d_min, d_max) = (need(r.d_min, "d_min")?, need(r.d_max, "d_max")?);
            bounds(d_min, d_max, ("d_min", "d_max"))?;
            Ok((RangeFormat::UniformDisparity, 1.0 / d_max, if d_min > 0.0 { 1.0 / d_min } else { f64::INFINITY }))
        }
        3 => Err(Error::input(
            path,
            format!(
                "{what} stores non-uniform disparity (ISO/IEC 23002-3 type 3), which drbokeh does not read; pass the depth with --depth"
            ),
        )),
        t => Err(Error::input(path, format!("{what}: unknown depth representation type {t} (ISO/IEC 23002-3 defines 0 to 3)"))),
    }
}

/// Decodes the auxiliary image `aux` of `primary` as grey in [0, 1] and checks its aspect
/// ratio against the photo's.
fn checked_plane(path: &Path, primary: &ImageHandle, aux: &ImageHandle, limits: &ReadLimits, what: &str) -> Result<super::heif::GreyPlane> {
    let plane = aux.decode_grey(limits, what)?;
    let photo = primary.size();
    let own = (plane.image.width, plane.image.height);
    if !same_aspect(own, photo) {
        return Err(Error::input(
            path,
            format!("{what} is {}x{} but the photo is {}x{} (a different aspect ratio)", own.0, own.1, photo.0, photo.1),
        ));
    }
    Ok(plane)
}

/// Reads the portrait matte of the HEIF photo `path` (see the module doc).
pub fn read_matte(path: &Path, limits: &ReadLimits) -> Result<Option<EmbeddedMatte>> {
    read_matte_and_list(path, limits).map(|(m, _)| m)
}

/// The portrait matte of the HEIF photo `path`, and every auxiliary image other than depth
/// and alpha with what it is used for (for `inspect`): one open of the file for both.
pub fn read_matte_and_list(path: &Path, limits: &ReadLimits) -> Result<(Option<EmbeddedMatte>, Vec<AuxInfo>)> {
    let file = HeifFile::open(path)?;
    let primary = file.primary()?;
    let (mut matte, mut list) = (None, Vec::new());
    for (id, aux_type) in primary.auxiliary()? {
        let aux = primary.auxiliary_image(id)?;
        let (width, height) = aux.size();
        let is_matte = aux_type == APPLE_PORTRAIT_MATTE;
        if is_matte && matte.is_none() {
            let what = format!("the HEIF portrait matte (item {id})");
            let plane = checked_plane(path, &primary, &aux, limits, &what)?;
            let info = MatteInfo {
                container: Container::Heif,
                aux_type: aux_type.clone(),
                item_id: id,
                width: plane.image.width,
                height: plane.image.height,
                bit_depth: plane.bits,
            };
            matte = Some(EmbeddedMatte { matte: plane.image, info });
        }
        list.push(AuxInfo { item_id: id, aux_type, width, height, used_as: if is_matte { "matte" } else { "not used" } });
    }
    Ok((matte, list))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rep(kind: i32, z: Option<(f64, f64)>, d: Option<(f64, f64)>) -> Representation {
        Representation {
            kind,
            z_near: z.map(|z| z.0),
            z_far: z.map(|z| z.1),
            d_min: d.map(|d| d.0),
            d_max: d.map(|d| d.1),
            disparity_reference_view: 0,
        }
    }

    #[test]
    fn laws_follow_the_representation() {
        let p = Path::new("p.heic");
        // Apple's pug: uniform disparity 1.498 .. 4.383 (1/m): the brightest sample is 1/4.383 m.
        let (f, near, far) = law(p, Some(&rep(1, None, Some((1.498, 4.383)))), "d").unwrap();
        assert_eq!(f, RangeFormat::UniformDisparity);
        assert!((f.depth(1.0, near, far) - 1.0 / 4.383).abs() < 1e-12);
        assert!((f.depth(0.0, near, far) - 1.0 / 1.498).abs() < 1e-12);
        assert!((1.0 / f.depth(0.5, near, far) - (1.498 + 4.383) / 2.0).abs() < 1e-12);
        // d_min = 0 is infinitely far.
        let (f, near, far) = law(p, Some(&rep(1, None, Some((0.0, 2.0)))), "d").unwrap();
        assert!(far.is_infinite() && f.depth(0.0, near, far).is_infinite());
        let (f, near, far) = law(p, Some(&rep(0, Some((0.5, 8.0)), None)), "d").unwrap();
        assert_eq!((f, near, far), (RangeFormat::UniformInverseZ, 0.5, 8.0));
        assert!((f.depth(1.0, near, far) - 0.5).abs() < 1e-12 && (f.depth(0.0, near, far) - 8.0).abs() < 1e-12);
        let (f, near, far) = law(p, Some(&rep(2, Some((0.5, 8.0)), None)), "d").unwrap();
        assert_eq!(f.depth(0.0, near, far), 0.5);
        // No representation: relative disparity.
        let (f, near, far) = law(p, None, "d").unwrap();
        assert!((1.0 / f.depth(0.3, near, far) - 0.3).abs() < 1e-12);
    }

    impl Representation {
        fn with_z_far(self, z_far: Option<f64>) -> Representation {
            Representation { z_far, ..self }
        }
    }

    #[test]
    fn representations_have_their_iso_names() {
        let names: Vec<Option<&str>> = (0..5).map(representation_name).collect();
        assert_eq!(names, [Some("uniform_inverse_Z"), Some("uniform_disparity"), Some("uniform_Z"), Some("nonuniform_disparity"), None]);
    }

    #[test]
    fn bad_representations_name_the_field() {
        let p = Path::new("p.heic");
        let cases = [
            (rep(3, None, Some((1.0, 2.0))), "non-uniform"),
            (rep(7, None, None), "unknown depth representation type 7"),
            (rep(1, None, None), "lacks d_min"),
            (rep(1, None, Some((2.0, 1.0))), "d_min = 2"),
            (rep(1, None, Some((2.0, 2.0))), "d_min = 2 and d_max = 2"),
            (rep(1, None, Some((f64::NAN, 1.0))), "d_min = NaN"),
            (rep(0, Some((0.0, 1.0)), None), "z_near is 0"),
            (rep(2, Some((-1.0, 1.0)), None), "z_near = -1"),
            (rep(2, Some((1.0, f64::INFINITY)), None), "z_far = inf"),
            (rep(0, None, None), "(uniform_inverse_Z) lacks z_near"),
            (rep(2, Some((1.0, 2.0)), None).with_z_far(None), "(uniform_Z) lacks z_far"),
        ];
        for (r, want) in cases {
            let e = law(p, Some(&r), "the HEIF depth image (item 5)").unwrap_err().to_string();
            assert!(e.contains("p.heic") && e.contains("item 5") && e.contains(want), "{want}: {e}");
        }
    }
}
