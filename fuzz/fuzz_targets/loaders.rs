//! The file loaders (photo, depth, matte, layer, the photo's embedded GDepth map) on arbitrary bytes under each extension.
//! The first byte picks the extension; the rest is the file. The loaders take paths, so the
//! bytes go to a per-process file in /dev/shm (or the temp folder).
#![no_main]
use drbokeh::color::Transfer;
use drbokeh::io::{read_depth, read_layer, read_matte, read_photo, ReadLimits};
use libfuzzer_sys::fuzz_target;

const EXTS: [&str; 6] = ["png", "jpg", "tif", "exr", "npy", "bin"];

fuzz_target!(|data: &[u8]| {
    let Some((&sel, body)) = data.split_first() else { return };
    let ext = EXTS[sel as usize % EXTS.len()];
    let dir = if std::path::Path::new("/dev/shm").is_dir() { std::path::PathBuf::from("/dev/shm") } else { std::env::temp_dir() };
    let path = dir.join(format!("drbokeh-fuzz-{}.{ext}", std::process::id()));
    if std::fs::write(&path, body).is_err() {
        return;
    }
    let limits = ReadLimits { max_pixels: 1 << 22 };
    let _ = read_photo(&path, Transfer::Srgb, &limits);
    let _ = read_depth(&path, &limits);
    let _ = read_matte(&path, &limits);
    let _ = read_layer(&path, &limits);
    let _ = drbokeh::io::embedded_depth::read_gdepth(&path, &limits);
});
