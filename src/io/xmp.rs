//! XMP metadata of a JPEG file: the standard packet and the extended one, and the lookup of a
//! property by namespace and name.
//!
//! Contract (Adobe XMP Specification Part 3, "JPEG"):
//! - XMP lives in APP1 segments before the first start-of-scan. The *standard* packet is one
//!   segment whose payload starts with `http://ns.adobe.com/xap/1.0/\0`; the rest of the
//!   payload is the packet (UTF-8).
//! - A packet larger than a segment continues in *extended* XMP: segments whose payload starts
//!   with `http://ns.adobe.com/xmp/extension/\0`, then a 32-character GUID, the full length of
//!   the extended packet (u32, big-endian), the offset of this chunk in it (u32, big-endian),
//!   then the chunk. The chunks are put together by offset. The standard packet names the
//!   extended packet it belongs to in `xmpNote:HasExtendedXMP` (the GUID); chunks of another
//!   GUID are left out (an older packet a tool left behind), as ExifTool does. The GUID is
//!   meant to be the MD5 of the extended packet; like ExifTool, the reader does not check that.
//! - Errors (each an [`Error::Input`] naming the file and the field): a packet that is not
//!   UTF-8 or not well-formed XML, `xmpNote:HasExtendedXMP` naming a GUID no segment carries
//!   (or carrying extended segments without naming one), chunks that leave a gap, overlap
//!   with other bytes, or lie outside the full length they declare.
//!
//! Allocation is bounded by the file's size: the extended packet is put together from the
//! chunks that are present, after their offsets and lengths were checked.
//!
//! Properties are looked up by namespace URI (not by prefix: a writer may choose any prefix)
//! and local name, written either as an attribute (`GDepth:Near="1.5"`) or as an element
//! (`<GDepth:Near>1.5</GDepth:Near>`), anywhere in the packet ([`Packet::values`]).

use crate::error::{Error, Result};
use std::path::Path;

/// Start of a standard XMP APP1 payload.
const STANDARD_HEADER: &[u8] = b"http://ns.adobe.com/xap/1.0/\0";
/// Start of an extended XMP APP1 payload.
const EXTENDED_HEADER: &[u8] = b"http://ns.adobe.com/xmp/extension/\0";
/// GUID, full length (u32), offset (u32) after [`EXTENDED_HEADER`].
const EXTENDED_FIELDS: usize = 32 + 4 + 4;
/// The `xmpNote` namespace (`HasExtendedXMP`).
pub const NS_XMP_NOTE: &str = "http://ns.adobe.com/xmp/note/";

/// Where the XMP of a file came from: the segments, for reports.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct XmpLayout {
    /// The file has a standard XMP packet.
    pub standard: bool,
    /// Extended XMP segments put together (0: no extended packet).
    pub extended_segments: usize,
    /// Bytes of the extended packet.
    pub extended_bytes: usize,
    /// The extended packet's GUID (`xmpNote:HasExtendedXMP`), if there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub guid: Option<String>,
}

/// The XMP packets of a JPEG file, as text.
#[derive(Clone, Debug, Default)]
pub struct JpegXmp {
    /// The standard packet.
    pub standard: Option<String>,
    /// The extended packet, put together and checked against the standard packet's GUID.
    pub extended: Option<String>,
    /// Segments and sizes (for reports).
    pub layout: XmpLayout,
}

/// One marker of a JPEG stream: its code, its payload (empty for the markers that carry no
/// length: SOI, EOI, RSTn, TEM) and where the next marker may start.
struct Marker {
    code: u8,
    payload: std::ops::Range<usize>,
    next: usize,
}

