//! OpenEXR reading (any channel names) and writing (float32).
//!
//! Reading uses the `exr` crate's generic API so that channels named `Y`, `Z` or `D` read as
//! well as `R,G,B,A`. Only the first valid (non-deep) layer of a multi-part file and its largest
//! resolution level are read; the data window is read as the image (its offset and the display
//! window are ignored). Half, float and uint channels are all converted to `f32`.
//!
//! Before any pixel is decoded the header is read and every part's data window is checked
//! against [`ReadLimits`]. Decoding runs single-threaded (`non_parallel`) so that the panic
//! guard in [`super::format::guarded`] covers all decoder code.

use super::format::{FileFormat, guarded, open};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use exr::prelude::{self as x, ReadChannels, ReadLayers, WritableImage};
use std::io::{Seek, SeekFrom};
use std::path::Path;

/// One channel of an EXR file, converted to `f32`.
#[derive(Clone, Debug)]
pub struct ExrChannel {
    /// The channel's name in the file ("R", "A", "Z", "depth"...).
    pub name: String,
    /// `width * height` samples, row-major.
    pub data: Vec<f32>,
    /// Bits per sample in the file: 16 (half) or 32 (float, uint).
    pub bits: u8,
}

/// All channels of the first layer of an EXR file, in the file's (alphabetical) order.
#[derive(Clone, Debug)]
pub struct ExrChannels {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The channels, in the file's (alphabetical) order.
    pub channels: Vec<ExrChannel>,
}

impl ExrChannels {
    /// Index of the channel called `name`: an exact match first, then case-insensitive.
    pub fn find(&self, name: &str) -> Option<usize> {
        self.channels.iter().position(|c| c.name == name).or_else(|| self.channels.iter().position(|c| c.name.eq_ignore_ascii_case(name)))
    }

    /// The first of `names` (in priority order) that exists.
    pub fn find_first(&self, names: &[&str]) -> Option<usize> {
        names.iter().find_map(|n| self.find(n))
    }

    /// "R, G, B" — for error messages.
    pub fn names(&self) -> String {
        let v: Vec<&str> = self.channels.iter().map(|c| c.name.as_str()).collect();
        v.join(", ")
    }

    /// Interleaves the channels at `indices` into one image. Parallel over rows (rayon);
    /// allocates the image.
    pub fn to_image(&self, indices: &[usize]) -> Image {
        use rayon::prelude::*;
        let n = indices.len();
        let w = self.width;
        let mut out = Image::new(w, self.height, n);
        if w == 0 {
            return out;
        }
        out.data.par_chunks_mut(w * n).enumerate().for_each(|(y, row)| {
            for (k, &i) in indices.iter().enumerate() {
                let src = &self.channels[i].data[y * w..(y + 1) * w];
                for (dst, &v) in row.iter_mut().skip(k).step_by(n).zip(src) {
                    *dst = v;
                }
            }
        });
        out
    }

    /// Largest bit depth among `indices`.
    pub fn bits(&self, indices: &[usize]) -> u8 {
        indices.iter().map(|&i| self.channels[i].bits).max().unwrap_or(32)
    }
}

fn exr_error(path: &Path, e: x::Error) -> Error {
    match e {
        x::Error::NotSupported(m) => Error::input(path, format!("unsupported EXR feature: {m}")),
        x::Error::Io(e) => Error::input(path, format!("cannot read EXR data: {e}")),
        other => Error::input(path, format!("corrupt or truncated EXR: {other}")),
    }
}

