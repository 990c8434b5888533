//! HEIF files (HEIC photos from phones, AVIF) through the system's libheif, loaded at run time:
//! the primary image, its depth or disparity image and its portrait matte.
//!
//! Why loaded at run time, and not through the `libheif-rs`/`libheif-sys` crates: those link
//! libheif at build time, found by pkg-config, and need libheif ≥ 1.17 (Debian 12 ships 1.15,
//! Ubuntu 22.04 1.12), so they would make HEIC an optional feature that the default build and
//! most Linux systems lack; their embedded build compiles libheif but not its HEVC decoder. Here
//! the default build needs neither libheif's headers nor its library, and a user who has
//! libheif (Debian/Ubuntu `libheif1`, Fedora `libheif`, macOS `brew install libheif`) reads HEIC
//! with the same binary; the ~30 entry points used are declared below from `libheif/heif.h`. The library is looked for once per process:
//! `DRBOKEH_LIBHEIF` (a path) first, then the loader's search path under its usual names
//! ([`LIBRARY_NAMES`]). libheif ≥ [`MIN_VERSION`] is required (its depth API is settled there).
//! Without it every HEIF read is an [`Error::Input`] naming the file, what was searched and how
//! to install the library.
//!
//! Contracts:
//! - Pixels are in stored order: the container's rotation and mirror (`irot`, `imir`) are not
//!   applied, as EXIF orientation is not applied to a JPEG ([`super::image_file`]); the photo,
//!   its depth image and its matte then stay aligned whatever the container says about display
//!   (phones store the auxiliary images without the primary image's rotation). The crop
//!   (`clap`, the clean aperture) is applied: it is part of each image's size (an encoder pads
//!   a coded picture to its block size and crops it back with `clap`). libheif cannot apply
//!   one without the others, so it decodes with none and the crop is read from the container
//!   here ([`clean_apertures`]) and applied to the decoded plane.
//! - The primary image is decoded as interleaved RGB: 8-bit files as 8-bit samples, 10/12-bit
//!   files as samples scaled to [0, 1] by `2^bits − 1`; display-encoded (the colour profile is
//!   not applied, as for a JPEG). Alpha is dropped.
//! - Auxiliary images (depth, mattes) are decoded as one grey channel in [0, 1] (`q / (2^b − 1)`).
//! - Every size is checked against [`ReadLimits`] from the container's header before anything
//!   is decoded. The file is read into memory once (a HEIC is a few MB) and parsed by libheif
//!   without a copy.
//! - libheif is C++ code of the system: a malformed file it rejects is an error naming the
//!   file and libheif's message; a crash inside it cannot be caught (no panic guard applies).

use super::limits::ReadLimits;
use crate::error::{Error, Result};
use std::ffi::{CStr, c_char, c_int, c_void};
use std::path::Path;
use std::sync::OnceLock;

/// File names tried, in order, when `DRBOKEH_LIBHEIF` is not set.
pub const LIBRARY_NAMES: &[&str] = &[
    "libheif.so.1",
    "libheif.so",
    "libheif.1.dylib",
    "libheif.dylib",
    "/opt/homebrew/lib/libheif.1.dylib",
    "/usr/local/lib/libheif.1.dylib",
    "heif.dll",
    "libheif.dll",
];

/// Oldest libheif accepted (major, minor): 1.11 fixed where depth representation info is read.
pub const MIN_VERSION: (u32, u32) = (1, 11);

/// How to get libheif, for messages.
pub const INSTALL_HINT: &str = "install libheif (Debian/Ubuntu: apt install libheif1; Fedora: dnf install libheif; \
     macOS: brew install libheif) or set DRBOKEH_LIBHEIF to the library's path";

/// Apple's portrait effects matte (iPhone portrait mode): the subject's matte.
pub const APPLE_PORTRAIT_MATTE: &str = "urn:com:apple:photo:2018:aux:portraiteffectsmatte";

// ---------------------------------------------------------------------------------------------
// The C API (libheif/heif.h), as far as it is used.

#[repr(C)]
#[derive(Clone, Copy)]
struct HeifError {
    code: c_int,
    subcode: c_int,
    message: *const c_char,
}

/// `struct heif_depth_representation_info`, version 1 fields.
#[repr(C)]
struct DepthRepresentation {
    version: u8,
    has_z_near: u8,
    has_z_far: u8,
    has_d_min: u8,
    has_d_max: u8,
    z_near: f64,
    z_far: f64,
    d_min: f64,
    d_max: f64,
    representation_type: c_int,
    disparity_reference_view: u32,
    nonlinear_model_size: u32,
    nonlinear_model: *mut u8,
}

enum Context {}
enum Handle {}
enum Picture {}

