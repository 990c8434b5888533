//! Writes Dynamic Depth 1.0 JPEGs for the tests, per the specification
//! (<https://developer.android.com/training/camera2/Dynamic-depth-v1.0.pdf>): the photo with a
//! standard XMP packet describing `Device:Cameras` (a `Camera:Image` and a `Camera:DepthMap`)
//! and `Device:Container` (`Container:Directory`, a `rdf:Seq` of `Container:Item`s), then the
//! items' bytes appended in directory order after the photo's end. Written here independently
//! of the library's reader; every field can be set to any text, so the bad-input tests can
//! write what no camera should.
#![allow(dead_code)]

use super::gdepth::insert_app1;

/// Dynamic Depth namespaces by prefix.
pub const NAMESPACES: [(&str, &str); 7] = [
    ("Device", "http://ns.google.com/photos/dd/1.0/device/"),
    ("Container", "http://ns.google.com/photos/dd/1.0/container/"),
    ("Item", "http://ns.google.com/photos/dd/1.0/item/"),
    ("Camera", "http://ns.google.com/photos/dd/1.0/camera/"),
    ("DepthMap", "http://ns.google.com/photos/dd/1.0/depthmap/"),
    ("Image", "http://ns.google.com/photos/dd/1.0/image/"),
    ("Profile", "http://ns.google.com/photos/dd/1.0/profile/"),
];

/// One container item: its `Item:*` fields and the bytes appended for it.
#[derive(Clone, Debug)]
pub struct Item {
    /// `Item:*` fields by local name, in order.
    pub fields: Vec<(String, String)>,
    /// The bytes appended to the file for this item.
    pub payload: Vec<u8>,
}

/// A Dynamic Depth JPEG to be written by [`DynamicDepthJpeg::bytes`].
#[derive(Clone, Debug)]
pub struct DynamicDepthJpeg {
    /// The photo: a complete JPEG stream.
    pub photo: Vec<u8>,
    /// `DepthMap:*` fields by local name, in order.
    pub depth_map: Vec<(String, String)>,
    /// The directory, item 0 the primary image.
    pub items: Vec<Item>,
    /// Cameras listed before the one with the depth map (each with an image only).
    pub cameras_before: usize,
    /// Write the structures' fields as elements instead of attributes.
    pub elements: bool,
    /// Bytes appended after the items (another trailer).
    pub after: Vec<u8>,
    /// More attributes (with their namespace declarations) for the packet's description.
    pub extra_attributes: String,
}

impl DynamicDepthJpeg {
    /// A Depth Photo: `format`, `near`, `far` (metres) and the depth image (`mime`, bytes) as
    /// item 2 (`android/depthmap`), after a confidence map (`confidence`, item 1).
    pub fn new(photo: Vec<u8>, format: &str, near: f64, far: f64, mime: &str, image: &[u8], confidence: &[u8]) -> Self {
        let item = |mime: &str, uri: &str, payload: &[u8]| Item {
            fields: vec![("Mime".into(), mime.into()), ("Length".into(), payload.len().to_string()), ("DataURI".into(), uri.into())],
            payload: payload.to_vec(),
        };
        DynamicDepthJpeg {
            photo,
            depth_map: vec![
                ("ItemSemantic".into(), "Depth".into()),
                ("Format".into(), format.into()),
                ("Near".into(), format!("{near}")),
                ("Far".into(), format!("{far}")),
                ("Units".into(), "Meters".into()),
                ("DepthURI".into(), "android/depthmap".into()),
                ("ConfidenceURI".into(), "android/confidencemap".into()),
                ("MeasureType".into(), "OpticalAxis".into()),
            ],
            items: vec![
                item("image/jpeg", "primary_image", &[]),
                item("image/png", "android/confidencemap", confidence),
                item(mime, "android/depthmap", image),
            ],
            cameras_before: 0,
            elements: false,
            after: Vec::new(),
            extra_attributes: String::new(),
        }
    }

    /// Sets (or adds) the `DepthMap` field `name`; `None` removes it.
    pub fn depth_field(mut self, name: &str, value: Option<&str>) -> Self {
        set(&mut self.depth_map, name, value);
        self
    }