/// The marker at `i` (fill bytes `0xFF` before the code are skipped), or None where the
/// stream is not at a marker, ends early or has a malformed segment length.
fn marker_at(b: &[u8], mut i: usize) -> Option<Marker> {
    if b.get(i) != Some(&0xFF) {
        return None;
    }
    while b.get(i) == Some(&0xFF) {
        i += 1;
    }
    let code = *b.get(i)?;
    i += 1;
    if matches!(code, 0x01 | 0xD0..=0xD9) {
        return Some(Marker { code, payload: i..i, next: i });
    }
    let len = b.get(i..i + 2).map(|l| u16::from_be_bytes([l[0], l[1]]) as usize)?;
    if len < 2 || i + len > b.len() {
        return None;
    }
    Some(Marker { code, payload: i + 2..i + len, next: i + len })
}

const SOS: u8 = 0xDA;
const EOI: u8 = 0xD9;

/// The payloads of the APP1 segments of the JPEG stream `b`, in file order, up to the first
/// start-of-scan (metadata comes before the image data). A stream that ends early or has a
/// malformed segment length ends the walk: the photo's decoder reports the damage.
pub fn app1_segments(b: &[u8]) -> Vec<&[u8]> {
    const APP1: u8 = 0xE1;
    let mut out = Vec::new();
    if !b.starts_with(&[0xFF, 0xD8]) {
        return out;
    }
    let mut i = 2;
    while let Some(m) = marker_at(b, i) {
        match m.code {
            SOS | EOI => break,
            APP1 => out.push(&b[m.payload.clone()]),
            _ => {}
        }
        i = m.next;
    }
    out
}

/// The length of the first JPEG image of `b`: the offset just after its end-of-image marker,
/// found by walking its segments and skipping each scan's entropy-coded data (where `0xFF` is
/// followed by a stuffed `0x00`, a restart marker or fill bytes). An EXIF thumbnail inside an
/// APP1 segment is skipped with its segment. None when `b` is not a JPEG or ends before its
/// end-of-image marker. What follows it is a file's trailer (Dynamic Depth container items).
pub fn jpeg_end(b: &[u8]) -> Option<usize> {
    if !b.starts_with(&[0xFF, 0xD8]) {
        return None;
    }
    let mut i = 2;
    loop {
        let m = marker_at(b, i)?;
        if m.code == EOI {
            return Some(m.next);
        }
        i = m.next;
        if m.code == SOS {
            // Entropy-coded data up to the next marker that is not stuffing or a restart.
            loop {
                i += b.get(i..)?.iter().position(|&c| c == 0xFF)?;
                match *b.get(i + 1)? {
                    0x00 | 0xD0..=0xD7 => i += 2,
                    0xFF => i += 1,
                    _ => break,
                }
            }
        }
    }
}

/// One extended XMP chunk.
struct Chunk<'a> {
    guid: &'a [u8],
    full: u32,
    offset: u32,
    data: &'a [u8],
}