// enum heif_colorspace / heif_chroma / heif_channel values used.
const COLORSPACE_RGB: c_int = 1;
const COLORSPACE_MONOCHROME: c_int = 2;
const CHROMA_MONOCHROME: c_int = 0;
const CHROMA_INTERLEAVED_RGB: c_int = 10;
const CHROMA_INTERLEAVED_RRGGBB_LE: c_int = 14;
const CHANNEL_Y: c_int = 0;
const CHANNEL_INTERLEAVED: c_int = 10;
/// `LIBHEIF_AUX_IMAGE_FILTER_OMIT_ALPHA | LIBHEIF_AUX_IMAGE_FILTER_OMIT_DEPTH`: depth images
/// are listed by their own calls, alpha belongs to the photo.
const AUX_OMIT_ALPHA_AND_DEPTH: c_int = (1 << 1) | (2 << 1);
/// Offset of `ignore_transformations` in `struct heif_decoding_options` (after `version`).
const OPTION_IGNORE_TRANSFORMATIONS: usize = 1;

/// The entry points, resolved once; the library stays loaded for the process.
struct Api {
    version: String,
    context_alloc: unsafe extern "C" fn() -> *mut Context,
    context_free: unsafe extern "C" fn(*mut Context),
    read_from_memory: unsafe extern "C" fn(*mut Context, *const c_void, usize, *const c_void) -> HeifError,
    primary_handle: unsafe extern "C" fn(*mut Context, *mut *mut Handle) -> HeifError,
    primary_id: unsafe extern "C" fn(*mut Context, *mut u32) -> HeifError,
    handle_release: unsafe extern "C" fn(*const Handle),
    handle_width: unsafe extern "C" fn(*const Handle) -> c_int,
    handle_height: unsafe extern "C" fn(*const Handle) -> c_int,
    handle_has_alpha: unsafe extern "C" fn(*const Handle) -> c_int,
    handle_ispe_width: unsafe extern "C" fn(*const Handle) -> c_int,
    handle_ispe_height: unsafe extern "C" fn(*const Handle) -> c_int,
    handle_luma_bits: unsafe extern "C" fn(*const Handle) -> c_int,
    depth_count: unsafe extern "C" fn(*const Handle) -> c_int,
    depth_ids: unsafe extern "C" fn(*const Handle, *mut u32, c_int) -> c_int,
    depth_handle: unsafe extern "C" fn(*const Handle, u32, *mut *mut Handle) -> HeifError,
    depth_representation: unsafe extern "C" fn(*const Handle, u32, *mut *const DepthRepresentation) -> c_int,
    depth_representation_free: unsafe extern "C" fn(*const DepthRepresentation),
    aux_count: unsafe extern "C" fn(*const Handle, c_int) -> c_int,
    aux_ids: unsafe extern "C" fn(*const Handle, c_int, *mut u32, c_int) -> c_int,
    aux_type: unsafe extern "C" fn(*const Handle, *mut *const c_char) -> HeifError,
    aux_type_free: unsafe extern "C" fn(*const Handle, *mut *const c_char),
    aux_handle: unsafe extern "C" fn(*const Handle, u32, *mut *mut Handle) -> HeifError,
    options_alloc: unsafe extern "C" fn() -> *mut u8,
    options_free: unsafe extern "C" fn(*mut u8),
    decode: unsafe extern "C" fn(*const Handle, *mut *mut Picture, c_int, c_int, *const u8) -> HeifError,
    picture_release: unsafe extern "C" fn(*const Picture),
    picture_width: unsafe extern "C" fn(*const Picture, c_int) -> c_int,
    picture_height: unsafe extern "C" fn(*const Picture, c_int) -> c_int,
    picture_bits: unsafe extern "C" fn(*const Picture, c_int) -> c_int,
    plane: unsafe extern "C" fn(*const Picture, c_int, *mut c_int) -> *const u8,
}

/// The process's libheif, or why there is none (a message without the file's name).
fn api() -> std::result::Result<&'static Api, &'static str> {
    static API: OnceLock<std::result::Result<Api, String>> = OnceLock::new();
    API.get_or_init(load).as_ref().map_err(String::as_str)
}

