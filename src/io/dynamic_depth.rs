//! Google's Dynamic Depth 1.0 (<https://developer.android.com/training/camera2/Dynamic-depth-v1.0.pdf>):
//! a JPEG whose XMP describes a device, its cameras and a container of items, the items'
//! bytes appended to the file after the primary image.
//!
//! Contract of [`read`] (called by [`super::embedded::read_embedded`]):
//! - The XMP (either packet) holds `Device:Container` with a `Container:Directory`, a list of
//!   `Container:Item` structures (`Item:Mime`, `Item:Length` in bytes, `Item:Padding`,
//!   `Item:DataURI`), and `Device:Cameras`, each `Device:Camera` with an optional
//!   `Camera:DepthMap` (`DepthMap:ItemSemantic`, `Format`, `Near`, `Far`, `Units`, `DepthURI`,
//!   `ConfidenceURI`, `MeasureType`). Namespaces `http://ns.google.com/photos/dd/1.0/…/`, any
//!   prefix, fields as attributes or elements.
//! - The depth map used is the first camera's whose `ItemSemantic` is `Depth` (or absent);
//!   the Depth Photo profile puts it on camera 0, aligned with the primary image (a depth
//!   map of another camera is used with a warning). A `Segmentation` map is not a depth map.
//!   No depth map: `Ok(None)`, the file embeds none.
//! - Items are laid out in directory order from the end of the primary image (its EOI marker,
//!   found by walking the JPEG: [`super::xmp::jpeg_end`]): item k starts after the `Length`s
//!   of items 1..k. Item 0 is the primary image itself; its `Length` (0 in the reference
//!   writer) takes no room in the trailer. An item's `Padding` is part of its `Length` and
//!   follows its data. The depth item is the one whose `DataURI` equals `DepthURI`.
//! - Its bytes are decoded and converted as GDepth's are (same [`Range`] checks and format
//!   definitions; `Format` without regard to case, as the reference reader does; `Units`
//!   `Diopters` turned into metres).
//! - Errors name the photo and the field (`DepthMap:DepthURI`, `Container:Item 2
//!   ('android/depthmap') Item:Length`...): a missing or duplicate URI, an item that reaches
//!   beyond the file's end, a length that is not a number, a primary image without an end.

use super::embedded_depth::{Container, DepthImage, DepthInfo, EmbeddedDepth, ItemInfo, Packets, Range, shorten};
use super::limits::ReadLimits;
use super::xmp::{JpegXmp, field_values, jpeg_end, single};
use crate::error::{Error, Result};
use std::path::Path;

/// The Dynamic Depth namespaces this reader uses.
pub const NS_DEVICE: &str = "http://ns.google.com/photos/dd/1.0/device/";
/// `Container:Directory`, `Container:Item`.
pub const NS_CONTAINER: &str = "http://ns.google.com/photos/dd/1.0/container/";
/// `Item:Mime`, `Item:Length`, `Item:Padding`, `Item:DataURI`.
pub const NS_ITEM: &str = "http://ns.google.com/photos/dd/1.0/item/";
/// `Camera:DepthMap`, `Camera:Image`.
pub const NS_CAMERA: &str = "http://ns.google.com/photos/dd/1.0/camera/";
/// `DepthMap:Format`, `Near`, `Far`...
pub const NS_DEPTHMAP: &str = "http://ns.google.com/photos/dd/1.0/depthmap/";

/// One `Container:Item`.
struct Item {
    mime: String,
    length: usize,
    padding: usize,
    uri: Option<String>,
}

/// The one value of the field `ns`:`name` of the structure `node`.
fn field(path: &Path, node: roxmltree::Node, ns: &str, name: &str, what: &str) -> Result<Option<String>> {
    Ok(single(path, field_values(node, ns, name), what)?.map(|v| v.trim().to_owned()))
}

