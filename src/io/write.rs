//! Output writers: PNG (8/16-bit, transfer-encoded), EXR and NPY (float32). Every writer goes
//! through [`super::atomic::write_atomic`]: the destination is replaced only once the whole file
//! is written; an existing file is overwritten (the caller refuses output == input).

use super::exr_file::write_exr;
use crate::color::Transfer;
use crate::error::{Error, Result};
use crate::image::Image;
use std::io::Write;
use std::path::Path;

/// Output file formats, chosen from the extension (serialized lowercase, as the extension:
/// "png", "exr", "npy").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OutputFormat {
    /// 8- or 16-bit PNG, transfer-encoded (sRGB or the naive gamma), clipped to [0, 1].
    Png,
    /// OpenEXR, 32-bit float, linear, unclipped.
    Exr,
    /// NumPy `.npy`, float32, linear, unclipped (H x W or H x W x C).
    Npy,
}

impl OutputFormat {
    /// The file extension, without the dot (lowercase; also the serialized name).
    pub fn extension(self) -> &'static str {
        match self {
            OutputFormat::Png => "png",
            OutputFormat::Exr => "exr",
            OutputFormat::Npy => "npy",
        }
    }

    /// `.png`, `.exr` or `.npy` (case-insensitive); a FIFO, character device or symbolic link
    /// without an extension (`/dev/stdout`, `/dev/fd/1`) gets PNG; anything else is an error
    /// naming the extension and the supported ones.
    pub fn from_path(path: &Path) -> Result<OutputFormat> {
        if path.extension().is_none() {
            let special = std::fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink())
                || matches!(super::atomic::destination(path), Ok(super::atomic::Destination::Stream));
            if special {
                return Ok(OutputFormat::Png);
            }
        }
        let ext = path.extension().map(|e| e.to_string_lossy().into_owned());
        match ext.as_deref().map(str::to_ascii_lowercase).as_deref() {
            Some("png") => Ok(OutputFormat::Png),
            Some("exr") => Ok(OutputFormat::Exr),
            Some("npy") => Ok(OutputFormat::Npy),
            Some(other) => Err(Error::input(path, format!("unsupported output extension '.{other}'; use .png, .exr or .npy"))),
            None => Err(Error::input(path, "output file has no extension; use .png, .exr or .npy")),
        }
    }
}

/// Bits per sample of a PNG output. Serialized as the number (8 or 16), so `output.bit_depth`
/// reads and writes as before; any other number is refused when the config is parsed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "u8", into = "u8")]
pub enum BitDepth {
    /// 8 bits per sample: 256 levels, enough for display.
    #[default]
    Eight,
    /// 16 bits per sample: 65536 levels, for further editing without banding.
    Sixteen,
}

impl BitDepth {
    /// The number of bits, 8 or 16, as [`write_png`] takes it.
    pub fn bits(self) -> u8 {
        match self {
            BitDepth::Eight => 8,
            BitDepth::Sixteen => 16,
        }
    }
}

impl From<BitDepth> for u8 {
    fn from(b: BitDepth) -> u8 {
        b.bits()
    }
}

impl TryFrom<u8> for BitDepth {
    type Error = String;
    fn try_from(bits: u8) -> std::result::Result<BitDepth, String> {
        match bits {
            8 => Ok(BitDepth::Eight),
            16 => Ok(BitDepth::Sixteen),
            other => Err(format!("output.bit_depth must be 8 or 16, got {other}")),
        }
    }
}

/// Default EXR channel names for an image with `channels` channels: Y, YA, RGB, RGBA, RGBAD.
pub fn default_channel_names(channels: usize) -> Option<&'static [&'static str]> {
    match channels {
        1 => Some(&["Y"]),
        2 => Some(&["Y", "A"]),
        3 => Some(&["R", "G", "B"]),
        4 => Some(&["R", "G", "B", "A"]),
        5 => Some(&["R", "G", "B", "A", "D"]),
        _ => None,
    }
}

