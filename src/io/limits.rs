//! Resource limits for reading untrusted files.
//!
//! Every reader checks the dimensions stated in a file's header against [`ReadLimits`] before
//! it allocates pixel memory, so a small file that claims to be 100000 x 100000 pixels (a
//! "decompression bomb") is refused in microseconds instead of exhausting memory.

use crate::error::{Error, Result};
use std::path::Path;

/// Limits applied while decoding input files.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReadLimits {
    /// Largest accepted `width * height` of one image (all channels together count once).
    pub max_pixels: u64,
}

impl ReadLimits {
    /// The default limit: 200 million pixels (e.g. 16000 x 12500).
    pub const DEFAULT_MAX_PIXELS: u64 = 200_000_000;

    /// Limits of at most `max_pixels` pixels per image.
    pub fn new(max_pixels: u64) -> Self {
        ReadLimits { max_pixels }
    }

    /// No limit at all; only for trusted input.
    pub fn unlimited() -> Self {
        ReadLimits { max_pixels: u64::MAX }
    }

    /// Refuses a zero-sized image or one above the pixel limit. Call this with the header's
    /// dimensions before allocating anything proportional to them.
    pub fn check(&self, path: &Path, width: u64, height: u64) -> Result<()> {
        if width == 0 || height == 0 {
            return Err(Error::input(path, format!("image is empty ({width}x{height} pixels)")));
        }
        let pixels = width.saturating_mul(height);
        if pixels > self.max_pixels {
            return Err(Error::input(
                path,
                format!(
                    "image is {width}x{height} = {pixels} pixels, above the limit of {} pixels \
                     (refused before decoding; raise the pixel limit if the file is trusted)",
                    self.max_pixels
                ),
            ));
        }
        Ok(())
    }

    /// Byte budget handed to third-party decoders as a second line of defence: the largest
    /// pixel count times 16 bytes (four 32-bit channels), plus 64 MiB of working memory.
    pub(crate) fn alloc_budget(&self) -> u64 {
        self.max_pixels.saturating_mul(16).saturating_add(64 << 20)
    }
}

impl Default for ReadLimits {
    fn default() -> Self {
        ReadLimits { max_pixels: Self::DEFAULT_MAX_PIXELS }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_refuses_empty_and_large() {
        let l = ReadLimits::new(100);
        let p = Path::new("x.png");
        assert!(l.check(p, 10, 10).is_ok());
        assert!(l.check(p, 0, 10).unwrap_err().to_string().contains("empty"));
        let e = l.check(p, 11, 10).unwrap_err().to_string();
        assert!(e.contains("limit of 100 pixels") && e.contains("x.png"), "{e}");
        assert!(ReadLimits::unlimited().check(p, u64::MAX, u64::MAX).is_ok());
    }
}