/// Reads the standard and extended XMP of the JPEG bytes `b` (see the module doc). `path`
/// names the file in errors.
pub fn read_jpeg_xmp(path: &Path, b: &[u8]) -> Result<JpegXmp> {
    let mut standard: Option<&[u8]> = None;
    let mut chunks: Vec<Chunk> = Vec::new();
    for seg in app1_segments(b) {
        if let Some(packet) = seg.strip_prefix(STANDARD_HEADER) {
            // A second standard packet is not allowed; the first one is the file's.
            standard.get_or_insert(packet);
        } else if let Some(rest) = seg.strip_prefix(EXTENDED_HEADER) {
            if rest.len() < EXTENDED_FIELDS {
                return Err(Error::input(
                    path,
                    format!("extended XMP segment is {} bytes, shorter than its GUID, length and offset fields", seg.len()),
                ));
            }
            let word = |k: usize| u32::from_be_bytes([rest[k], rest[k + 1], rest[k + 2], rest[k + 3]]);
            chunks.push(Chunk { guid: &rest[..32], full: word(32), offset: word(36), data: &rest[EXTENDED_FIELDS..] });
        }
    }
    let mut out = JpegXmp::default();
    let Some(standard) = standard else {
        if let Some(c) = chunks.first() {
            return Err(Error::input(
                path,
                format!(
                    "the file has extended XMP segments (GUID {}) but no standard XMP packet to name them (xmpNote:HasExtendedXMP)",
                    String::from_utf8_lossy(c.guid)
                ),
            ));
        }
        return Ok(out);
    };
    let standard = utf8(path, standard, "standard XMP packet")?;
    out.layout.standard = true;
    let doc = Packet::parse(path, &standard, "standard XMP packet")?;
    let guid = doc.single_value(path, NS_XMP_NOTE, "HasExtendedXMP", "xmpNote:HasExtendedXMP")?;
    out.standard = Some(standard.clone());
    let Some(guid) = guid else {
        if let Some(c) = chunks.first() {
            return Err(Error::input(
                path,
                format!(
                    "the file has extended XMP segments (GUID {}) but its standard XMP names none (no xmpNote:HasExtendedXMP): \
                     the extended packet may belong to another version of the photo",
                    String::from_utf8_lossy(c.guid)
                ),
            ));
        }
        return Ok(out);
    };
    let guid = guid.trim().to_owned();
    let mine: Vec<&Chunk> = chunks.iter().filter(|c| c.guid == guid.as_bytes()).collect();
    if mine.is_empty() {
        let others: Vec<String> = chunks
            .iter()
            .map(|c| String::from_utf8_lossy(c.guid).into_owned())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .collect();
        let found = if others.is_empty() {
            "the file has no extended XMP segment".to_owned()
        } else {
            format!("its extended XMP segments carry GUID {}", others.join(", "))
        };
        return Err(Error::input(
            path,
            format!("xmpNote:HasExtendedXMP names the extended XMP packet {guid}, but {found} (a GUID mismatch or missing segments)"),
        ));
    }
    let packet = assemble(path, &guid, &mine)?;
    out.layout.extended_segments = mine.len();
    out.layout.extended_bytes = packet.len();
    out.layout.guid = Some(guid);
    let extended = utf8(path, &packet, "extended XMP packet")?;
    out.extended = Some(extended);
    Ok(out)
}

/// The extended packet of `chunks` (one GUID): sorted by offset, each within the declared
/// full length, together covering it exactly once (a chunk repeated with the same bytes is
/// allowed).
fn assemble(path: &Path, guid: &str, chunks: &[&Chunk]) -> Result<Vec<u8>> {
    let full = chunks[0].full;
    let field = format!("extended XMP (GUID {guid})");
    if let Some(c) = chunks.iter().find(|c| c.full != full) {
        return Err(Error::input(path, format!("{field}: its segments disagree on the packet's length ({full} and {} bytes)", c.full)));
    }
    let mut sorted: Vec<&Chunk> = chunks.to_vec();
    sorted.sort_by_key(|c| c.offset);
    let mut packet: Vec<u8> = Vec::new();
    for c in sorted {
        let (start, end) = (c.offset as u64, c.offset as u64 + c.data.len() as u64);
        if end > full as u64 {
            return Err(Error::input(
                path,
                format!("{field}: a segment holds bytes {start}..{end}, beyond the packet's length of {full} bytes"),
            ));
        }
        let have = packet.len() as u64;
        if start > have {
            return Err(Error::input(
                path,
                format!("{field} is incomplete: bytes {have}..{start} of {full} are missing (a segment was lost or cut)"),
            ));
        }
        // Overlap: the bytes already there must be the same.
        let overlap = (have.min(end) - start) as usize;
        if packet[start as usize..start as usize + overlap] != c.data[..overlap] {
            return Err(Error::input(path, format!("{field}: two segments give different bytes at offset {start}")));
        }
        packet.extend_from_slice(&c.data[overlap..]);
    }
    if (packet.len() as u64) < full as u64 {
        return Err(Error::input(
            path,
            format!("{field} is incomplete: bytes {}..{full} of {full} are missing (a segment was lost or cut)", packet.len()),
        ));
    }
    Ok(packet)
}