    /// Sets (or adds) the field `name` of item `k`; `None` removes it.
    pub fn item_field(mut self, k: usize, name: &str, value: Option<&str>) -> Self {
        set(&mut self.items[k].fields, name, value);
        self
    }

    /// The XMP packet.
    pub fn xmp(&self) -> String {
        let ns: String = NAMESPACES.iter().map(|(p, u)| format!(" xmlns:{p}=\"{u}\"")).collect();
        let strukt = |tag: &str, prefix: &str, fields: &[(String, String)]| {
            if self.elements {
                let inner: String = fields.iter().map(|(n, v)| format!("<{prefix}:{n}>{v}</{prefix}:{n}>")).collect();
                format!("<{tag} rdf:parseType=\"Resource\">{inner}</{tag}>")
            } else {
                let attrs: String = fields.iter().map(|(n, v)| format!(" {prefix}:{n}=\"{v}\"")).collect();
                format!("<{tag}{attrs}/>")
            }
        };
        let image =
            |uri: &str| strukt("Camera:Image", "Image", &[("ItemSemantic".into(), "Original".into()), ("ItemURI".into(), uri.into())]);
        let mut cameras = String::new();
        for k in 0..self.cameras_before {
            cameras.push_str(&format!(
                "<rdf:li rdf:parseType=\"Resource\"><Device:Camera rdf:parseType=\"Resource\">{}</Device:Camera></rdf:li>",
                image(&format!("camera{k}"))
            ));
        }
        let primary =
            strukt("Camera:Image", "Image", &[("ItemSemantic".into(), "Primary".into()), ("ItemURI".into(), "primary_image".into())]);
        cameras.push_str(&format!(
            "<rdf:li rdf:parseType=\"Resource\"><Device:Camera rdf:parseType=\"Resource\">{primary}{}</Device:Camera></rdf:li>",
            strukt("Camera:DepthMap", "DepthMap", &self.depth_map)
        ));
        let items: String = self
            .items
            .iter()
            .map(|i| format!("<rdf:li rdf:parseType=\"Resource\">{}</rdf:li>", strukt("Container:Item", "Item", &i.fields)))
            .collect();
        format!(
            "<?xpacket begin=\"\u{feff}\" id=\"W5M0MpCehiHzreSzNTczkc9d\"?>\n\
             <x:xmpmeta xmlns:x=\"adobe:ns:meta/\"><rdf:RDF xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\">\n\
             <rdf:Description rdf:about=\"\"{ns}{}>\n\
             <Device:Profiles><rdf:Seq><rdf:li rdf:parseType=\"Resource\"><Device:Profile rdf:parseType=\"Resource\">\
             <Profile:Type>DepthPhoto</Profile:Type><Profile:CameraIndices><rdf:Seq><rdf:li>{}</rdf:li></rdf:Seq></Profile:CameraIndices>\
             </Device:Profile></rdf:li></rdf:Seq></Device:Profiles>\n\
             <Device:Cameras><rdf:Seq>{cameras}</rdf:Seq></Device:Cameras>\n\
             <Device:Container rdf:parseType=\"Resource\"><Container:Directory><rdf:Seq>{items}</rdf:Seq></Container:Directory></Device:Container>\n\
             </rdf:Description></rdf:RDF></x:xmpmeta>\n<?xpacket end=\"w\"?>",
            self.extra_attributes, self.cameras_before
        )
    }

    /// The file: the photo with the XMP in an APP1 segment, then every item's payload, then
    /// [`Self::after`].
    pub fn bytes(&self) -> Vec<u8> {
        let mut seg = b"http://ns.adobe.com/xap/1.0/\0".to_vec();
        seg.extend(self.xmp().as_bytes());
        let mut out = insert_app1(&self.photo, &[seg]);
        for i in &self.items {
            out.extend(&i.payload);
        }
        out.extend(&self.after);
        out
    }
}

fn set(fields: &mut Vec<(String, String)>, name: &str, value: Option<&str>) {
    match (fields.iter().position(|(n, _)| n == name), value) {
        (Some(k), Some(v)) => fields[k].1 = v.to_owned(),
        (Some(k), None) => {
            fields.remove(k);
        }
        (None, Some(v)) => fields.push((name.to_owned(), v.to_owned())),
        (None, None) => {}
    }
}