/// Quantizes one value to an integer in `0..=max` (as `f32`): `round(clamp(e, 0, 1) * max)`
/// where `e = transfer.encode(v)` for colour and `v` for alpha; NaN becomes 0. The reference
/// that [`EncodeTable`] reproduces.
#[inline]
fn quantize_value(v: f32, transfer: Transfer, max: f32) -> f32 {
    let e = transfer.encode(v);
    let e = if e.is_nan() { 0.0 } else { e.clamp(0.0, 1.0) };
    (e * max).round()
}

/// [`quantize_value`] for a colour transfer without a `powf` per value: the thresholds where
/// the quantized level steps up, a first guess of the level, and comparisons with the
/// thresholds around the guess that reach the exact level.
///
/// Equal to [`quantize_value`] for every input as long as that is non-decreasing in `v`
/// (true of the sRGB curve and of gammas > 0; `tests::encode_table_equals_the_formula` checks
/// every threshold's neighbourhood and a million random values per table). Built for 8-bit
/// output with [`Transfer::Srgb`] or [`Transfer::Gamma`] of a finite positive exponent, and
/// for 16-bit sRGB output; `None` otherwise (the caller uses the formula).
#[derive(Clone)]
struct EncodeTable {
    /// The largest level, 255 or 65535.
    max: u16,
    /// `thresholds[k]`: the smallest positive float whose level is at least `k + 1`; padded
    /// with infinities so that the searches never index past the end.
    thresholds: Vec<f32>,
    /// 8-bit search. `start[b]`: the level of the float with bits `b << shift` (the smallest
    /// of its range); shift 16 (16 K entries, 32 KB), so a range holds at most one threshold
    /// (near 1.0 ~0.5 levels, where the sRGB curve is flattest in float bits). `steps`: powers
    /// of two, largest first, summing to at least the most levels one range spans, the
    /// branchless search steps (`[1]` for sRGB; a loop of comparisons was 2x slower on noisy
    /// data, mispredicted branches). Measured on a noisy 12.2 MP RGB image, 2 cores: 0.24 s
    /// against 0.39 s with the formula; for 16-bit this search (a 0.5 MB start table and 4
    /// steps) took 0.93 s, hence `ramp` there. Empty for 16-bit.
    start: Vec<u16>,
    shift: u32,
    steps: Vec<usize>,
    /// 16-bit sRGB search (empty for 8-bit). Below `2^-9` (on the curve's linear segment) the
    /// level is the formula's product, no `powf`. Above, `ramp[i] = (c, dc)`: the unrounded
    /// level `c` at the start of float-bit range `i` (`2^15` floats, 1/256 of a binade: 2304
    /// ranges, 18 KB) and its slope per float step; the interpolated level is within 0.05 of
    /// the formula's (tested; the curve's bend over 1/256 of a binade), so its rounding is off
    /// by at most one level, which one comparison each way with the thresholds settles.
    ramp: Vec<(f32, f32)>,
}

/// [`quantize_value`] for sRGB below [`RAMP_START`], out of line: rare in a photo, and kept
/// out of the per-sample loop that [`EncodeTable::level_by`] inlines into.
#[cold]
#[inline(never)]
fn linear_segment(v: f32, max: u16) -> u16 {
    quantize_value(v, Transfer::Srgb, max as f32) as u16
}

/// First float bits of [`EncodeTable::ramp`]'s ranges: `2^-9` (below it, sRGB is linear).
const RAMP_START: u32 = 0x3B00_0000;
/// Float bits per range of [`EncodeTable::ramp`].
const RAMP_SHIFT: u32 = 15;

