//! OpenEXR reading (any channel names) and writing (float32).
//!
//! Reading uses the `exr` crate's generic API so that channels named `Y`, `Z` or `D` read as
//! well as `R,G,B,A`. Only the first valid (non-deep) layer of a multi-part file and its largest
//! resolution level are read; the data window is read as the image (its offset and the display
//! window are ignored). Half, float and uint channels are all converted to `f32`.
//!
//! Before any pixel is decoded the header is read and every part's data window is checked
//! against [`ReadLimits`]. Chunks are decompressed in parallel on rayon (whose jobs hand a
//! panic back to the caller, so the panic guard in [`super::format::guarded`] covers them).

use super::format::{FileFormat, guarded, open};
use super::limits::ReadLimits;
use crate::error::{Error, Result};
use crate::image::Image;
use exr::prelude::{self as x, WritableImage};
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

/// Reads every channel of the first flat (non-deep) part of an EXR file, its largest
/// resolution level.
///
/// The chunks are read from the file in order and decompressed in parallel (rayon, in groups
/// of about [`GROUP_BYTES`] compressed bytes, so memory stays the image plus one group): ZIP
/// and PIZ decompression was the whole cost of an EXR read on one thread. A rayon job's panic
/// reaches this thread, so the panic guard still covers all decoder code.
pub fn read_exr_channels(path: &Path, limits: &ReadLimits) -> Result<ExrChannels> {
    use exr::block::chunk::Chunk;
    use exr::block::reader::ChunksReader;
    use rayon::prelude::*;
    let reader = open(path)?;
    guarded(path, FileFormat::Exr, || {
        let file = exr::block::read(reader, false).map_err(|e| exr_error(path, e))?;
        let headers = file.headers();
        if headers.is_empty() {
            return Err(Error::input(path, "corrupt EXR: the file has no image parts"));
        }
        for h in headers.iter() {
            limits.check(path, h.layer_size.0 as u64, h.layer_size.1 as u64)?;
        }
        let part =
            headers.iter().position(|h| !h.deep).ok_or_else(|| Error::input(path, "EXR file has only deep-data parts; not supported"))?;
        let header = &headers[part];
        let (width, height) = (header.layer_size.0, header.layer_size.1);
        let n = width.saturating_mul(height);
        let list = &header.channels.list;
        if list.is_empty() {
            return Err(Error::input(path, "EXR file has no channels"));
        }
        if let Some(c) = list.iter().find(|c| c.sampling != x::Vec2(1, 1)) {
            return Err(Error::input(
                path,
                format!("EXR channel '{}' is subsampled ({}x{}); not supported", c.name, c.sampling.0, c.sampling.1),
            ));
        }
        let kinds: Vec<x::SampleType> = list.iter().map(|c| c.sample_type).collect();
        let names: Vec<String> = list.iter().map(|c| c.name.to_string()).collect();
        let mut planes: Vec<Vec<f32>> = kinds.iter().map(|_| vec![0f32; n]).collect();
        let mut chunks =
            file.filter_chunks(false, |_, _, block| block.layer == part && block.level == x::Vec2(0, 0)).map_err(|e| exr_error(path, e))?;
        let meta = chunks.meta_data().clone();
        let (mut group, mut bytes): (Vec<Chunk>, usize) = (Vec::new(), 0);
        loop {
            let next = chunks.next().transpose().map_err(|e| exr_error(path, e))?;
            let end = next.is_none();
            if let Some(chunk) = next {
                bytes += chunk_bytes(&chunk);
                group.push(chunk);
            }
            if !group.is_empty() && (end || bytes >= GROUP_BYTES) {
                let blocks: Vec<exr::block::UncompressedBlock> = std::mem::take(&mut group)
                    .into_par_iter()
                    .map(|chunk| exr::block::UncompressedBlock::decompress_chunk(chunk, &meta, false).map_err(|e| exr_error(path, e)))
                    .collect::<Result<_>>()?;
                place(&mut planes, width, &kinds, blocks).map_err(|m| Error::input(path, format!("corrupt EXR: {m}")))?;
                bytes = 0;
            }
            if end {
                break;
            }
        }
        let channels = names
            .into_iter()
            .zip(planes)
            .zip(&kinds)
            .map(|((name, data), kind)| ExrChannel { name, data, bits: if *kind == x::SampleType::F16 { 16 } else { 32 } })
            .collect();
        Ok(ExrChannels { width, height, channels })
    })
}

/// Compressed bytes held per group of chunks decompressed in parallel.
const GROUP_BYTES: usize = 8 << 20;

