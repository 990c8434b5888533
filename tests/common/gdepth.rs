//! Writes GDepth JPEGs for the tests: a photo JPEG with an APP1 XMP packet holding Google's
//! depth-map properties (`http://ns.google.com/photos/1.0/depthmap/`) and the depth image as
//! base64, optionally split over a standard packet and several extended XMP segments
//! (`http://ns.adobe.com/xmp/extension/`: GUID, full length, offset). Every field can be set
//! to any text, chunks dropped and GUIDs changed, so the bad-input tests can write what no
//! camera should.
#![allow(dead_code)]

use drbokeh::Image;

/// The GDepth namespace.
pub const NS_GDEPTH: &str = "http://ns.google.com/photos/1.0/depthmap/";
/// A GUID (32 hex digits; real writers use the MD5 of the extended packet).
pub const GUID: &str = "5D9C3C2E8E2A4B0F9A1B2C3D4E5F6071";

/// A GDepth JPEG to be written by [`GDepthJpeg::bytes`].
#[derive(Clone, Debug)]
pub struct GDepthJpeg {
    /// The photo: a complete JPEG stream.
    pub photo: Vec<u8>,
    /// GDepth properties by local name, in order (`Data` is the base64 text).
    pub fields: Vec<(String, String)>,
    /// Write the properties as elements (`<GDepth:Near>1</GDepth:Near>`) instead of attributes.
    pub elements: bool,
    /// `Some(n)`: `Data` goes to the extended packet, written in chunks of `n` bytes.
    pub extended_chunk: Option<usize>,
    /// The GUID the standard packet names (`xmpNote:HasExtendedXMP`).
    pub guid: String,
    /// The GUID written on the extended chunks (default: `guid`).
    pub chunk_guid: Option<String>,
    /// Leave out the extended chunk of this index.
    pub drop_chunk: Option<usize>,
    /// Namespace prefix of the GDepth properties (any prefix is legal).
    pub prefix: String,
}

impl GDepthJpeg {
    /// A photo with a GDepth map: `format` ("RangeInverse", "RangeLinear"), `near`, `far`,
    /// `mime` and the depth image's bytes.
    pub fn new(photo: Vec<u8>, format: &str, near: f64, far: f64, mime: &str, image: &[u8]) -> GDepthJpeg {
        let fields = vec![
            ("Format".to_owned(), format.to_owned()),
            ("Near".to_owned(), format!("{near}")),
            ("Far".to_owned(), format!("{far}")),
            ("Mime".to_owned(), mime.to_owned()),
            ("Units".to_owned(), "m".to_owned()),
            ("MeasureType".to_owned(), "OpticalAxis".to_owned()),
            ("Data".to_owned(), base64(image)),
        ];
        GDepthJpeg {
            photo,
            fields,
            elements: false,
            extended_chunk: None,
            guid: GUID.to_owned(),
            chunk_guid: None,
            drop_chunk: None,
            prefix: "GDepth".to_owned(),
        }
    }

    /// Sets (or adds) the property `name`.
    pub fn set(mut self, name: &str, value: &str) -> Self {
        match self.fields.iter_mut().find(|(n, _)| n == name) {
            Some(f) => f.1 = value.to_owned(),
            None => self.fields.push((name.to_owned(), value.to_owned())),
        }
        self
    }

    /// Removes the property `name`.
    pub fn without(mut self, name: &str) -> Self {
        self.fields.retain(|(n, _)| n != name);
        self
    }

    /// Splits the XMP: `Data` in the extended packet, in chunks of `n` bytes.
    pub fn extended(mut self, n: usize) -> Self {
        self.extended_chunk = Some(n);
        self
    }

    /// The JPEG file: the photo with the XMP segments after its SOI and APP0 (JFIF).
    pub fn bytes(&self) -> Vec<u8> {
        let (std_fields, ext_fields): (Vec<_>, Vec<_>) =
            self.fields.iter().cloned().partition(|(n, _)| self.extended_chunk.is_none() || n != "Data");
        let mut segments = Vec::new();
        let mut standard = self.packet(&std_fields, self.extended_chunk.map(|_| self.guid.as_str()));
        standard.insert_str(0, "http://ns.adobe.com/xap/1.0/\0");
        segments.push(standard.into_bytes());
        if let Some(n) = self.extended_chunk {
            let ext = self.packet(&ext_fields, None).into_bytes();
            let guid = self.chunk_guid.as_deref().unwrap_or(&self.guid);
            for (i, (k, chunk)) in ext.chunks(n).enumerate().enumerate() {
                if self.drop_chunk == Some(i) {
                    continue;
                }
                let mut s = b"http://ns.adobe.com/xmp/extension/\0".to_vec();
                s.extend(guid.as_bytes());
                s.extend((ext.len() as u32).to_be_bytes());
                s.extend(((k * n) as u32).to_be_bytes());
                s.extend(chunk);
                segments.push(s);
            }
        }
        insert_app1(&self.photo, &segments)
    }