/// Loads libheif and resolves [`Api`].
fn load() -> std::result::Result<Api, String> {
    let (lib, from) = open_library()?;
    // Kept loaded for the process: `Api`'s function pointers point into it.
    let lib: &'static libloading::Library = Box::leak(Box::new(lib));
    macro_rules! sym {
        ($name:literal) => {
            // SAFETY: the symbol has the signature of libheif's heif.h declaration, which the
            // field's type repeats.
            *unsafe { lib.get(concat!($name, "\0").as_bytes()) }.map_err(|e| format!("libheif at {from} lacks {}: {e}", $name))?
        };
    }
    let get_version: unsafe extern "C" fn() -> *const c_char = sym!("heif_get_version");
    // SAFETY: returns a static NUL-terminated string.
    let version = unsafe { CStr::from_ptr(get_version()) }.to_string_lossy().into_owned();
    let mut parts = version.split('.').map(|p| p.parse::<u32>().unwrap_or(0));
    let (major, minor) = (parts.next().unwrap_or(0), parts.next().unwrap_or(0));
    if (major, minor) < MIN_VERSION {
        return Err(format!(
            "libheif {version} at {from} is too old (drbokeh needs {}.{} or later); {INSTALL_HINT}",
            MIN_VERSION.0, MIN_VERSION.1
        ));
    }
    // heif_init is reference counted and optional before 1.14's plugins; called once, never undone.
    let init: unsafe extern "C" fn(*const c_void) -> HeifError = sym!("heif_init");
    // SAFETY: NULL parameters are allowed.
    let e = unsafe { init(std::ptr::null()) };
    if e.code != 0 {
        return Err(format!("libheif {version} at {from} failed to start: {}", message(&e)));
    }
    Ok(Api {
        version: format!("{version} ({from})"),
        context_alloc: sym!("heif_context_alloc"),
        context_free: sym!("heif_context_free"),
        read_from_memory: sym!("heif_context_read_from_memory_without_copy"),
        primary_handle: sym!("heif_context_get_primary_image_handle"),
        primary_id: sym!("heif_context_get_primary_image_ID"),
        handle_release: sym!("heif_image_handle_release"),
        handle_width: sym!("heif_image_handle_get_width"),
        handle_height: sym!("heif_image_handle_get_height"),
        handle_has_alpha: sym!("heif_image_handle_has_alpha_channel"),
        handle_ispe_width: sym!("heif_image_handle_get_ispe_width"),
        handle_ispe_height: sym!("heif_image_handle_get_ispe_height"),
        handle_luma_bits: sym!("heif_image_handle_get_luma_bits_per_pixel"),
        depth_count: sym!("heif_image_handle_get_number_of_depth_images"),
        depth_ids: sym!("heif_image_handle_get_list_of_depth_image_IDs"),
        depth_handle: sym!("heif_image_handle_get_depth_image_handle"),
        depth_representation: sym!("heif_image_handle_get_depth_image_representation_info"),
        depth_representation_free: sym!("heif_depth_representation_info_free"),
        aux_count: sym!("heif_image_handle_get_number_of_auxiliary_images"),
        aux_ids: sym!("heif_image_handle_get_list_of_auxiliary_image_IDs"),
        aux_type: sym!("heif_image_handle_get_auxiliary_type"),
        aux_type_free: sym!("heif_image_handle_free_auxiliary_types"),
        aux_handle: sym!("heif_image_handle_get_auxiliary_image_handle"),
        options_alloc: sym!("heif_decoding_options_alloc"),
        options_free: sym!("heif_decoding_options_free"),
        decode: sym!("heif_decode_image"),
        picture_release: sym!("heif_image_release"),
        picture_width: sym!("heif_image_get_width"),
        picture_height: sym!("heif_image_get_height"),
        picture_bits: sym!("heif_image_get_bits_per_pixel_range"),
        plane: sym!("heif_image_get_plane_readonly"),
    })
}

/// The library from `DRBOKEH_LIBHEIF`, else the first of [`LIBRARY_NAMES`] that loads.
fn open_library() -> std::result::Result<(libloading::Library, String), String> {
    // SAFETY (both loads): libheif's initializers only register its codecs.
    if let Some(p) = std::env::var_os("DRBOKEH_LIBHEIF").filter(|s| !s.is_empty()) {
        let shown = Path::new(&p).display().to_string();
        return unsafe { libloading::Library::new(&p) }
            .map(|l| (l, shown.clone()))
            .map_err(|e| format!("libheif could not be loaded from DRBOKEH_LIBHEIF={shown}: {e}; {INSTALL_HINT}"));
    }
    for name in LIBRARY_NAMES {
        if let Ok(l) = unsafe { libloading::Library::new(*name) } {
            return Ok((l, (*name).to_owned()));
        }
    }
    Err(format!(
        "reading HEIF/HEIC needs libheif, which was not found (tried DRBOKEH_LIBHEIF, {}); {INSTALL_HINT}",
        LIBRARY_NAMES.join(", ")
    ))
}

/// libheif's message of `e`.
fn message(e: &HeifError) -> String {
    if e.message.is_null() {
        return format!("error {}.{}", e.code, e.subcode);
    }
    // SAFETY: libheif's messages are static NUL-terminated strings.
    unsafe { CStr::from_ptr(e.message) }.to_string_lossy().into_owned()
}

/// The libheif in use ("1.15.1 (libheif.so.1)"), or why there is none.
pub fn library_version() -> std::result::Result<String, String> {
    api().map(|a| a.version.clone()).map_err(str::to_owned)
}