impl EncodeTable {
    /// O(levels · 30) `encode` calls for the thresholds (bisection over float bits, parallel)
    /// plus O(table) look-ups: under 1 ms for 8 bits, ~20 ms for 16 (built once per process,
    /// [`EncodeTable::get`]).
    fn new(transfer: Transfer, bits: u8) -> Option<EncodeTable> {
        use rayon::prelude::*;
        match (transfer, bits) {
            (Transfer::Srgb, 8 | 16) => {}
            (Transfer::Gamma(g), 8) if g.is_finite() && g > 0.0 => {}
            _ => return None,
        }
        let max = if bits == 16 { u16::MAX } else { 255 };
        let m = max as f32;
        let level = |v: f32| quantize_value(v, transfer, m) as u32;
        // What the look-up assumes outside (0, 1): NaN, zero and negatives are level 0, 1.0
        // and above (monotonic) the top level.
        if [f32::NAN, 0.0, -1.0, f32::NEG_INFINITY].iter().any(|&v| level(v) != 0) || level(1.0) != max as u32 {
            return None;
        }
        let one = 1.0f32.to_bits();
        let mut thresholds: Vec<f32> = (1..=max as u32)
            .into_par_iter()
            .map(|k| {
                // Smallest bit pattern in (0, one] whose level reaches k.
                let (mut lo, mut hi) = (0u32, one);
                while hi - lo > 1 {
                    let mid = lo + (hi - lo) / 2;
                    if level(f32::from_bits(mid)) >= k { hi = mid } else { lo = mid }
                }
                f32::from_bits(hi)
            })
            .collect();
        if bits == 16 {
            // The formula's level before rounding (its f32 `powf` is within ~0.01 level of exact).
            let c = |b: u32| transfer.encode(f32::from_bits(b)).clamp(0.0, 1.0) as f64 * max as f64;
            let ramp = (RAMP_START >> RAMP_SHIFT..one >> RAMP_SHIFT)
                .map(|i| {
                    let (c0, c1) = (c(i << RAMP_SHIFT), c((i + 1) << RAMP_SHIFT));
                    (c0 as f32, ((c1 - c0) / (1u32 << RAMP_SHIFT) as f64) as f32)
                })
                .collect();
            thresholds.resize(max as usize + 2, f32::INFINITY);
            return Some(EncodeTable { max, thresholds, start: Vec::new(), shift: 0, steps: Vec::new(), ramp });
        }
        let shift = 16;
        let start: Vec<u16> = (0..=one >> shift)
            .map(|b| {
                let v = f32::from_bits(b << shift);
                thresholds.partition_point(|&t| t <= v) as u16
            })
            .collect();
        // Levels between the starts of consecutive ranges (and from the last to `max`).
        let span = start.windows(2).map(|w| w[1] - w[0]).chain([max - start[start.len() - 1]]).max().unwrap_or(0) as usize;
        // P, P/2, .., 1 with P the largest power of two <= span: they sum to 2P - 1 >= span.
        let steps: Vec<usize> = if span == 0 { Vec::new() } else { (0..=span.ilog2()).rev().map(|e| 1usize << e).collect() };
        thresholds.resize(max as usize + 2 * steps.iter().sum::<usize>() + 1, f32::INFINITY);
        Some(EncodeTable { max, thresholds, start, shift, steps, ramp: Vec::new() })
    }