/// The compressed bytes of a chunk (for grouping).
fn chunk_bytes(chunk: &exr::block::chunk::Chunk) -> usize {
    use exr::block::chunk::CompressedBlock as B;
    match &chunk.compressed_block {
        B::ScanLine(b) => b.compressed_pixels_le.len(),
        B::Tile(b) => b.compressed_pixels_le.len(),
        B::DeepScanLine(b) => b.compressed_sample_data_le.len() + b.compressed_pixel_offset_table.len(),
        B::DeepTile(b) => b.compressed_sample_data_le.len() + b.compressed_pixel_offset_table.len(),
    }
}

/// Converts decompressed blocks into the channel planes (`width` samples per row), in
/// parallel over bands of rows: blocks that start on the same row and have the same height
/// (one scan-line block, or one row of tiles) share a band, and bands never overlap (an
/// error otherwise, as for a block outside the planes or of the wrong byte count).
fn place(
    planes: &mut [Vec<f32>],
    width: usize,
    kinds: &[x::SampleType],
    mut blocks: Vec<exr::block::UncompressedBlock>,
) -> std::result::Result<(), String> {
    use rayon::prelude::*;
    let height = planes.first().map_or(0, |p| p.len() / width.max(1));
    // Bytes of one line of a block `bw` pixels wide: every channel's samples.
    let line_bytes = |bw: usize| kinds.iter().map(|k| k.bytes_per_sample() * bw).sum::<usize>();
    blocks.sort_by_key(|b| (b.index.pixel_position.1, b.index.pixel_position.0));
    // Bands: (first row, rows, blocks), checked.
    let mut bands: Vec<(usize, usize, Vec<exr::block::UncompressedBlock>)> = Vec::new();
    for b in blocks {
        let (x::Vec2(bx, by), x::Vec2(bw, bh)) = (b.index.pixel_position, b.index.pixel_size);
        if bx + bw > width || by + bh > height {
            return Err("a block lies outside the data window".into());
        }
        if line_bytes(bw) * bh != b.data.len() {
            return Err("a block's size does not match its channels".into());
        }
        match bands.last_mut() {
            Some((y, h, list)) if *y == by && *h == bh => {
                let prev = &list[list.len() - 1].index;
                if bx < prev.pixel_position.0 + prev.pixel_size.0 {
                    return Err("two blocks overlap".into());
                }
                list.push(b);
            }
            Some((y, h, _)) if by < *y + *h => return Err("two blocks overlap".into()),
            _ => bands.push((by, bh, vec![b])),
        }
    }
    // Each band's rows of every plane, split off in order.
    let mut rest: Vec<&mut [f32]> = planes.iter_mut().map(|p| &mut p[..]).collect();
    let mut consumed = 0;
    let mut jobs = Vec::with_capacity(bands.len());
    for (y, h, list) in bands {
        let mut rows = Vec::with_capacity(rest.len());
        for r in rest.iter_mut() {
            let (_, tail) = std::mem::take(r).split_at_mut((y - consumed) * width);
            let (mine, tail) = tail.split_at_mut(h * width);
            rows.push(mine);
            *r = tail;
        }
        consumed = y + h;
        jobs.push((rows, list));
    }
    jobs.into_par_iter().for_each(|(mut rows, list)| {
        for b in list {
            let (x0, bw) = (b.index.pixel_position.0, b.index.pixel_size.0);
            let line = line_bytes(bw);
            // The block's bytes: line by line, each line channel by channel (native endian).
            for (l, bytes) in b.data.chunks_exact(line.max(1)).enumerate() {
                let mut src = bytes;
                for (kind, plane) in kinds.iter().zip(rows.iter_mut()) {
                    let (s, tail) = src.split_at(kind.bytes_per_sample() * bw);
                    src = tail;
                    let dst = &mut plane[l * width + x0..][..bw];
                    match kind {
                        x::SampleType::F16 => {
                            dst.iter_mut().zip(s.chunks_exact(2)).for_each(|(d, b)| *d = x::f16::from_ne_bytes([b[0], b[1]]).to_f32())
                        }
                        x::SampleType::F32 => {
                            dst.iter_mut().zip(s.chunks_exact(4)).for_each(|(d, b)| *d = f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
                        }
                        x::SampleType::U32 => dst
                            .iter_mut()
                            .zip(s.chunks_exact(4))
                            .for_each(|(d, b)| *d = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]) as f32),
                    }
                }
            }
        }
    });
    Ok(())
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