// ---------------------------------------------------------------------------------------------
// Safe wrappers.

/// An open HEIF file: its bytes (which libheif reads without a copy) and libheif's context.
pub struct HeifFile<'p> {
    api: &'static Api,
    path: &'p Path,
    ctx: *mut Context,
    /// Each item's clean aperture, read from the container.
    claps: Vec<(u32, Clap)>,
    // Declared after `ctx`, freed after it in `Drop` (the context reads these bytes).
    _bytes: Vec<u8>,
}

impl Drop for HeifFile<'_> {
    fn drop(&mut self) {
        // SAFETY: allocated by heif_context_alloc, freed once; handles borrow `self` so none
        // outlives it.
        unsafe { (self.api.context_free)(self.ctx) }
    }
}

/// An image of a file (the primary image, a depth image, an auxiliary image).
pub struct ImageHandle<'f> {
    file: &'f HeifFile<'f>,
    raw: *mut Handle,
    /// Its item id.
    id: u32,
}

impl Drop for ImageHandle<'_> {
    fn drop(&mut self) {
        // SAFETY: a handle libheif gave out, released once.
        unsafe { (self.file.api.handle_release)(self.raw) }
    }
}

/// A decoded image: released when dropped.
struct Decoded<'f> {
    api: &'static Api,
    raw: *mut Picture,
    _file: std::marker::PhantomData<&'f ()>,
}

impl Drop for Decoded<'_> {
    fn drop(&mut self) {
        // SAFETY: an image heif_decode_image gave out, released once.
        unsafe { (self.api.picture_release)(self.raw) }
    }
}

impl<'p> HeifFile<'p> {
    /// Reads and parses `path` (the whole file into memory). Errors: no libheif, the file
    /// cannot be read, libheif rejects it.
    pub fn open(path: &'p Path) -> Result<HeifFile<'p>> {
        let api = api().map_err(|m| Error::input(path, m))?;
        let bytes = super::format::read_input(path)?;
        // SAFETY: a fresh context; freed by Drop (also on the error return below).
        let ctx = unsafe { (api.context_alloc)() };
        if ctx.is_null() {
            return Err(Error::Internal("libheif could not allocate a context".into()));
        }
        let claps = clean_apertures(&bytes);
        let file = HeifFile { api, path, ctx, claps, _bytes: bytes };
        // SAFETY: the bytes live as long as the context (same struct, freed after it).
        let e = unsafe { (api.read_from_memory)(ctx, file._bytes.as_ptr().cast(), file._bytes.len(), std::ptr::null()) };
        file.check(e, "cannot read the HEIF file")?;
        Ok(file)
    }

    /// `Ok` when `e` is libheif's success, else an input error: "`what`: libheif's message".
    fn check(&self, e: HeifError, what: &str) -> Result<()> {
        if e.code == 0 { Ok(()) } else { Err(Error::input(self.path, format!("{what}: {} (libheif)", message(&e)))) }
    }

    /// The primary image (the photo).
    pub fn primary(&self) -> Result<ImageHandle<'_>> {
        let (mut raw, mut id) = (std::ptr::null_mut(), 0u32);
        // SAFETY: a live context.
        let e = unsafe { (self.api.primary_id)(self.ctx, &mut id) };
        self.check(e, "the HEIF file has no primary image")?;
        // SAFETY: a live context; the handle is released by ImageHandle's Drop.
        let e = unsafe { (self.api.primary_handle)(self.ctx, &mut raw) };
        self.check(e, "the HEIF file has no primary image")?;
        Ok(ImageHandle { file: self, raw, id })
    }
}

/// An image's depth representation (ISO/IEC 23002-3, as libheif reports it from the depth
/// image's `auxC` property).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Representation {
    /// 0 uniform inverse Z, 1 uniform disparity, 2 uniform Z, 3 non-uniform disparity.
    pub kind: i32,
    /// Nearest and farthest depth (for the Z kinds), when given.
    pub z_near: Option<f64>,
    /// See `z_near`.
    pub z_far: Option<f64>,
    /// Smallest and largest disparity (for the disparity kinds), when given.
    pub d_min: Option<f64>,
    /// See `d_min`.
    pub d_max: Option<f64>,
    /// The view the disparity refers to.
    pub disparity_reference_view: u32,
}

/// A one-channel image decoded from an auxiliary image: values in [0, 1].
pub struct GreyPlane {
    /// One channel, `q / (2^bits − 1)`.
    pub image: crate::image::Image,
    /// Bits per sample in the file.
    pub bits: u8,
}

