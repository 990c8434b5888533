//! Reading and writing images, depth maps, mattes and layers.
//!
//! One file per concern: [`format`] (detection by magic bytes then extension, panic guard),
//! [`limits`] (decompression-bomb limits), [`image_file`] (photos and generic rasters),
//! [`tiff_file`], [`exr_file`], [`npy`], [`depth`], [`matte`], [`layer`], [`write`] and
//! [`atomic`] (temp file + rename), [`guard`] (no write may hit a file the run reads).
//!
//! Every error names the file and says what is wrong. Untrusted input never makes the
//! readers panic or allocate beyond [`ReadLimits`]: header dimensions are checked before
//! decoding, and third-party decoders run behind `catch_unwind` as defence in depth.

pub mod atomic;
pub mod depth;
pub mod exr_file;
pub mod format;
pub mod guard;
pub mod image_file;
pub mod layer;
pub mod limits;
pub mod matte;
pub mod npy;
pub mod tiff_file;
pub mod write;

pub use depth::{read_depth, read_depth_map, DepthMap};
pub use exr_file::{read_exr_channels, write_exr, ExrChannel, ExrChannels};
pub use format::{detect_format, FileFormat, SUPPORTED_INPUT_EXTENSIONS};
pub use guard::InputFiles;
pub use image_file::{read_decoded, read_photo, Decoded, Encoding};
pub use layer::{read_layer, LAYER_CHANNELS};
pub use limits::ReadLimits;
pub use matte::{read_matte, MATTE_TOLERANCE};
pub use npy::{read_npy, save_npy};
pub use write::{default_channel_names, encode_png, write_output, write_png, OutputFormat};
