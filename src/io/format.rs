//! Input format detection and the shared plumbing of every reader: opening files with a plain
//! error (regular files only: see [`check_regular_file`]), and running third-party decoders
//! behind a panic guard.
//!
//! Detection looks at the file's first bytes (magic numbers) first and falls back to the
//! extension only when the content is not recognised, so a PNG saved as `depth.tif` still reads,
//! and garbage named `photo.png` is reported as a corrupt PNG.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

/// The input formats the readers understand.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FileFormat {
    /// PNG: grey or RGB, optional alpha, up to 16 bits.
    Png,
    /// JPEG, 8 bits.
    Jpeg,
    /// TIFF: 8/16/32-bit unsigned or 16/32/64-bit float samples.
    Tiff,
    /// OpenEXR: half or float channels, linear.
    Exr,
    /// NumPy `.npy`: float32, float64, uint8 or uint16, H x W or H x W x C.
    Npy,
    /// HEIF: HEIC photos (HEVC), AVIF; 8 to 12 bits, read through libheif ([`super::heif`]).
    Heif,
}

/// ISO BMFF major brands of HEIF still images (HEVC: heic/heix/heim/heis, mif1/msf1 generic,
/// image sequences hevc/hevx, AVIF avif/avis).
const HEIF_BRANDS: [&[u8; 4]; 11] = [b"heic", b"heix", b"heim", b"heis", b"hevc", b"hevx", b"hevm", b"mif1", b"msf1", b"avif", b"avis"];

/// Extensions accepted for input, as listed in error messages.
pub const SUPPORTED_INPUT_EXTENSIONS: &str = ".png, .jpg/.jpeg, .tif/.tiff, .exr, .npy, .heic/.heif/.avif (with libheif)";

impl FileFormat {
    /// Human name used in messages ("PNG", "OpenEXR"...).
    pub fn name(self) -> &'static str {
        match self {
            FileFormat::Png => "PNG",
            FileFormat::Jpeg => "JPEG",
            FileFormat::Tiff => "TIFF",
            FileFormat::Exr => "EXR",
            FileFormat::Npy => "NPY",
            FileFormat::Heif => "HEIF",
        }
    }

    /// Recognises the format from the first bytes of a file.
    pub fn from_magic(head: &[u8]) -> Option<FileFormat> {
        if head.starts_with(b"\x89PNG\r\n\x1a\n") {
            Some(FileFormat::Png)
        } else if head.starts_with(&[0xFF, 0xD8, 0xFF]) {
            Some(FileFormat::Jpeg)
        } else if head.starts_with(b"II*\0") || head.starts_with(b"MM\0*") || head.starts_with(b"II+\0") || head.starts_with(b"MM\0+") {
            Some(FileFormat::Tiff)
        } else if head.starts_with(&[0x76, 0x2F, 0x31, 0x01]) {
            Some(FileFormat::Exr)
        } else if head.starts_with(b"\x93NUMPY") {
            Some(FileFormat::Npy)
        } else if head.len() >= 12 && &head[4..8] == b"ftyp" && HEIF_BRANDS.iter().any(|b| &head[8..12] == *b) {
            Some(FileFormat::Heif)
        } else {
            None
        }
    }

    /// Recognises the format from the file extension (case-insensitive).
    pub fn from_extension(path: &Path) -> Option<FileFormat> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        match ext.as_str() {
            "png" => Some(FileFormat::Png),
            "jpg" | "jpeg" | "jpe" => Some(FileFormat::Jpeg),
            "tif" | "tiff" => Some(FileFormat::Tiff),
            "exr" => Some(FileFormat::Exr),
            "npy" => Some(FileFormat::Npy),
            "heic" | "heif" | "hif" | "avif" => Some(FileFormat::Heif),
            _ => None,
        }
    }
}

/// Detects the format of `path`: by content first, by extension second.
///
/// Errors: the file cannot be opened or read, is empty, or is neither recognisable by content
/// nor by extension (the message lists the supported extensions, and names the format when
/// it is a known but unsupported one such as WebP or BMP).
pub fn detect_format(path: &Path) -> Result<FileFormat> {
    let mut head = [0u8; 16];
    let n = {
        let mut f = open(path)?;
        let mut n = 0;
        while n < head.len() {
            match f.read(&mut head[n..]) {
                Ok(0) => break,
                Ok(k) => n += k,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(read_error(path, e)),
            }
        }
        n
    };
    if n == 0 {
        return Err(Error::input(path, "file is empty (0 bytes)"));
    }
    let head = &head[..n];
    if let Some(f) = FileFormat::from_magic(head) {
        return Ok(f);
    }
    if let Some(f) = FileFormat::from_extension(path) {
        return Ok(f);
    }
    let known = image::guess_format(head).ok().map(|f| format!("{f:?} files are not supported; "));
    Err(Error::input(
        path,
        format!("unrecognised file format ({}supported formats: {SUPPORTED_INPUT_EXTENSIONS})", known.unwrap_or_default()),
    ))
}

/// Wraps an I/O error from reading `path` so that the message says what failed:
/// "<path>: cannot read file: No such file or directory (os error 2)".
pub(crate) fn read_error(path: &Path, e: std::io::Error) -> Error {
    Error::io(path, std::io::Error::new(e.kind(), format!("cannot read file: {e}")))
}