impl<'f> ImageHandle<'f> {
    /// Width and height in stored orientation after the crop (see the module doc): the `ispe`
    /// property cropped by `clap`, else libheif's size when no `ispe` is given.
    pub fn size(&self) -> (usize, usize) {
        let (w, h) = self.coded_size();
        match self.crop(w, h) {
            Some(c) => (c.width, c.height),
            None => (w, h),
        }
    }

    /// Width and height before the crop.
    fn coded_size(&self) -> (usize, usize) {
        let api = self.file.api;
        // SAFETY: a live handle.
        let (w, h) = unsafe { ((api.handle_ispe_width)(self.raw), (api.handle_ispe_height)(self.raw)) };
        let (w, h) = if w > 0 && h > 0 { (w, h) } else { unsafe { ((api.handle_width)(self.raw), (api.handle_height)(self.raw)) } };
        (w.max(0) as usize, h.max(0) as usize)
    }

    /// The image's crop of a `w` x `h` picture, if its item has a valid clean aperture (an
    /// invalid one, which libheif would refuse on display, is not applied).
    fn crop(&self, w: usize, h: usize) -> Option<Crop> {
        self.file.claps.iter().find(|(id, _)| *id == self.id).and_then(|(_, c)| c.crop(w, h))
    }

    /// Bits per luma sample (8 for most phones, 10 for HDR), or `None` when not stated.
    pub fn luma_bits(&self) -> Option<u8> {
        // SAFETY: a live handle.
        let b = unsafe { (self.file.api.handle_luma_bits)(self.raw) };
        (1..=16).contains(&b).then_some(b as u8)
    }

    /// True when the image has an alpha channel.
    pub fn has_alpha(&self) -> bool {
        // SAFETY: a live handle.
        unsafe { (self.file.api.handle_has_alpha)(self.raw) != 0 }
    }

    /// The ids of the image's depth images (usually none or one).
    pub fn depth_ids(&self) -> Vec<u32> {
        let api = self.file.api;
        // SAFETY: a live handle; the list is written into a buffer of the count asked for.
        unsafe {
            let n = (api.depth_count)(self.raw).max(0);
            let mut ids = vec![0u32; n as usize];
            let got = (api.depth_ids)(self.raw, ids.as_mut_ptr(), n).clamp(0, n);
            ids.truncate(got as usize);
            ids
        }
    }