fn utf8(path: &Path, b: &[u8], what: &str) -> Result<String> {
    // Packets are often padded with NULs or whitespace after the closing processing instruction.
    let end = b.iter().rposition(|&c| c != 0).map_or(0, |i| i + 1);
    String::from_utf8(b[..end].to_vec()).map_err(|e| Error::input(path, format!("{what} is not UTF-8 text ({e})")))
}

/// A parsed XMP packet.
pub struct Packet<'a> {
    doc: roxmltree::Document<'a>,
}

impl<'a> Packet<'a> {
    /// Parses `text` (an XMP packet); `what` names it in errors. DTDs are refused (no entity
    /// expansion).
    pub fn parse(path: &Path, text: &'a str, what: &str) -> Result<Packet<'a>> {
        let opt = roxmltree::ParsingOptions { allow_dtd: false, ..Default::default() };
        roxmltree::Document::parse_with_options(text, opt)
            .map(|doc| Packet { doc })
            .map_err(|e| Error::input(path, format!("{what} is not well-formed XML: {e}")))
    }

    /// Every value of the property `ns`:`name` anywhere in the packet (see [`field_values`]).
    pub fn values(&self, ns: &str, name: &str) -> Vec<String> {
        field_values(self.doc.root(), ns, name)
    }

    /// The elements `ns`:`name` (structures, as Dynamic Depth's `Container:Item`), in document
    /// order; their fields are read with [`field_values`].
    pub fn elements<'p>(&'p self, ns: &str, name: &str) -> Vec<roxmltree::Node<'p, 'a>> {
        self.doc.descendants().filter(|n| n.is_element() && n.tag_name().namespace() == Some(ns) && n.tag_name().name() == name).collect()
    }

    /// The one value of `ns`:`name`, if any; the same value given several times is one value,
    /// different values are an error naming `field`.
    pub fn single_value(&self, path: &Path, ns: &str, name: &str, field: &str) -> Result<Option<String>> {
        single(path, self.values(ns, name), field)
    }
}

/// Every value of the property `ns`:`name` within `node` (the node and its descendants):
/// attributes of that name on any element, and the text of elements of that name (an element
/// with child elements is a structure, not a text value: its text is empty).
pub fn field_values(node: roxmltree::Node, ns: &str, name: &str) -> Vec<String> {
    let mut out = Vec::new();
    for node in node.descendants().filter(|n| n.is_element()) {
        if let Some(v) = node.attribute((ns, name)) {
            out.push(v.to_owned());
        }
        let tag = node.tag_name();
        if tag.namespace() == Some(ns) && tag.name() == name {
            let text: String = node.children().filter(|c| c.is_text()).filter_map(|c| c.text()).collect();
            out.push(text);
        }
    }
    out
}