/// Reads every channel of the first valid layer of an EXR file.
pub fn read_exr_channels(path: &Path, limits: &ReadLimits) -> Result<ExrChannels> {
    let mut reader = open(path)?;
    guarded(path, FileFormat::Exr, || {
        let meta = x::MetaData::read_from_buffered(&mut reader, false).map_err(|e| exr_error(path, e))?;
        if meta.headers.is_empty() {
            return Err(Error::input(path, "corrupt EXR: the file has no image parts"));
        }
        for h in meta.headers.iter() {
            limits.check(path, h.layer_size.0 as u64, h.layer_size.1 as u64)?;
        }
        reader.seek(SeekFrom::Start(0)).map_err(|e| super::format::read_error(path, e))?;
        let image = x::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .first_valid_layer()
            .all_attributes()
            .non_parallel()
            .from_buffered(reader)
            .map_err(|e| exr_error(path, e))?;
        let layer = image.layer_data;
        let (width, height) = (layer.size.0, layer.size.1);
        limits.check(path, width as u64, height as u64)?;
        let n = width.saturating_mul(height);
        let mut channels = Vec::with_capacity(layer.channel_data.list.len());
        for ch in layer.channel_data.list.into_iter() {
            let name = ch.name.to_string();
            let (data, bits): (Vec<f32>, u8) = match ch.sample_data {
                x::FlatSamples::F16(v) => (v.into_iter().map(|h| h.to_f32()).collect(), 16),
                x::FlatSamples::F32(v) => (v, 32),
                x::FlatSamples::U32(v) => (v.into_iter().map(|u| u as f32).collect(), 32),
            };
            if data.len() != n {
                return Err(Error::input(
                    path,
                    format!("EXR channel '{name}' is subsampled ({} samples for {width}x{height} pixels); not supported", data.len()),
                ));
            }
            channels.push(ExrChannel { name, data, bits });
        }
        if channels.is_empty() {
            return Err(Error::input(path, "EXR file has no channels"));
        }
        Ok(ExrChannels { width, height, channels })
    })
}

/// How [`write_exr`] stores pixels: RLE-compressed scan lines, in increasing order (lossless,
/// part of every OpenEXR reader). Measured on a noisy 12.2 MP RGB float image (2 cores, the
/// `exr` crate's parallel writer, `examples/io_timing`): ZIP16 (the `exr` crate's
/// `SMALL_LOSSLESS`, used before) wrote in 6.9 s at 137 MB, ZIP1 4.5 s / 143 MB, PIZ 3.9 s /
/// 110 MB, RLE 0.38 s / 146 MB, none 0.53 s / 146 MB; reading back took 1.37 / 1.04 / 3.66 /
/// 0.64 / 1.25 s. Float mantissas of a photo do not deflate, and the `exr` crate compresses
/// ZIP at a fixed, slow level; RLE still shrinks flat areas (alpha, empty layer regions).
const WRITE_ENCODING: x::Encoding =
    x::Encoding { compression: x::Compression::RLE, blocks: x::Blocks::ScanLines, line_order: x::LineOrder::Increasing };

/// Writes `img` as a float32 EXR (RLE compressed, lossless: see `WRITE_ENCODING`) with the given channel names, one
/// name per channel (e.g. `["R","G","B"]`, `["R","G","B","A","D"]`, `["Y"]`). The file is
/// written atomically. Channels are stored in the alphabetical order the format requires;
/// readers find them by name.
pub fn write_exr(path: &Path, img: &Image, channel_names: &[&str]) -> Result<()> {
    if img.is_empty() {
        return Err(Error::input(path, format!("cannot write an empty {}x{} image", img.width, img.height)));
    }
    if channel_names.len() != img.channels {
        return Err(Error::input(
            path,
            format!("cannot write EXR: {} channel names given for a {}-channel image", channel_names.len(), img.channels),
        ));
    }
    let mut list = x::SmallVec::<[x::AnyChannel<x::FlatSamples>; 4]>::new();
    for (i, &name) in channel_names.iter().enumerate() {
        if channel_names[..i].contains(&name) {
            return Err(Error::input(path, format!("cannot write EXR: channel name '{name}' is used twice")));
        }
        let text = x::Text::new_or_none(name)
            .filter(|_| !name.is_empty())
            .ok_or_else(|| Error::input(path, format!("cannot write EXR: invalid channel name '{name}'")))?;
        let data: Vec<f32> = img.data.iter().skip(i).step_by(img.channels).copied().collect();
        list.push(x::AnyChannel::new(text, x::FlatSamples::F32(data)));
    }
    let layer = x::Layer::new((img.width, img.height), x::LayerAttributes::default(), WRITE_ENCODING, x::AnyChannels::sort(list));
    let image = x::Image::from_layer(layer);
    super::atomic::write_atomic(path, |w| {
        image.write().to_buffered(w).map_err(|e| match e {
            x::Error::Io(e) => Error::io(path, e),
            other => Error::input(path, format!("cannot write EXR: {other}")),
        })
    })
}