    /// The table of `transfer` at `bits`, built once per process for 16-bit sRGB (its
    /// thresholds take ~20 ms), per call otherwise.
    fn get(transfer: Transfer, bits: u8) -> Option<std::borrow::Cow<'static, EncodeTable>> {
        static SRGB16: std::sync::OnceLock<Option<EncodeTable>> = std::sync::OnceLock::new();
        if (transfer, bits) == (Transfer::Srgb, 16) {
            SRGB16.get_or_init(|| EncodeTable::new(transfer, bits)).as_ref().map(std::borrow::Cow::Borrowed)
        } else {
            EncodeTable::new(transfer, bits).map(std::borrow::Cow::Owned)
        }
    }

    /// The level of `v`, equal to `quantize_value(v, transfer, max)` (the tests' entry; the
    /// quantizer calls [`EncodeTable::level_by`] with the search fixed).
    #[cfg(test)]
    fn level(&self, v: f32) -> u16 {
        if self.ramp.is_empty() { self.level_by::<false>(v) } else { self.level_by::<true>(v) }
    }

    /// [`EncodeTable::level_by`] for a table whose ranges hold at most one threshold each (`steps`
    /// of length 0 or 1: the 8-bit tables): the range's first level, plus one if `v` reaches
    /// the next threshold. NaN and every value with the sign bit (-0 included) give 0, like
    /// `v <= 0`; +inf and every value from 1 up give `max`. One table read and one compare,
    /// no branch the data decides but the range test.
    #[inline]
    fn level_one_step(&self, v: f32) -> u16 {
        debug_assert!(self.ramp.is_empty() && self.steps.len() <= 1);
        let b = v.to_bits();
        if b < 1.0f32.to_bits() {
            let q = self.start[(b >> self.shift) as usize];
            q + (v >= self.thresholds[q as usize]) as u16
        } else if b <= f32::INFINITY.to_bits() {
            self.max
        } else {
            0
        }
    }

    /// [`EncodeTable::level`] by the search `INTERPOLATED` names (the `ramp`'s if true, the
    /// `steps`' otherwise), chosen once per image rather than per sample.
    #[inline(always)]
    fn level_by<const INTERPOLATED: bool>(&self, v: f32) -> u16 {
        if v.is_nan() || v <= 0.0 {
            return 0;
        }
        if v >= 1.0 {
            return self.max;
        }
        if !INTERPOLATED {
            // Branchless binary search among the range's few thresholds (sorted): add each
            // step whose last threshold `v` reaches.
            let mut q = self.start[(v.to_bits() >> self.shift) as usize] as usize;
            for &s in &self.steps {
                q += s * (v >= self.thresholds[q + s - 1]) as usize;
            }
            return q as u16;
        }
        let b = v.to_bits();
        if b < RAMP_START {
            // sRGB's linear segment: the formula itself, which takes no `powf` there (the ramp
            // exists for sRGB only).
            return linear_segment(v, self.max);
        }
        let (c, dc) = self.ramp[((b - RAMP_START) >> RAMP_SHIFT) as usize];
        let guess = ((c + dc * (b & ((1 << RAMP_SHIFT) - 1)) as f32 + 0.5) as usize).min(self.max as usize);
        // One level up if `v` reaches the guess's next threshold, one down if it falls short
        // of the guess's own. (Skipping the comparisons where the guess is far from a rounding
        // boundary measured no faster: the branch mispredicts.)
        let up = (v >= self.thresholds[guess]) as usize;
        let down = (guess > 0 && v < self.thresholds[guess.saturating_sub(1)]) as usize;
        (guess + up - down) as u16
    }
}

/// Quantizes `img` to 8 or 16-bit samples: colour channels go through `transfer.encode`
/// (alpha, the last channel of 2/4-channel images, is written linearly), then are clipped to
/// [0, 1] (NaN becomes 0) and rounded to nearest ([`quantize_value`]). 16-bit samples are
/// big-endian, as PNG stores them. Colour goes through an [`EncodeTable`] where one applies;
/// parallel over blocks of 64 K pixels (rayon). Allocates the output bytes only. (The PNG
/// writer quantizes band by band instead, [`encode_png`].)
#[cfg(test)]
fn quantize(img: &Image, bit_depth: u8, transfer: Transfer) -> Vec<u8> {
    use rayon::prelude::*;
    const PIXELS_PER_TASK: usize = 1 << 16;
    let table = EncodeTable::get(transfer, bit_depth);
    let q = Quantizer::new(table.as_deref(), transfer, bit_depth, img.channels);
    let mut out = vec![0u8; img.data.len() * q.bytes];
    let c = q.channels;
    out.par_chunks_mut(PIXELS_PER_TASK * c * q.bytes)
        .zip(img.data.par_chunks(PIXELS_PER_TASK * c))
        .for_each(|(dst, src)| q.block(src, dst));
    out
}

/// The quantizer of one image: its colour search chosen once (the table's, or the formula
/// where no table applies), so that the per-sample call inlines in [`quantize_block`].
struct Quantizer<'a> {
    colour: Colour<'a>,
    /// Channels per pixel and bytes per sample (1 or 2).
    channels: usize,
    bytes: usize,
}