/// The one value of `values` (several equal ones count once), or an error naming `field`.
pub fn single(path: &Path, mut values: Vec<String>, field: &str) -> Result<Option<String>> {
    values.sort();
    values.dedup();
    match values.len() {
        0 => Ok(None),
        1 => Ok(values.pop()),
        _ => {
            let shown: Vec<String> =
                values
                    .iter()
                    .map(|v| {
                        if v.len() > 40 {
                            format!("'{}…' ({} bytes)", &v[..v.floor_char_boundary(40)], v.len())
                        } else {
                            format!("'{v}'")
                        }
                    })
                    .collect();
            Err(Error::input(path, format!("{field} is given several times with different values: {}", shown.join(", "))))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn app1(payload: &[u8]) -> Vec<u8> {
        let mut s = vec![0xFF, 0xE1];
        s.extend(((payload.len() + 2) as u16).to_be_bytes());
        s.extend(payload);
        s
    }

    fn jpeg(segments: &[Vec<u8>]) -> Vec<u8> {
        let mut b = vec![0xFF, 0xD8];
        for s in segments {
            b.extend(app1(s));
        }
        b.extend([0xFF, 0xDA, 0x00, 0x02, 0xFF, 0xD9]);
        b
    }

    fn standard(body: &str) -> Vec<u8> {
        let mut p = STANDARD_HEADER.to_vec();
        p.extend(body.as_bytes());
        p
    }

    fn extended(guid: &str, full: u32, offset: u32, data: &[u8]) -> Vec<u8> {
        let mut p = EXTENDED_HEADER.to_vec();
        p.extend(guid.as_bytes());
        p.extend(full.to_be_bytes());
        p.extend(offset.to_be_bytes());
        p.extend(data);
        p
    }

    const GUID: &str = "0123456789ABCDEF0123456789ABCDEF";

    fn with_guid(guid: &str) -> String {
        format!(
            r#"<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
            <rdf:Description xmlns:xmpNote="http://ns.adobe.com/xmp/note/" xmpNote:HasExtendedXMP="{guid}"/></rdf:RDF></x:xmpmeta>"#
        )
    }

    #[test]
    fn chunks_are_put_together_by_offset_in_any_order() {
        let ext = b"<x:xmpmeta xmlns:x='adobe:ns:meta/'><a xmlns:t='urn:t' t:v='1'/></x:xmpmeta>";
        let n = ext.len() as u32;
        let b = jpeg(&[standard(&with_guid(GUID)), extended(GUID, n, 30, &ext[30..]), extended(GUID, n, 0, &ext[..30])]);
        let x = read_jpeg_xmp(Path::new("p.jpg"), &b).unwrap();
        assert_eq!(x.extended.as_deref(), Some(std::str::from_utf8(ext).unwrap()));
        assert_eq!((x.layout.extended_segments, x.layout.extended_bytes), (2, ext.len()));
        let doc = Packet::parse(Path::new("p"), x.extended.as_deref().unwrap(), "x").unwrap();
        assert_eq!(doc.values("urn:t", "v"), vec!["1".to_owned()]);
    }

    #[test]
    fn missing_chunks_and_guid_mismatch_are_errors() {
        let ext = b"<x/>0123456789";
        let n = ext.len() as u32;
        let p = Path::new("p.jpg");
        // A gap in the middle, the end missing, a chunk beyond the length.
        for segs in [
            vec![extended(GUID, n, 0, &ext[..4]), extended(GUID, n, 8, &ext[8..])],
            vec![extended(GUID, n, 0, &ext[..8])],
            vec![extended(GUID, n, 0, &ext[..]), extended(GUID, n, 10, &ext[..8])],
        ] {
            let mut all = vec![standard(&with_guid(GUID))];
            all.extend(segs);
            let e = read_jpeg_xmp(p, &jpeg(&all)).unwrap_err().to_string();
            assert!(e.contains("p.jpg") && e.contains("extended XMP") && e.contains(GUID), "{e}");
        }
        let other = "FFFFFFFFFFFFFFFFFFFFFFFFFFFFFFFF";
        let e = read_jpeg_xmp(p, &jpeg(&[standard(&with_guid(GUID)), extended(other, n, 0, ext)])).unwrap_err().to_string();
        assert!(e.contains("xmpNote:HasExtendedXMP") && e.contains(other) && e.contains("mismatch"), "{e}");
        let e = read_jpeg_xmp(p, &jpeg(&[standard(&with_guid(GUID))])).unwrap_err().to_string();
        assert!(e.contains("no extended XMP segment"), "{e}");
        // Extended segments without a standard packet naming them.
        let e = read_jpeg_xmp(p, &jpeg(&[standard("<a/>"), extended(GUID, n, 0, ext)])).unwrap_err().to_string();
        assert!(e.contains("HasExtendedXMP"), "{e}");
        // A stale packet of another GUID next to the right one is left out.
        let b = jpeg(&[standard(&with_guid(GUID)), extended(other, 3, 0, b"<y>"), extended(GUID, n, 0, ext)]);
        assert_eq!(read_jpeg_xmp(p, &b).unwrap().extended.as_deref(), Some("<x/>0123456789"));
    }

    #[test]
    fn the_walk_stops_at_the_scan_and_survives_cuts() {
        let b = jpeg(&[standard("<a/>")]);
        assert_eq!(app1_segments(&b).len(), 1);
        for cut in 0..b.len() {
            let _ = app1_segments(&b[..cut]);
            let _ = read_jpeg_xmp(Path::new("p"), &b[..cut]);
        }
        assert!(read_jpeg_xmp(Path::new("p"), b"not a jpeg").unwrap().standard.is_none());
    }

    #[test]
    fn the_end_of_a_jpeg_skips_segments_and_scan_data() {
        // An APP1 holding an EXIF-like thumbnail with its own end marker, a scan whose data
        // has stuffed bytes, restart markers and fill bytes, a second scan (progressive), then
        // a trailer that itself looks like a JPEG.
        let thumb = [0xFF, 0xD8, 0xFF, 0xD9];
        let mut b = jpeg(&[thumb.to_vec()]);
        b.truncate(b.len() - 6);
        let sos = [0xFF, 0xDA, 0x00, 0x03, 0x01];
        b.extend(sos);
        b.extend([0x12, 0xFF, 0x00, 0x34, 0xFF, 0xD0, 0x56, 0xFF, 0xFF, 0xD1, 0x78]);
        b.extend([0xFF, 0xC4, 0x00, 0x03, 0x00]);
        b.extend(sos);
        b.extend([0x9A, 0xFF, 0x00]);
        b.extend([0xFF, 0xD9]);
        let end = b.len();
        b.extend([0xFF, 0xD8, 0xFF, 0xD9, 1, 2, 3]);
        assert_eq!(jpeg_end(&b), Some(end));
        // Every cut before the end has no end; the walk never panics.
        for cut in 0..end {
            assert_eq!(jpeg_end(&b[..cut]), None, "cut at {cut}");
        }
        assert_eq!(jpeg_end(b"not a jpeg"), None);
        // A real encoder's stream ends where its bytes do.
        let mut real = Vec::new();
        let img = image::RgbImage::from_fn(37, 23, |x, y| image::Rgb([(x * 7) as u8, (y * 11) as u8, (x * y) as u8]));
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut real, 90).encode_image(&img).unwrap();
        let n = real.len();
        real.extend(b"trailer");
        assert_eq!(jpeg_end(&real), Some(n));
    }

    #[test]
    fn values_as_attributes_and_elements_by_namespace() {
        let text = r#"<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">
            <rdf:Description xmlns:g="urn:g" g:Near="1.5"><g:Far>4</g:Far></rdf:Description>
            <rdf:Description xmlns:h="urn:g"><h:Near>1.5</h:Near></rdf:Description></rdf:RDF></x:xmpmeta>"#;
        let doc = Packet::parse(Path::new("p"), text, "x").unwrap();
        let p = Path::new("p");
        assert_eq!(doc.single_value(p, "urn:g", "Near", "g:Near").unwrap().as_deref(), Some("1.5"));
        assert_eq!(doc.single_value(p, "urn:g", "Far", "g:Far").unwrap().as_deref(), Some("4"));
        assert_eq!(doc.single_value(p, "urn:other", "Far", "o:Far").unwrap(), None);
        let two = text.replace("<h:Near>1.5", "<h:Near>2");
        let doc = Packet::parse(p, &two, "x").unwrap();
        let e = doc.single_value(p, "urn:g", "Near", "GDepth:Near").unwrap_err().to_string();
        assert!(e.contains("GDepth:Near") && e.contains("'1.5'") && e.contains("'2'"), "{e}");
        let e = Packet::parse(p, "<a><b></a>", "standard XMP packet").err().unwrap().to_string();
        assert!(e.contains("not well-formed"), "{e}");
        let e = Packet::parse(p, "<!DOCTYPE a [<!ENTITY x 'y'>]><a>&x;</a>", "standard XMP packet").err().unwrap().to_string();
        assert!(e.contains("not well-formed"), "{e}");
    }
}