    /// The depth image `id` of this (primary) image.
    pub fn depth_image(&self, id: u32) -> Result<ImageHandle<'f>> {
        let mut raw = std::ptr::null_mut();
        // SAFETY: a live handle; the new one is released by its Drop.
        let e = unsafe { (self.file.api.depth_handle)(self.raw, id, &mut raw) };
        self.file.check(e, &format!("cannot open the depth image (item {id})"))?;
        Ok(ImageHandle { file: self.file, raw, id })
    }

    /// The depth representation of this (primary) image's depth image `id`, if the file
    /// states one.
    pub fn depth_representation(&self, id: u32) -> Option<Representation> {
        let api = self.file.api;
        let mut info: *const DepthRepresentation = std::ptr::null();
        // SAFETY: a live handle; the info is freed below with libheif's own call.
        unsafe {
            if (api.depth_representation)(self.raw, id, &mut info) == 0 || info.is_null() {
                return None;
            }
            let i = &*info;
            let opt = |has: u8, v: f64| (has != 0).then_some(v);
            let r = Representation {
                kind: i.representation_type,
                z_near: opt(i.has_z_near, i.z_near),
                z_far: opt(i.has_z_far, i.z_far),
                d_min: opt(i.has_d_min, i.d_min),
                d_max: opt(i.has_d_max, i.d_max),
                disparity_reference_view: i.disparity_reference_view,
            };
            (api.depth_representation_free)(info);
            Some(r)
        }
    }

    /// The auxiliary images other than alpha and depth: (id, type URN).
    pub fn auxiliary(&self) -> Result<Vec<(u32, String)>> {
        let api = self.file.api;
        let ids = {
            // SAFETY: a live handle; the list is written into a buffer of the count asked for.
            unsafe {
                let n = (api.aux_count)(self.raw, AUX_OMIT_ALPHA_AND_DEPTH).max(0);
                let mut ids = vec![0u32; n as usize];
                let got = (api.aux_ids)(self.raw, AUX_OMIT_ALPHA_AND_DEPTH, ids.as_mut_ptr(), n).clamp(0, n);
                ids.truncate(got as usize);
                ids
            }
        };
        let mut out = Vec::with_capacity(ids.len());
        for id in ids {
            let aux = self.auxiliary_image(id)?;
            let mut t: *const c_char = std::ptr::null();
            // SAFETY: a live handle; the string is freed with libheif's own call.
            let e = unsafe { (api.aux_type)(aux.raw, &mut t) };
            self.file.check(e, &format!("cannot read the type of auxiliary image {id}"))?;
            let urn = if t.is_null() { String::new() } else { unsafe { CStr::from_ptr(t) }.to_string_lossy().into_owned() };
            unsafe { (api.aux_type_free)(aux.raw, &mut t) };
            out.push((id, urn));
        }
        Ok(out)
    }

    /// The auxiliary image `id` of this image.
    pub fn auxiliary_image(&self, id: u32) -> Result<ImageHandle<'f>> {
        let mut raw = std::ptr::null_mut();
        // SAFETY: a live handle; the new one is released by its Drop.
        let e = unsafe { (self.file.api.aux_handle)(self.raw, id, &mut raw) };
        self.file.check(e, &format!("cannot open auxiliary image {id}"))?;
        Ok(ImageHandle { file: self.file, raw, id })
    }

    /// Decodes into `colorspace`/`chroma`, transformations not applied, after checking the
    /// size against `limits`; `what` names the image in errors.
    fn decode(&self, colorspace: c_int, chroma: c_int, limits: &ReadLimits, what: &str) -> Result<Decoded<'f>> {
        let (w, h) = self.size();
        limits.check(self.file.path, w as u64, h as u64).map_err(|e| e.within(what))?;
        let api = self.file.api;
        let mut raw = std::ptr::null_mut();
        // SAFETY: the options struct is libheif's own (so its version matches), freed after the
        // call; the byte set is `ignore_transformations`, present in every version.
        let e = unsafe {
            let options = (api.options_alloc)();
            if !options.is_null() {
                *options.add(OPTION_IGNORE_TRANSFORMATIONS) = 1;
            }
            let e = (api.decode)(self.raw, &mut raw, colorspace, chroma, options);
            if !options.is_null() {
                (api.options_free)(options);
            }
            e
        };
        self.file.check(e, &format!("cannot decode {what}"))?;
        Ok(Decoded { api, raw, _file: std::marker::PhantomData })
    }

    /// Decodes the image as interleaved RGB (see the module doc): its width, height, samples
    /// (8-bit, or scaled to [0, 1] for deeper files) and bits per sample.
    pub fn decode_rgb(&self, limits: &ReadLimits) -> Result<(usize, usize, Rgb, u8)> {
        let deep = self.luma_bits().is_some_and(|b| b > 8);
        let chroma = if deep { CHROMA_INTERLEAVED_RRGGBB_LE } else { CHROMA_INTERLEAVED_RGB };
        let d = self.decode(COLORSPACE_RGB, chroma, limits, "the primary image")?;
        let (plane, bits) = d.plane(self.file.path, CHANNEL_INTERLEAVED, "the primary image")?;
        let c = self.crop(plane.width, plane.height).unwrap_or(Crop::whole(plane.width, plane.height));
        let rgb = if deep {
            let m = ((1u32 << bits) - 1) as f32;
            let mut v = Vec::with_capacity(c.width * c.height * 3);
            for r in plane.rows(&c, 6) {
                v.extend(r.as_chunks::<2>().0.iter().map(|q| u16::from_le_bytes(*q) as f32 / m));
            }
            Rgb::Scaled(v)
        } else {
            let mut v = Vec::with_capacity(c.width * c.height * 3);
            for r in plane.rows(&c, 3) {
                v.extend_from_slice(r);
            }
            Rgb::U8(v)
        };
        Ok((c.width, c.height, rgb, bits))
    }

    /// Decodes the image as one grey channel in [0, 1]; `what` names it in errors.
    pub fn decode_grey(&self, limits: &ReadLimits, what: &str) -> Result<GreyPlane> {
        let d = self.decode(COLORSPACE_MONOCHROME, CHROMA_MONOCHROME, limits, what)?;
        let (plane, bits) = d.plane(self.file.path, CHANNEL_Y, what)?;
        let c = self.crop(plane.width, plane.height).unwrap_or(Crop::whole(plane.width, plane.height));
        let m = ((1u32 << bits) - 1) as f32;
        let mut v = Vec::with_capacity(c.width * c.height);
        for r in plane.rows(&c, if bits > 8 { 2 } else { 1 }) {
            if bits > 8 {
                v.extend(r.as_chunks::<2>().0.iter().map(|q| u16::from_ne_bytes(*q) as f32 / m));
            } else {
                v.extend(r.iter().map(|&q| q as f32 / m));
            }
        }
        let image = crate::image::Image::from_vec(c.width, c.height, 1, v).ok_or_else(|| Error::Internal("libheif plane size".into()))?;
        Ok(GreyPlane { image, bits })
    }
}

/// The primary image's samples.
pub enum Rgb {
    /// 8-bit, interleaved RGB.
    U8(Vec<u8>),
    /// Deeper files, scaled to [0, 1].
    Scaled(Vec<f32>),
}

/// A decoded plane: `height` rows of `stride` bytes.
struct Plane<'a> {
    width: usize,
    height: usize,
    stride: usize,
    bytes: &'a [u8],
}