/// Refuses anything but a regular file (or a symlink to one) before it is opened: a folder, a
/// FIFO, a socket or a device. Opening a FIFO for reading blocks until a writer appears, and
/// reading a character device such as `/dev/stdin` or `/dev/zero` may block or never end, so
/// the check looks at the metadata (`stat`, which never blocks) and runs before `open`. (A file
/// swapped for a FIFO between the check and the open would still block: that takes a hostile
/// local user, not a mistake.)
///
/// Every input goes through here: images, depth maps, mattes and layers via [`open`] and
/// [`read_input`], configs, manifests and models via [`read_input_text`] / [`read_input`].
pub fn check_regular_file(path: &Path) -> Result<()> {
    let meta = std::fs::metadata(path).map_err(|e| read_error(path, e))?;
    if meta.is_file() {
        return Ok(());
    }
    let kind = file_kind(&meta.file_type());
    Err(Error::input(path, format!("cannot read file: it is {kind}, not a regular file")))
}

/// "a folder", "a FIFO (named pipe)"... for [`check_regular_file`]'s message.
fn file_kind(t: &std::fs::FileType) -> &'static str {
    if t.is_dir() {
        return "a folder";
    }
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if t.is_fifo() {
            return "a FIFO (named pipe)";
        } else if t.is_char_device() {
            return "a character device";
        } else if t.is_block_device() {
            return "a block device";
        } else if t.is_socket() {
            return "a socket";
        }
    }
    "a special file"
}

/// Opens `path` for buffered reading after [`check_regular_file`].
pub(crate) fn open(path: &Path) -> Result<BufReader<File>> {
    check_regular_file(path)?;
    let file = File::open(path).map_err(|e| read_error(path, e))?;
    Ok(BufReader::new(file))
}

/// Reads the whole of `path` after [`check_regular_file`]. Allocates the file's size.
pub fn read_input(path: &Path) -> Result<Vec<u8>> {
    check_regular_file(path)?;
    std::fs::read(path).map_err(|e| read_error(path, e))
}

/// Reads the whole of the text file `path` (a config, a manifest) after [`check_regular_file`].
pub fn read_input_text(path: &Path) -> Result<String> {
    check_regular_file(path)?;
    std::fs::read_to_string(path).map_err(|e| read_error(path, e))
}

/// Runs a third-party decoder call behind `catch_unwind`.
///
/// Defence in depth: the image, tiff and exr decoders are meant to return errors on malformed
/// input, but fuzzing has found panics in such crates before. A panic while decoding `path`
/// becomes an [`Error::Input`] ("decoder failed on malformed data") instead of tearing the
/// process down. (The default panic hook still prints the panic message to stderr.) Decoders
/// must run on the calling thread or in rayon jobs it joins (rayon resumes a job's panic on
/// the joining thread): a decoder's own thread pool would escape the guard (the `exr` crate's
/// parallel reader aborts the process on a panic), which is why EXR chunks are decompressed in
/// rayon jobs of ours.
pub(crate) fn guarded<T>(path: &Path, format: FileFormat, f: impl FnOnce() -> Result<T>) -> Result<T> {
    match std::panic::catch_unwind(std::panic::AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(payload) => {
            let detail = payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(Error::input(path, format!("{} decoder failed on malformed data (decoder panicked: {detail})", format.name())))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A panic in a rayon job under the guard becomes an input error, as one on the calling
    /// thread does (the EXR reader decompresses in such jobs).
    #[test]
    fn guard_catches_a_panic_in_a_rayon_job() {
        use rayon::prelude::*;
        let e = guarded(Path::new("x.exr"), FileFormat::Exr, || {
            (0..64).into_par_iter().for_each(|i| assert!(i != 37, "bad block {i}"));
            Ok(())
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("x.exr") && e.contains("decoder failed") && e.contains("bad block 37"), "{e}");
    }

    #[test]
    fn magic_and_extension() {
        assert_eq!(FileFormat::from_magic(b"\x89PNG\r\n\x1a\n...."), Some(FileFormat::Png));
        assert_eq!(FileFormat::from_magic(&[0xFF, 0xD8, 0xFF, 0xE0]), Some(FileFormat::Jpeg));
        assert_eq!(FileFormat::from_magic(b"II*\0"), Some(FileFormat::Tiff));
        assert_eq!(FileFormat::from_magic(b"MM\0*"), Some(FileFormat::Tiff));
        assert_eq!(FileFormat::from_magic(&[0x76, 0x2F, 0x31, 0x01, 2]), Some(FileFormat::Exr));
        assert_eq!(FileFormat::from_magic(b"\x93NUMPY\x01\x00"), Some(FileFormat::Npy));
        assert_eq!(FileFormat::from_magic(b"hello"), None);
        assert_eq!(FileFormat::from_magic(b"\0\0\0\x18ftypheic\0\0\0\0"), Some(FileFormat::Heif));
        assert_eq!(FileFormat::from_magic(b"\0\0\0\x18ftypmif1\0\0\0\0"), Some(FileFormat::Heif));
        assert_eq!(FileFormat::from_magic(b"\0\0\0\x18ftypisom\0\0\0\0"), None, "an MP4 is not a HEIF image");
        assert_eq!(FileFormat::from_extension(Path::new("IMG_0001.HEIC")), Some(FileFormat::Heif));
        assert_eq!(FileFormat::from_extension(Path::new("a/B.TIFF")), Some(FileFormat::Tiff));
        assert_eq!(FileFormat::from_extension(Path::new("a.JPEG")), Some(FileFormat::Jpeg));
        assert_eq!(FileFormat::from_extension(Path::new("a.bmp")), None);
        assert_eq!(FileFormat::from_extension(Path::new("noext")), None);
    }

    #[test]
    fn guard_turns_panic_into_error() {
        let r: Result<()> = guarded(Path::new("bad.exr"), FileFormat::Exr, || panic!("boom"));
        let msg = r.unwrap_err().to_string();
        assert!(msg.contains("bad.exr") && msg.contains("malformed data") && msg.contains("boom"), "{msg}");
    }
}