/// [`Quantizer`]'s colour search.
#[derive(Clone, Copy)]
enum Colour<'a> {
    /// [`EncodeTable::level_one_step`] (the 8-bit tables).
    OneStep(&'a EncodeTable),
    /// [`EncodeTable::level_by`], by steps (`false`) or by the ramp (`true`).
    Steps(&'a EncodeTable),
    Ramp(&'a EncodeTable),
    /// [`quantize_value`].
    Formula(Transfer),
}

impl<'a> Quantizer<'a> {
    fn new(table: Option<&'a EncodeTable>, transfer: Transfer, bit_depth: u8, channels: usize) -> Self {
        let colour = match table {
            Some(t) if t.ramp.is_empty() && t.steps.len() <= 1 => Colour::OneStep(t),
            Some(t) if t.ramp.is_empty() => Colour::Steps(t),
            Some(t) => Colour::Ramp(t),
            None => Colour::Formula(transfer),
        };
        Quantizer { colour, channels: channels.max(1), bytes: if bit_depth == 16 { 2 } else { 1 } }
    }

    /// Quantizes whole pixels `src` into `dst` (`bytes` per sample).
    fn block(&self, src: &[f32], dst: &mut [u8]) {
        let (c, bytes) = (self.channels, self.bytes);
        match self.colour {
            Colour::OneStep(t) => quantize_block(src, dst, c, bytes, |v| t.level_one_step(v)),
            Colour::Steps(t) => quantize_block(src, dst, c, bytes, |v| t.level_by::<false>(v)),
            Colour::Ramp(t) => quantize_block(src, dst, c, bytes, |v| t.level_by::<true>(v)),
            Colour::Formula(transfer) => {
                let max = if bytes == 2 { 65535.0 } else { 255.0 };
                quantize_block(src, dst, c, bytes, |v| quantize_value(v, transfer, max) as u16)
            }
        }
    }
}

/// [`Quantizer::block`] with the colour quantizer `colour` (alpha: [`quantize_value`],
/// linear). Monomorphized per quantizer so that the per-value call inlines.
#[inline]
fn quantize_block(src: &[f32], dst: &mut [u8], c: usize, bytes: usize, colour: impl Fn(f32) -> u16) {
    let colours = if c == 2 || c == 4 { c - 1 } else { c };
    if colours == c {
        // Every sample a colour (grey or RGB): one flat loop.
        if bytes == 1 {
            dst.iter_mut().zip(src).for_each(|(d, &v)| *d = colour(v) as u8);
        } else {
            dst.chunks_exact_mut(2).zip(src).for_each(|(d, &v)| d.copy_from_slice(&colour(v).to_be_bytes()));
        }
        return;
    }
    let max = if bytes == 2 { 65535.0 } else { 255.0 };
    for (d, px) in dst.chunks_exact_mut(c * bytes).zip(src.chunks_exact(c)) {
        for (k, &v) in px.iter().enumerate() {
            let q = if k < colours { colour(v) } else { quantize_value(v, Transfer::Linear, max) as u16 };
            if bytes == 2 {
                d[2 * k..2 * k + 2].copy_from_slice(&q.to_be_bytes());
            } else {
                d[k] = q as u8;
            }
        }
    }
}

/// Encodes `img` (1, 2, 3 or 4 channels) as PNG into `w`; see [`write_png`]. Quantizing,
/// filtering and compressing run in parallel (rayon's threads and this one, which writes);
/// the bytes are the same for any thread count (`png_encode`).
pub fn encode_png<W: Write>(w: W, img: &Image, bit_depth: u8, transfer: Transfer) -> std::result::Result<(), String> {
    let colour = match img.channels {
        1 => png::ColorType::Grayscale,
        2 => png::ColorType::GrayscaleAlpha,
        3 => png::ColorType::Rgb,
        4 => png::ColorType::Rgba,
        _ if matches!(bit_depth, 8 | 16) => return Err(format!("cannot write a {}-channel image as PNG (1 to 4 channels)", img.channels)),
        _ => return Err(format!("PNG bit depth must be 8 or 16, not {bit_depth}")),
    };
    let depth = match bit_depth {
        8 => png::BitDepth::Eight,
        16 => png::BitDepth::Sixteen,
        _ => return Err(format!("PNG bit depth must be 8 or 16, not {bit_depth}")),
    };
    if img.is_empty() || img.width > u32::MAX as usize || img.height > u32::MAX as usize {
        return Err(format!("cannot write a {}x{} image as PNG", img.width, img.height));
    }
    let table = EncodeTable::get(transfer, bit_depth);
    let q = Quantizer::new(table.as_deref(), transfer, bit_depth, img.channels);
    // Rows are quantized band by band where they are filtered and compressed (no image-sized
    // byte buffer): `png_encode`, in parallel, byte-identical for any thread count.
    let row = img.width * img.channels;
    super::png_encode::encode(w, img.width as u32, img.height as u32, colour, depth, |y, dst: &mut [u8]| {
        let src = &img.data[y * row..][..dst.len() / q.bytes];
        q.block(src, dst);
    })
}

/// Writes `img` (1 = grey, 2 = grey+alpha, 3 = RGB, 4 = RGBA channels) as an 8 or 16-bit PNG,
/// atomically. Colour values are encoded with `transfer` (`Transfer::Linear` writes the values
/// as they are; alpha is never encoded), clipped to [0, 1] and rounded to nearest.
pub fn write_png(path: &Path, img: &Image, bit_depth: u8, transfer: Transfer) -> Result<()> {
    if bit_depth != 8 && bit_depth != 16 {
        return Err(Error::usage(format!("PNG bit depth must be 8 or 16, not {bit_depth}")));
    }
    super::atomic::write_atomic(path, |w| {
        encode_png(w, img, bit_depth, transfer).map_err(|msg| {
            if msg.starts_with("PNG encoder failed") { Error::io(path, std::io::Error::other(msg)) } else { Error::input(path, msg) }
        })
    })
}

/// Writes a result image, the format picked from the extension ([`OutputFormat::from_path`]):
/// PNG is quantized to `bit_depth` after encoding with `transfer`; EXR (channels named by
/// [`default_channel_names`]) and NPY store the float32 values unchanged (`bit_depth` and
/// `transfer` are ignored).
pub fn write_output(path: &Path, img: &Image, bit_depth: u8, transfer: Transfer) -> Result<()> {
    match OutputFormat::from_path(path)? {
        OutputFormat::Png => write_png(path, img, bit_depth, transfer),
        OutputFormat::Exr => {
            let names = default_channel_names(img.channels)
                .ok_or_else(|| Error::input(path, format!("cannot write a {}-channel image as EXR (1 to 5 channels)", img.channels)))?;
            write_exr(path, img, names)
        }
        OutputFormat::Npy => {
            if img.is_empty() {
                return Err(Error::input(path, format!("cannot write an empty {}x{} image", img.width, img.height)));
            }
            super::npy::save_npy(path, img)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantize_rounds_clips_and_keeps_alpha_linear() {
        let img = Image::from_vec(2, 1, 2, vec![0.5, 0.5, f32::NAN, 2.0]).unwrap();
        assert_eq!(quantize(&img, 8, Transfer::Linear), vec![128, 128, 0, 255]);
        let srgb = quantize(&img, 8, Transfer::Srgb);
        assert_eq!(srgb[1], 128, "alpha is not encoded");
        assert_eq!(srgb[0], 188, "linear 0.5 is sRGB 187.5 -> 188");
        let q16 = quantize(&Image::from_vec(1, 1, 1, vec![0.5]).unwrap(), 16, Transfer::Linear);
        assert_eq!(u16::from_be_bytes([q16[0], q16[1]]), 32768, "16-bit samples are big-endian");
    }

    /// The table quantizer equals the formula: on both sides of every threshold (64 floats
    /// each way), on a million seeded random values in [0, 1.1], and on the special values (NaN
    /// of either sign and payload, signed zeros, infinities, subnormals); the 8-bit tables'
    /// one-step search ([`EncodeTable::level_one_step`], what the quantizer runs) too.
    #[test]
    fn encode_table_equals_the_formula() {
        for (transfer, bits) in [(Transfer::Srgb, 8), (Transfer::Gamma(2.2), 8), (Transfer::Gamma(0.7), 8), (Transfer::Srgb, 16)] {
            let t = EncodeTable::new(transfer, bits).unwrap();
            let max = t.max as f32;
            let one_step = t.ramp.is_empty() && t.steps.len() <= 1;
            let check = |v: f32| {
                let want = quantize_value(v, transfer, max);
                assert_eq!(t.level(v) as f32, want, "{transfer:?} {bits} bits at {v:e}");
                if one_step {
                    assert_eq!(t.level_one_step(v) as f32, want, "{transfer:?} {bits} bits at {v:e}, one step");
                }
            };
            if !t.ramp.is_empty() {
                // The guess is within a small fraction of a level of the formula's unrounded
                // level across every range (so the one-step corrections suffice).
                for (i, &(c, dc)) in t.ramp.iter().enumerate() {
                    for k in 0..=16u32 {
                        let off = (k << RAMP_SHIFT) / 16 - u32::from(k == 16);
                        let v = f32::from_bits(RAMP_START + ((i as u32) << RAMP_SHIFT) + off);
                        let exact = transfer.encode(v).clamp(0.0, 1.0) * max;
                        assert!((c + dc * off as f32 - exact).abs() < 0.05, "range {i} at {v:e}");
                    }
                }
            }
            for &th in &t.thresholds[..t.max as usize] {
                let b = th.to_bits();
                (b.saturating_sub(64)..b + 64).for_each(|b| check(f32::from_bits(b)));
            }
            let mut x = 0x9E37_79B9_7F4A_7C15u64;
            for _ in 0..1_000_000 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                check((x >> 40) as f32 / (1u64 << 24) as f32 * 1.1);
            }
            [f32::NAN, -f32::NAN, -0.0, 0.0, -1.0, 1.0, 1.0001, f32::INFINITY, f32::NEG_INFINITY, f32::MIN_POSITIVE, 1e-40, -1e-40]
                .into_iter()
                .chain([f32::MAX, 1.0 - f32::EPSILON / 2.0, f32::from_bits(0x7f80_0001), f32::from_bits(0xffff_ffff)])
                .for_each(check);
        }
        assert!(EncodeTable::new(Transfer::Srgb, 8).is_some_and(|t| t.steps.len() <= 1), "8-bit sRGB takes the one-step search");
        assert!(EncodeTable::new(Transfer::Linear, 8).is_none() && EncodeTable::new(Transfer::Gamma(-1.0), 8).is_none());
        assert!(EncodeTable::new(Transfer::Gamma(2.2), 16).is_none(), "16-bit gamma keeps the formula");
    }

    /// The PNG writer's bands (each quantized where it is filtered and compressed) give the
    /// image [`quantize`] gives in one piece: every channel count and both depths, bands that
    /// do not divide the height, one band, and a row longer than a band.
    #[test]
    fn png_bands_decode_to_the_whole_image_quantized() {
        for (w, h) in [(300, 1000), (7, 3), (100_000, 2)] {
            for c in 1..=4 {
                for bits in [8u8, 16] {
                    let data = (0..w * h * c).map(|i| ((i * 7919) % 1013) as f32 / 1000.0 - 0.005).collect();
                    let img = Image::from_vec(w, h, c, data).unwrap();
                    let mut file = Vec::new();
                    encode_png(&mut file, &img, bits, Transfer::Srgb).unwrap();
                    let mut reader = png::Decoder::new(std::io::Cursor::new(file)).read_info().unwrap();
                    let mut out = vec![0u8; reader.output_buffer_size().unwrap()];
                    reader.next_frame(&mut out).unwrap();
                    assert!(out == quantize(&img, bits, Transfer::Srgb), "{w}x{h}x{c} at {bits} bits");
                }
            }
        }
    }

    #[test]
    fn output_format_from_extension() {
        assert_eq!(OutputFormat::from_path(Path::new("a.PNG")).unwrap(), OutputFormat::Png);
        assert_eq!(OutputFormat::from_path(Path::new("a.Exr")).unwrap(), OutputFormat::Exr);
        assert_eq!(OutputFormat::from_path(Path::new("a.npy")).unwrap(), OutputFormat::Npy);
        let e = OutputFormat::from_path(Path::new("a.bmp")).unwrap_err().to_string();
        assert!(e.contains(".bmp") && e.contains(".png"), "{e}");
        assert!(OutputFormat::from_path(Path::new("a")).is_err());
    }
}
