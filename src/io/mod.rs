//! Reading and writing images, depth maps, mattes and layers.
//!
//! One file per concern: [`format`] (detection by magic bytes then extension, panic guard),
//! [`limits`] (decompression-bomb limits), [`image_file`] (photos and generic rasters; a PNG
//! photo decoded row by row in `png_rows`; PNG encoded in parallel in `png_encode`),
//! [`tiff_file`], [`exr_file`], [`npy`], [`depth`], [`matte`], [`layer`], [`write`] and
//! [`atomic`] (temp file + rename), [`guard`] (no write may hit a file the run reads),
//! [`xmp`] (a JPEG's XMP packets), [`embedded`] (the depth map inside a photo, by format:
//! [`gdepth`], [`dynamic_depth`], [`heif_depth`]; what they share in [`embedded_depth`]), [`heif`] (HEIC photos through libheif, loaded at run
//! time; [`heif_depth`] also reads a HEIC's portrait matte).
//!
//! Every error names the file and says what is wrong. Only regular files are opened (a FIFO
//! or a device would block: [`check_regular_file`]), and a truncated file is an error in every
//! format. What is usable but doubtful (an 8-bit depth map, layer alpha outside [0, 1]) comes
//! back as warnings next to the data ([`DepthMap::warnings`], [`LayerFile::warnings`]) for the
//! caller to show. Untrusted input never makes the
//! readers panic or allocate beyond [`ReadLimits`]: header dimensions are checked before
//! decoding, and third-party decoders run behind `catch_unwind` as defence in depth.

pub mod atomic;
pub mod depth;
pub mod dynamic_depth;
pub mod embedded;
pub mod embedded_depth;
pub mod exr_file;
pub mod format;
pub mod gdepth;
pub mod guard;
pub mod heif;
pub mod heif_depth;
pub mod image_file;
pub mod inspect;
pub mod layer;
pub mod limits;
pub mod matte;
pub mod npy;
mod png_encode;
mod png_rows;
pub(crate) mod samples;
pub mod tiff_file;
pub mod write;
pub mod xmp;

pub use depth::{DepthMap, read_depth, read_depth_map};
pub use exr_file::{ExrChannel, ExrChannels, ExrLayout, read_exr_channels, read_exr_image, write_exr};
pub use format::{FileFormat, SUPPORTED_INPUT_EXTENSIONS, check_regular_file, detect_format, read_input, read_input_text};
pub use guard::{InputFiles, check_distinct, folder_of, same_destination};
pub use image_file::{Decoded, Encoding, Photo, read_decoded, read_photo, read_photo_file};
pub use layer::{LAYER_CHANNELS, LayerFile, read_layer, read_layer_file};
pub use limits::ReadLimits;
pub use matte::{MATTE_TOLERANCE, read_matte};
pub use npy::{read_npy, save_npy};
pub use write::{BitDepth, OutputFormat, default_channel_names, encode_png, write_output, write_png};