impl<'a> Plane<'a> {
    /// The rows of `crop`, each its `crop.width * bytes_per_pixel` bytes.
    fn rows(&self, crop: &Crop, bytes_per_pixel: usize) -> impl Iterator<Item = &'a [u8]> {
        let (x0, x1) = (crop.left * bytes_per_pixel, (crop.left + crop.width) * bytes_per_pixel);
        let bytes = self.bytes;
        let stride = self.stride;
        (crop.top..crop.top + crop.height).map(move |y| &bytes[y * stride + x0..y * stride + x1])
    }
}

impl Decoded<'_> {
    /// The plane `channel` and its bits per sample, checked for a size libheif's own header
    /// promised.
    fn plane(&self, path: &Path, channel: c_int, what: &str) -> Result<(Plane<'_>, u8)> {
        let mut stride: c_int = 0;
        // SAFETY: a live image; the plane it returns lives as long as the image (`&self`).
        let (w, h, bits, ptr) = unsafe {
            (
                (self.api.picture_width)(self.raw, channel),
                (self.api.picture_height)(self.raw, channel),
                (self.api.picture_bits)(self.raw, channel),
                (self.api.plane)(self.raw, channel, &mut stride),
            )
        };
        let bad = ptr.is_null() || w <= 0 || h <= 0 || !(1..=16).contains(&bits) || stride <= 0;
        let bytes_per_sample = if bits > 8 { 2 } else { 1 };
        let samples = if channel == CHANNEL_INTERLEAVED { 3 } else { 1 };
        if bad || (stride as usize) < w as usize * bytes_per_sample * samples {
            return Err(Error::input(path, format!("{what}: libheif decoded no usable pixels ({w}x{h}, {bits}-bit, stride {stride})")));
        }
        // SAFETY: libheif's plane is `stride * height` bytes.
        let bytes = unsafe { std::slice::from_raw_parts(ptr, stride as usize * h as usize) };
        Ok((Plane { width: w as usize, height: h as usize, stride: stride as usize, bytes }, bits as u8))
    }
}

// ---------------------------------------------------------------------------------------------
// The clean aperture, read from the container (ISO/IEC 14496-12 boxes, ISO/IEC 23008-12 items).

/// A `clap` property: the crop's size and its centre's offset from the picture's centre, each
/// a fraction (numerator, denominator).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Clap {
    width: (u32, u32),
    height: (u32, u32),
    horizontal_offset: (i32, u32),
    vertical_offset: (i32, u32),
}

/// A rectangle of a picture, pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Crop {
    left: usize,
    top: usize,
    width: usize,
    height: usize,
}

impl Crop {
    fn whole(width: usize, height: usize) -> Crop {
        Crop { left: 0, top: 0, width, height }
    }
}

impl Clap {
    /// The crop of a `w` x `h` picture: centre at `offset + (size − 1)/2`, edges at the centre
    /// ∓ (crop size − 1)/2, rounded; `None` when a denominator is 0 or the crop leaves the
    /// picture.
    fn crop(&self, w: usize, h: usize) -> Option<Crop> {
        let frac = |(n, d): (i64, u32)| (d != 0).then(|| n as f64 / d as f64);
        let axis = |size: (u32, u32), offset: (i32, u32), full: usize| -> Option<(usize, usize)> {
            let (s, o) = (frac((size.0 as i64, size.1))?, frac((offset.0 as i64, offset.1))?);
            let centre = o + (full as f64 - 1.0) / 2.0;
            let (a, b) = ((centre - (s - 1.0) / 2.0).round(), (centre + (s - 1.0) / 2.0).round());
            (a >= 0.0 && b >= a && b < full as f64).then_some((a as usize, (b - a) as usize + 1))
        };
        let (left, width) = axis(self.width, self.horizontal_offset, w)?;
        let (top, height) = axis(self.height, self.vertical_offset, h)?;
        Some(Crop { left, top, width, height })
    }
}

/// The boxes of `b`: (type, payload). Stops at the first malformed header (libheif has
/// already checked the structure; this reader only looks for properties).
fn boxes(mut b: &[u8]) -> Vec<([u8; 4], &[u8])> {
    let mut out = Vec::new();
    while b.len() >= 8 {
        let size = u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as u64;
        let kind = [b[4], b[5], b[6], b[7]];
        let (head, size) = match size {
            0 => (8, b.len() as u64),
            1 if b.len() >= 16 => (16, u64::from_be_bytes(b[8..16].try_into().expect("8 bytes"))),
            _ => (8, size),
        };
        if size < head as u64 || size > b.len() as u64 {
            break;
        }
        out.push((kind, &b[head..size as usize]));
        b = &b[size as usize..];
    }
    out
}