/// The Dynamic Depth map of the JPEG bytes `b` (see the module doc), `Ok(None)` when its XMP
/// describes none.
pub(super) fn read(path: &Path, b: &[u8], xmp: &JpegXmp, packets: &Packets, limits: &ReadLimits) -> Result<Option<EmbeddedDepth>> {
    // The first depth map of the cameras, in document order (camera 0 first).
    let cameras: Vec<roxmltree::Node> = packets.docs.iter().flat_map(|d| d.elements(NS_DEVICE, "Camera")).collect();
    let mut chosen = None;
    for (k, cam) in cameras.iter().enumerate() {
        for map in cam.descendants().filter(|n| n.is_element() && n.has_tag_name((NS_CAMERA, "DepthMap"))) {
            let semantic = field(path, map, NS_DEPTHMAP, "ItemSemantic", "DepthMap:ItemSemantic")?;
            if semantic.as_deref().is_none_or(|s| s.eq_ignore_ascii_case("Depth")) {
                chosen = Some((k, map));
                break;
            }
        }
        if chosen.is_some() {
            break;
        }
    }
    let Some((camera, map)) = chosen else { return Ok(None) };
    let f = |name: &str| field(path, map, NS_DEPTHMAP, name, &format!("DepthMap:{name}"));
    let required = |name: &str| {
        f(name)?.ok_or_else(|| {
            Error::input(path, format!("the photo has a Dynamic Depth DepthMap but no DepthMap:{name} (required by Dynamic Depth 1.0)"))
        })
    };
    let range = Range::checked(path, Container::DynamicDepth, &required("Format")?, &required("Near")?, &required("Far")?)?;
    let depth_uri = required("DepthURI")?;
    let items = directory(path, packets)?;
    let matches: Vec<usize> = (0..items.len()).filter(|&k| items[k].uri.as_deref() == Some(depth_uri.as_str())).collect();
    let index = match matches[..] {
        [k] => k,
        [] => {
            let uris: Vec<String> = items.iter().filter_map(|i| i.uri.as_deref().map(|u| format!("'{}'", shorten(u)))).collect();
            return Err(Error::input(
                path,
                format!(
                    "DepthMap:DepthURI is '{}', but no Container:Item has that Item:DataURI (the directory's: {})",
                    shorten(&depth_uri),
                    if uris.is_empty() { "none".to_owned() } else { uris.join(", ") }
                ),
            ));
        }
        _ => {
            return Err(Error::input(path, format!("DepthMap:DepthURI '{}' names {} Container:Items", shorten(&depth_uri), matches.len())));
        }
    };
    let item = &items[index];
    let name = format!("Container:Item {index} ('{}')", shorten(&depth_uri));
    if index == 0 {
        return Err(Error::input(path, format!("{name} is the directory's first item, the primary image; it cannot be the depth map")));
    }
    let end = jpeg_end(b).ok_or_else(|| {
        Error::input(path, format!("the primary JPEG image has no end-of-image marker, so {name} (after it) cannot be found"))
    })?;
    let offset = end + items[1..index].iter().map(|i| i.length).sum::<usize>();
    let trailer = b.len() - end;
    if offset.checked_add(item.length).is_none_or(|stop| stop > b.len()) {
        return Err(Error::input(
            path,
            format!(
                "{name}: Item:Length {} from byte {} of the {} bytes after the primary image reaches beyond the file's end (cut short?)",
                item.length,
                offset - end,
                trailer
            ),
        ));
    }
    let bytes = &b[offset..offset + item.length - item.padding];
    let image = DepthImage::decode(path, b, bytes, &item.mime, &name, &format!("{name} Item:Mime"), limits)?;
    let mut warnings = Vec::new();
    if camera != 0 {
        warnings.push(format!(
            "{}: the Dynamic Depth map is camera {camera}'s (camera 0 has none); it is used as aligned with the primary image",
            path.display()
        ));
    }
    let info = DepthInfo {
        container: Container::DynamicDepth,
        format: range.format,
        near: range.near,
        far: range.far,
        units: f("Units")?,
        measure_type: f("MeasureType")?,
        mime: item.mime.clone(),
        width: image.n.width,
        height: image.n.height,
        bit_depth: image.bit_depth,
        data_bytes: Some(bytes.len()),
        confidence_mime: None,
        item: Some(ItemInfo {
            uri: depth_uri,
            index,
            offset,
            length: item.length,
            padding: item.padding,
            camera,
            confidence_uri: f("ConfidenceURI")?,
        }),
        heif: None,
        xmp: Some(xmp.layout.clone()),
    };
    Ok(Some(EmbeddedDepth::new(path, &image, info, None, warnings)))
}

/// The items of `Container:Directory`, in order.
fn directory(path: &Path, packets: &Packets) -> Result<Vec<Item>> {
    let dirs: Vec<roxmltree::Node> = packets.docs.iter().flat_map(|d| d.elements(NS_CONTAINER, "Directory")).collect();
    let dir = match dirs[..] {
        [d] => d,
        [] => return Err(Error::input(path, "the photo has a Dynamic Depth DepthMap but no Container:Directory listing its items")),
        _ => {
            return Err(Error::input(
                path,
                format!("the photo's XMP has {} Container:Directory lists; Dynamic Depth allows one", dirs.len()),
            ));
        }
    };
    let nodes: Vec<roxmltree::Node> = dir.descendants().filter(|n| n.is_element() && n.has_tag_name((NS_CONTAINER, "Item"))).collect();
    let mut items = Vec::with_capacity(nodes.len());
    for (k, node) in nodes.into_iter().enumerate() {
        let name = |field: &str| format!("Container:Item {k} Item:{field}");
        let f = |field_name: &str| field(path, node, NS_ITEM, field_name, &name(field_name));
        let uri = f("DataURI")?;
        let number = |field_name: &str, v: Option<String>| -> Result<Option<usize>> {
            v.map(|v| {
                v.parse::<usize>().map_err(|_| Error::input(path, format!("{} is '{}', not a byte count", name(field_name), shorten(&v))))
            })
            .transpose()
        };
        let mime = f("Mime")?.ok_or_else(|| Error::input(path, format!("{} is missing (required by Dynamic Depth 1.0)", name("Mime"))))?;
        // The primary image (item 0) takes no room after itself; the others must say theirs.
        let length = match (number("Length", f("Length")?)?, k) {
            (_, 0) => 0,
            (Some(l), _) => l,
            (None, _) => return Err(Error::input(path, format!("{} is missing (required by Dynamic Depth 1.0)", name("Length")))),
        };
        let padding = number("Padding", f("Padding")?)?.unwrap_or(0);
        if k > 0 && padding > 0 && padding >= length {
            return Err(Error::input(path, format!("{} ({padding}) must be less than its Item:Length ({length})", name("Padding"))));
        }
        items.push(Item { mime, length, padding: if k == 0 { 0 } else { padding }, uri });
    }
    Ok(items)
}