    /// One XMP packet with `fields` (and `xmpNote:HasExtendedXMP` = `guid`).
    fn packet(&self, fields: &[(String, String)], guid: Option<&str>) -> String {
        let p = &self.prefix;
        let mut attrs = String::new();
        let mut elems = String::new();
        for (n, v) in fields {
            if self.elements {
                elems.push_str(&format!("\n   <{p}:{n}>{v}</{p}:{n}>"));
            } else {
                attrs.push_str(&format!("\n   {p}:{n}=\"{v}\""));
            }
        }
        if let Some(g) = guid {
            attrs.push_str(&format!("\n   xmpNote:HasExtendedXMP=\"{g}\""));
        }
        format!(
            "<?xpacket begin=\"\u{feff}\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?>\n\
             <x:xmpmeta xmlns:x=\"adobe:ns:meta/\">\n <rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n  \
             <rdf:Description rdf:about=\"\" xmlns:{p}=\"{NS_GDEPTH}\" xmlns:xmpNote=\"http://ns.adobe.com/xmp/note/\"{attrs}>{elems}\n  \
             </rdf:Description>\n </rdf:RDF>\n</x:xmpmeta>\n<?xpacket end=\"w\"?>"
        )
    }
}

/// `jpeg` with APP1 segments of `payloads` inserted after SOI and a leading APP0.
pub fn insert_app1(jpeg: &[u8], payloads: &[Vec<u8>]) -> Vec<u8> {
    assert!(jpeg.starts_with(&[0xFF, 0xD8]), "not a JPEG");
    let mut at = 2;
    if jpeg[2..4] == [0xFF, 0xE0] {
        at = 4 + u16::from_be_bytes([jpeg[4], jpeg[5]]) as usize;
    }
    let mut out = jpeg[..at].to_vec();
    for p in payloads {
        assert!(p.len() + 2 <= 0xFFFF, "an APP1 segment holds at most 65533 bytes, not {}", p.len());
        out.extend([0xFF, 0xE1]);
        out.extend(((p.len() + 2) as u16).to_be_bytes());
        out.extend(p);
    }
    out.extend(&jpeg[at..]);
    out
}

/// Standard base64 with padding.
pub fn base64(bytes: &[u8]) -> String {
    use base64::Engine;
    base64::engine::general_purpose::STANDARD.encode(bytes)
}

/// The photo `rgb8` (8-bit sRGB samples as 0..=255 values in an image of 3 channels) as a
/// JPEG of quality 95.
pub fn photo_jpeg(rgb8: &image::RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95).encode_image(rgb8).expect("JPEG encoding");
    out
}

/// A grey PNG (`bits` 8 or 16) of the normalized samples `n` (one channel, [0, 1]), rounded.
pub fn grey_png(n: &Image, bits: u8) -> Vec<u8> {
    let mut out = Vec::new();
    drbokeh::io::encode_png(&mut out, n, bits, drbokeh::color::Transfer::Linear).expect("PNG encoding");
    out
}

/// The samples `grey_png(n, bits)` stores, as integers.
pub fn quantized(n: &Image, bits: u8) -> Vec<u32> {
    let max = ((1u32 << bits) - 1) as f32;
    n.data.iter().map(|v| (v.clamp(0.0, 1.0) * max).round() as u32).collect()
}

/// Depth `d` in [near, far] normalized as GDepth stores it.
pub fn normalized(format: &str, d: f64, near: f64, far: f64) -> f64 {
    match format {
        "RangeLinear" => (d - near) / (far - near),
        "RangeInverse" => far * (d - near) / (d * (far - near)),
        other => panic!("no format {other}"),
    }
}

/// Depth of the normalized sample `n`, by the GDepth definitions (written here independently
/// of the library's).
pub fn depth_of(format: &str, n: f64, near: f64, far: f64) -> f64 {
    match format {
        "RangeLinear" => n * (far - near) + near,
        "RangeInverse" => far * near / (far - n * (far - near)),
        other => panic!("no format {other}"),
    }
}

/// A PNG header (signature + IHDR) claiming `w` x `h` grey 8-bit pixels, then an empty IDAT
/// and IEND: a "decompression bomb" in a few dozen bytes.
pub fn png_claiming(w: u32, h: u32) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        let mut body = kind.to_vec();
        body.extend(data);
        c.extend(&body);
        c.extend(crate::common::crc32(&body).to_be_bytes());
        c
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend(h.to_be_bytes());
    ihdr.extend([8, 0, 0, 0, 0]);
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    png.extend(chunk(b"IDAT", &[0x78, 0x9C, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]));
    png.extend(chunk(b"IEND", &[]));
    png
}