/// The payload of the first box of type `k` in `bs`.
fn find<'a>(bs: &[([u8; 4], &'a [u8])], k: &[u8; 4]) -> Option<&'a [u8]> {
    bs.iter().find(|(kind, _)| kind == k).map(|(_, p)| *p)
}

/// Every item's `clap` property: (item id, clean aperture). Empty when the file has none or
/// its boxes cannot be followed.
fn clean_apertures(file: &[u8]) -> Vec<(u32, Clap)> {
    let top = boxes(file);
    let Some(meta) = find(&top, b"meta").filter(|m| m.len() >= 4) else { return Vec::new() };
    let meta = boxes(&meta[4..]);
    let Some(iprp) = find(&meta, b"iprp") else { return Vec::new() };
    let iprp = boxes(iprp);
    let (Some(ipco), Some(ipma)) = (find(&iprp, b"ipco"), find(&iprp, b"ipma")) else { return Vec::new() };
    let properties = boxes(ipco);
    let mut out = Vec::new();
    for (item, index) in associations(ipma) {
        let Some((kind, p)) = index.checked_sub(1).and_then(|i| properties.get(i)) else { continue };
        if kind != b"clap" || p.len() < 32 {
            continue;
        }
        let w = |i: usize| u32::from_be_bytes(p[i * 4..i * 4 + 4].try_into().expect("4 bytes"));
        let clap = Clap {
            width: (w(0), w(1)),
            height: (w(2), w(3)),
            horizontal_offset: (w(4) as i32, w(5)),
            vertical_offset: (w(6) as i32, w(7)),
        };
        out.push((item, clap));
    }
    out
}

/// The (item id, 1-based property index) pairs of an `ipma` box's payload; stops where it is
/// cut short.
fn associations(p: &[u8]) -> Vec<(u32, usize)> {
    let mut out = Vec::new();
    if p.len() < 8 {
        return out;
    }
    let (version, wide) = (p[0], p[3] & 1 == 1);
    let count = u32::from_be_bytes([p[4], p[5], p[6], p[7]]);
    let mut at = 8;
    let mut take = |n: usize| -> Option<u32> {
        let v = p.get(at..at + n)?.iter().fold(0u32, |a, &b| (a << 8) | b as u32);
        at += n;
        Some(v)
    };
    for _ in 0..count {
        let Some(item) = take(if version < 1 { 2 } else { 4 }) else { break };
        let Some(n) = take(1) else { break };
        for _ in 0..n {
            let Some(a) = take(if wide { 2 } else { 1 }) else { return out };
            let index = if wide { a & 0x7FFF } else { a & 0x7F };
            out.push((item, index as usize));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clean_aperture_crops() {
        // libheif's padding of a 48 x 32 picture coded as 64 x 64: the top-left 48 x 32.
        let c = Clap { width: (48, 1), height: (32, 1), horizontal_offset: (-16, 2), vertical_offset: (-32, 2) };
        assert_eq!(c.crop(64, 64), Some(Crop { left: 0, top: 0, width: 48, height: 32 }));
        // Centred.
        let c = Clap { width: (10, 1), height: (6, 1), horizontal_offset: (0, 1), vertical_offset: (0, 1) };
        assert_eq!(c.crop(20, 10), Some(Crop { left: 5, top: 2, width: 10, height: 6 }));
        // Outside the picture, or a zero denominator: no crop.
        let c = Clap { width: (30, 1), height: (6, 1), horizontal_offset: (0, 1), vertical_offset: (0, 1) };
        assert_eq!(c.crop(20, 10), None);
        let c = Clap { width: (10, 0), height: (6, 1), horizontal_offset: (0, 1), vertical_offset: (0, 1) };
        assert_eq!(c.crop(20, 10), None);
    }

    #[test]
    fn box_walk_survives_damage() {
        // A meta box whose iprp is cut anywhere: never a panic.
        let clap: Vec<u8> = [48u32, 1, 32, 1, (-16i32) as u32, 2, (-32i32) as u32, 2].iter().flat_map(|v| v.to_be_bytes()).collect();
        let bx = |k: &[u8; 4], p: &[u8]| [&(8 + p.len() as u32).to_be_bytes()[..], k, p].concat();
        let ipco = bx(b"ipco", &bx(b"clap", &clap));
        let ipma = bx(b"ipma", &[0, 0, 0, 0, 0, 0, 0, 1, 0, 7, 1, 0x81]);
        let meta = bx(b"meta", &[&[0u8, 0, 0, 0][..], &bx(b"iprp", &[ipco, ipma].concat())].concat());
        let found = clean_apertures(&meta);
        assert_eq!(found.len(), 1);
        assert_eq!(found[0].0, 7);
        for cut in 0..meta.len() {
            let _ = clean_apertures(&meta[..cut]);
        }
    }
}
