//! The PNG encoder: filtering and DEFLATE in parallel over bands of rows, into one zlib stream.
//!
//! # Contract
//!
//! [`encode`] writes a complete, non-interlaced PNG (signature, IHDR, IDAT chunks, IEND; the
//! `png` crate writes the chunk framing and CRCs) of rows that a caller-supplied function
//! produces (`rows(y, dst)`: the packed samples of rows `y..`, as many as `dst` holds).
//!
//! - **Bands.** The image is cut into bands of whole rows, about [`BAND_BYTES`] of samples
//!   each: the count depends on the image's row size only, never on the thread count. Each
//!   band is produced, filtered and compressed on its own (the row above a band is produced
//!   once more, for the filters), by whichever thread claims it: rayon's threads and the
//!   calling thread, which also writes the finished bands in order.
//! - **Determinism.** A band's bytes depend on its rows alone, so the file is byte-identical
//!   for any thread count.
//! - **Filter.** Per row, the filter of the `png` crate's `Filter::Adaptive` (what the
//!   encoder used before): Up, Sub, Average, Paeth tried in that order, the smallest sum of
//!   absolute (signed) bytes kept, a later filter winning a tie, a zero sum ending the search.
//!   The filtered bytes are the same as the `png` crate's.
//! - **Format.** One zlib stream (header `78 01`, Adler-32 of the whole filtered stream at the
//!   end, combined from the bands'), pigz-style: a band is a run of DEFLATE blocks ending on a
//!   byte boundary with an empty stored block (a sync flush); only the last band's last block
//!   is final. Each band becomes one IDAT chunk (the first also holds the zlib header, the last
//!   the Adler-32).
//! - **Coder.** [`compress_band`]: per block of at most [`BLOCK_BYTES`] filtered bytes, one
//!   dynamic-Huffman block with a code fitted to the block (codes of at most 14 bits), whose
//!   symbols are literal bytes and runs of zero bytes (a zero, then matches at distance 1),
//!   as `fdeflate` (the `png` crate's `Compression::Fast`) codes them with its fixed code; a
//!   stored block where that would be smaller. Why a coder of our own: on
//!   `examples/io_timing`'s 4032x3024 8-bit RGB photo (36.6 MB filtered), one thread, it runs
//!   at ~1000 MB/s for 9.98 MB, `fdeflate` at ~555 MB/s for 12.64 MB (and it cannot end a
//!   band on a known bit, so cannot be split); `zlib-rs` 0.6 (raw, sync-flushed 1 MB bands,
//!   the flush pigz uses) at 140 MB/s with its RLE strategy (10.1 MB), 277 MB/s Huffman-only
//!   (9.94 MB), 311 MB/s at level 1 (20.6 MB: fixed codes); libdeflate level 1 at
//!   250-295 MB/s (11.9 MB, no flush); miniz level 1 at 120 MB/s. Each of those would need
//!   twice `fdeflate`'s CPU time or more, so none beats today's serial writer on two cores.
//!   (16-bit samples, 73 MB filtered: ~900 MB/s for 55.4 MB against 580 MB/s for 63.0 MB.)
//!
//! # Memory
//!
//! Per working thread, reused from band to band: one band's produced rows, its filtered bytes,
//! its compressed bytes, and two row-sized filter buffers. Each compressed band is copied out
//! at its size and held until it is written in order (at most the compressed file, when the
//! writer is slow). Nothing image-sized beyond that.
//!
//! # Errors
//!
//! A write error (or one from the `png` crate's framing) is returned as
//! `"PNG encoder failed: ..."`; the remaining bands are then abandoned. No input panics.

use std::io::Write;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Condvar, Mutex, MutexGuard};

/// Sample bytes per band (whole rows, at least one): ~70 bands for a 12 MP 8-bit RGB image,
/// enough to keep 16 threads busy to the end; the extra row a band produces for its first
/// row's filters costs ~2 % there. (256 KB to 1 MB bands compressed within 0.02 %.)
pub const BAND_BYTES: usize = 1 << 19;

/// Filtered bytes per DEFLATE block at most: a block's code fits its data, and the symbol
/// counts stay far from `u32` overflow whatever the row size.
pub const BLOCK_BYTES: usize = 1 << 20;

/// PNG's row filters, by their type byte.
const UP: u8 = 2;
const SUB: u8 = 1;
const AVG: u8 = 3;
const PAETH: u8 = 4;

/// Encodes a `width` x `height` image of `colour` and `depth` as PNG into `w`; `rows(y, dst)`
/// fills `dst` (whole rows) with the packed samples of rows `y..` (16-bit samples
/// big-endian). See the module doc. An empty image is an error.
pub fn encode<W: Write, F>(w: W, width: u32, height: u32, colour: png::ColorType, depth: png::BitDepth, rows: F) -> Result<(), String>
where
    F: Fn(usize, &mut [u8]) + Sync,
{
    encode_bands(w, width, height, colour, depth, BAND_BYTES, rows)
}

/// [`encode`] with bands of about `band_bytes` (the tests' small bands).
fn encode_bands<W: Write, F>(
    w: W,
    width: u32,
    height: u32,
    colour: png::ColorType,
    depth: png::BitDepth,
    band_bytes: usize,
    rows: F,
) -> Result<(), String>
where
    F: Fn(usize, &mut [u8]) + Sync,
{
    if width == 0 || height == 0 {
        return Err(format!("cannot write a {width}x{height} image as PNG"));
    }
    let failed = |e: png::EncodingError| format!("PNG encoder failed: {e}");
    let mut enc = png::Encoder::new(w, width, height);
    enc.set_color(colour);
    enc.set_depth(depth);
    let mut writer = enc.write_header().map_err(failed)?;
    let bpp = colour.samples() * if depth == png::BitDepth::Sixteen { 2 } else { 1 };
    let row_bytes = width as usize * bpp;
    let layout = Layout { row_bytes, height: height as usize, bpp, band_rows: (band_bytes / row_bytes).max(1) };
    let mut adler = 1u32;
    let mut written = Ok(());
    run_bands(&layout, &rows, |k, mut band: Band| {
        adler = adler32_combine(adler, band.adler, band.filtered as u64);
        if k + 1 == layout.bands() {
            band.bytes.extend_from_slice(&adler.to_be_bytes());
        }
        written = writer.write_chunk(png::chunk::IDAT, &band.bytes);
        written.is_ok()
    });
    written.map_err(failed)?;
    writer.finish().map_err(failed)
}

/// The band geometry: `bpp` bytes per pixel, `band_rows` rows per band.
struct Layout {
    row_bytes: usize,
    height: usize,
    bpp: usize,
    band_rows: usize,
}

impl Layout {
    fn bands(&self) -> usize {
        self.height.div_ceil(self.band_rows)
    }
}

/// One compressed band: its raw DEFLATE bytes (the first band's after the zlib header), the
/// Adler-32 and length of its filtered bytes.
struct Band {
    bytes: Vec<u8>,
    adler: u32,
    filtered: usize,
}

/// A thread's buffers, reused from band to band.
#[derive(Default)]
struct Scratch {
    rows: Vec<u8>,
    filtered: Vec<u8>,
    trial: [Vec<u8>; 2],
    compressed: Vec<u8>,
}

/// The bands shared between the threads: the next one to claim, the finished ones waiting to
/// be written, and the stop flag (a write failed, or a thread panicked).
struct Shared {
    next: AtomicUsize,
    stop: AtomicBool,
    done: Mutex<Vec<Option<Band>>>,
    ready: Condvar,
}

impl Shared {
    fn claim(&self, bands: usize) -> Option<usize> {
        if self.stop.load(Ordering::Relaxed) {
            return None;
        }
        let k = self.next.fetch_add(1, Ordering::Relaxed);
        (k < bands).then_some(k)
    }
    fn lock(&self) -> MutexGuard<'_, Vec<Option<Band>>> {
        self.done.lock().unwrap_or_else(|e| e.into_inner())
    }
    fn store(&self, k: usize, band: Band) {
        self.lock()[k] = Some(band);
        self.ready.notify_all();
    }
}

/// Stops the bands and wakes the writer if a thread unwinds, so that the writer never waits
/// for a band nobody will finish (the panic itself reaches the caller through rayon's scope).
struct PanicGuard<'a>(&'a Shared);

impl Drop for PanicGuard<'_> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.stop.store(true, Ordering::Relaxed);
            let _guard = self.0.lock();
            self.0.ready.notify_all();
        }
    }
}

/// Produces, filters and compresses every band, on rayon's threads and this one, and hands
/// them to `write(k, band)` in order on this thread; `write` returning false stops the rest.
fn run_bands<F>(layout: &Layout, rows: &F, mut write: impl FnMut(usize, Band) -> bool)
where
    F: Fn(usize, &mut [u8]) + Sync,
{
    let bands = layout.bands();
    let shared = Shared { next: AtomicUsize::new(0), stop: AtomicBool::new(false), done: Mutex::new(Vec::new()), ready: Condvar::new() };
    shared.lock().resize_with(bands, || None);
    let work = |scratch: &mut Scratch| {
        let _guard = PanicGuard(&shared);
        if let Some(k) = shared.claim(bands) {
            shared.store(k, encode_band(layout, rows, k, scratch));
            true
        } else {
            false
        }
    };
    rayon::in_place_scope(|s| {
        // Helpers only where there is more than one band: a small image stays on this thread.
        // This thread is one of the `--threads` workers: with one, it encodes alone.
        for _ in 0..(rayon::current_num_threads() - 1).min(bands - 1) {
            s.spawn(|_| {
                let mut scratch = Scratch::default();
                while work(&mut scratch) {}
            });
        }
        // This thread writes the bands in order, and compresses whenever the next one to
        // write is not ready.
        let mut scratch = Scratch::default();
        let mut k = 0;
        while k < bands {
            let ready = shared.lock()[k].take();
            if let Some(band) = ready {
                if !write(k, band) {
                    shared.stop.store(true, Ordering::Relaxed);
                    return;
                }
                k += 1;
            } else if !work(&mut scratch) {
                // Every band claimed: wait for band k (or for a panic's stop).
                let mut done = shared.lock();
                while done[k].is_none() && !shared.stop.load(Ordering::Relaxed) {
                    done = shared.ready.wait(done).unwrap_or_else(|e| e.into_inner());
                }
                if done[k].is_none() {
                    return;
                }
            }
        }
    });
}

/// Band `k`: its rows (and the one above) produced, filtered and compressed.
fn encode_band<F: Fn(usize, &mut [u8])>(layout: &Layout, rows: &F, k: usize, scratch: &mut Scratch) -> Band {
    let Layout { row_bytes, height, bpp, band_rows } = *layout;
    let y0 = k * band_rows;
    let y1 = (y0 + band_rows).min(height);
    // The row above the band (zeros above the image), then the band's rows.
    let above = y0.saturating_sub(1);
    let produced = y1 - above;
    // (Not cleared: `rows` overwrites all but the zero row.)
    scratch.rows.resize((produced + usize::from(y0 == 0)) * row_bytes, 0);
    let first = if y0 == 0 { row_bytes } else { 0 };
    scratch.rows[..first].fill(0);
    rows(above, &mut scratch.rows[first..]);
    scratch.filtered.clear();
    scratch.filtered.reserve((y1 - y0) * (row_bytes + 1));
    for t in &mut scratch.trial {
        t.resize(row_bytes, 0);
    }
    for pair in scratch.rows.windows(2 * row_bytes).step_by(row_bytes) {
        let (prev, cur) = pair.split_at(row_bytes);
        filter_row(bpp, prev, cur, &mut scratch.trial, &mut scratch.filtered);
    }
    let mut adler = simd_adler32::Adler32::new();
    adler.write(&scratch.filtered);
    let adler = adler.finish();
    let header: &[u8] = if k == 0 { &[0x78, 0x01] } else { &[] };
    let bytes = compress_band(header, &scratch.filtered, k + 1 == layout.bands(), &mut scratch.compressed);
    Band { bytes, adler, filtered: scratch.filtered.len() }
}

// ---- Filtering --------------------------------------------------------------------------

/// Appends row `cur`'s filter type and filtered bytes to `out`, the filter chosen as the
/// `png` crate's `Filter::Adaptive` chooses (see the module doc). `trial` holds two row-sized
/// buffers: the best filter so far and the one being tried.
fn filter_row(bpp: usize, prev: &[u8], cur: &[u8], trial: &mut [Vec<u8>; 2], out: &mut Vec<u8>) {
    let [best, next] = trial;
    let mut kind = UP;
    let mut cost = apply(UP, bpp, prev, cur, best);
    if cost > 0 {
        for f in [SUB, AVG, PAETH] {
            let c = apply(f, bpp, prev, cur, next);
            if c <= cost {
                std::mem::swap(best, next);
                (kind, cost) = (f, c);
                if c == 0 {
                    break;
                }
            }
        }
    }
    out.push(kind);
    out.extend_from_slice(&best[..cur.len()]);
}

/// Writes filter `f` of row `cur` (the row above: `prev`) into `out`; returns the sum of the
/// filtered bytes' absolute values as signed bytes (the adaptive filter's cost).
fn apply(f: u8, bpp: usize, prev: &[u8], cur: &[u8], out: &mut [u8]) -> u64 {
    let n = cur.len();
    let (out, prev) = (&mut out[..n], &prev[..n]);
    let bpp = bpp.min(n);
    // Left of the first pixel, `a` and `c` are 0.
    let (head, body) = out.split_at_mut(bpp);
    match f {
        UP => {
            out.iter_mut().zip(cur).zip(prev).for_each(|((o, &x), &b)| *o = x.wrapping_sub(b));
        }
        SUB => {
            head.copy_from_slice(&cur[..bpp]);
            body.iter_mut().zip(&cur[bpp..]).zip(cur).for_each(|((o, &x), &a)| *o = x.wrapping_sub(a));
        }
        AVG => {
            head.iter_mut().zip(cur).zip(prev).for_each(|((o, &x), &b)| *o = x.wrapping_sub(b / 2));
            body.iter_mut().zip(&cur[bpp..]).zip(cur).zip(&prev[bpp..]).for_each(|(((o, &x), &a), &b)| {
                // The average without overflow: common bits plus half the differing ones.
                *o = x.wrapping_sub((a & b) + ((a ^ b) >> 1));
            });
        }
        _ => {
            head.iter_mut().zip(cur).zip(prev).for_each(|((o, &x), &b)| *o = x.wrapping_sub(b));
            body.iter_mut().zip(&cur[bpp..]).zip(cur).zip(&prev[bpp..]).zip(prev).for_each(|((((o, &x), &a), &b), &c)| {
                *o = x.wrapping_sub(paeth(a, b, c));
            });
        }
    }
    cost(out)
}

/// PNG's Paeth predictor, in byte arithmetic that vectorizes: with `p = a + b - c`,
/// `|p - a| = |b - c|`, `|p - b| = |a - c|`, and `|p - c| = ||b - c| - |a - c||` when `c` lies
/// between `a` and `b` (otherwise it is the largest of the three and never chosen).
#[inline(always)]
fn paeth(a: u8, b: u8, c: u8) -> u8 {
    let pa = b.max(c) - b.min(c);
    let pb = a.max(c) - a.min(c);
    let pc = if (a < c) == (c < b) { pa.max(pb) - pa.min(pb) } else { 255 };
    if pa <= pb && pa <= pc {
        a
    } else if pb <= pc {
        b
    } else {
        c
    }
}

/// Sum of `|b as i8|`: 32-byte chunks summed in `u32` lanes (vectorized), then in `u64`.
fn cost(bytes: &[u8]) -> u64 {
    let mut chunks = bytes.chunks_exact(32);
    let mut sum = 0u64;
    for c in &mut chunks {
        sum += c.iter().map(|&b| u32::from((b as i8).unsigned_abs())).sum::<u32>() as u64;
    }
    sum + chunks.remainder().iter().map(|&b| u64::from((b as i8).unsigned_abs())).sum::<u64>()
}

// ---- Adler-32 ----------------------------------------------------------------------------

/// The Adler-32 of `A` then `B` from theirs and `B`'s length (zlib's `adler32_combine`):
/// `B`'s running sums each gain `A`'s byte sum (`s1(A) - 1`), `len_b` times for `s2`.
fn adler32_combine(a: u32, b: u32, len_b: u64) -> u32 {
    const BASE: u64 = 65521;
    let (a1, a2) = (u64::from(a & 0xffff), u64::from(a >> 16));
    let (b1, b2) = (u64::from(b & 0xffff), u64::from(b >> 16));
    let s1 = (a1 + b1 + BASE - 1) % BASE;
    let s2 = (a2 + b2 + (len_b % BASE) * ((a1 + BASE - 1) % BASE)) % BASE;
    (s2 << 16 | s1) as u32
}

// ---- DEFLATE -----------------------------------------------------------------------------

/// Blocks of at least this many bytes fit their code to a sample of [`SAMPLE_PIECE`]-byte
/// pieces, one in [`SAMPLE_EVERY`] (smaller ones to all their bytes).
const SAMPLED_BLOCK: usize = 1 << 16;
const SAMPLE_PIECE: usize = 4096;
const SAMPLE_EVERY: usize = 4;

/// Longest literal/length code: four literals (4 x 14 bits) fit the 57 bits the bit buffer
/// has free after a flush. (DEFLATE allows 15; only the rarest symbols of a block can reach
/// that deep.)
const MAX_CODE_BITS: usize = 14;
/// Longest code of the code-length alphabet (DEFLATE's limit).
const MAX_CL_BITS: usize = 7;
/// Literal/length alphabet: 256 literals, end of block, 29 length symbols.
const LITLEN: usize = 286;
const END_OF_BLOCK: usize = 256;

/// Base length and extra bits of length symbols 257..=285 (RFC 1951, 3.2.5).
const LENGTH_BASE: [u16; 29] =
    [3, 4, 5, 6, 7, 8, 9, 10, 11, 13, 15, 17, 19, 23, 27, 31, 35, 43, 51, 59, 67, 83, 99, 115, 131, 163, 195, 227, 258];
const LENGTH_EXTRA: [u8; 29] = [0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3, 4, 4, 4, 4, 5, 5, 5, 5, 0];

/// Length symbol (0..29, for 257..) of each match length 3..=258 (0..3 unused).
const LENGTH_SYMBOL: [u8; 259] = {
    let mut t = [0u8; 259];
    let (mut s, mut len) = (0, 3);
    while len <= 258 {
        while s + 1 < 29 && LENGTH_BASE[s + 1] as usize <= len {
            s += 1;
        }
        t[len] = s as u8;
        len += 1;
    }
    t
};

/// The order of the code-length code's lengths in a block header (RFC 1951, 3.2.7).
const CL_ORDER: [usize; 19] = [16, 17, 18, 0, 8, 7, 9, 6, 10, 5, 11, 4, 12, 3, 13, 2, 14, 1, 15];

/// Raw DEFLATE of one band's filtered bytes `data`, after `prefix` (the zlib header, for the
/// first band): blocks of at most [`BLOCK_BYTES`], then, unless `last`, an empty stored block
/// (a sync flush) so that the band ends on a byte boundary and the next one can follow.
fn compress_band(prefix: &[u8], data: &[u8], last: bool, buffer: &mut Vec<u8>) -> Vec<u8> {
    let mut w = BitWriter { out: std::mem::take(buffer), pos: 0, buf: 0, n: 0 };
    w.bytes(prefix);
    let blocks = data.len().div_ceil(BLOCK_BYTES);
    let mut aligned = false;
    for (i, piece) in data.chunks(BLOCK_BYTES).enumerate() {
        aligned = block(&mut w, piece, last && i + 1 == blocks);
    }
    if blocks == 0 {
        aligned = stored(&mut w, &[], last);
    }
    if !last && !aligned {
        w.put(0, 3);
        w.align();
        w.bytes(&[0, 0, 0xff, 0xff]);
    }
    w.align();
    // The band's bytes in a buffer of their size (the writer's, sized ahead, stays with the
    // thread for its next band).
    let band = w.out[..w.pos].to_vec();
    *buffer = w.out;
    band
}

/// Bits into bytes, least significant first (DEFLATE's order), through a 64-bit buffer that
/// each [`BitWriter::flush`] empties to at most 7 bits. The output (`out[..pos]`; bytes past
/// `pos` are scratch) is sized ahead from each block's estimated size.
struct BitWriter {
    out: Vec<u8>,
    pos: usize,
    buf: u64,
    n: u32,
}

impl BitWriter {
    /// Adds the low `len` bits of `bits` (no higher bit set); at most 57 bits between flushes.
    #[inline(always)]
    fn put(&mut self, bits: u64, len: u32) {
        debug_assert!(self.n + len <= 64 && bits >> len == 0);
        self.buf |= bits << self.n;
        self.n += len;
    }

    /// Writes the buffer's whole bytes: eight bytes stored, the write position moved past the
    /// whole ones.
    #[inline(always)]
    fn flush(&mut self) {
        if self.pos + 8 > self.out.len() {
            // Only where the size reserved ahead fell short (a sampled block's estimate).
            self.reserve(64.max(self.out.len() / 2));
        }
        self.out[self.pos..self.pos + 8].copy_from_slice(&self.buf.to_le_bytes());
        let k = self.n / 8;
        self.pos += k as usize;
        // k is at most 7 (n < 64), so the shift is in range.
        self.buf >>= 8 * k;
        self.n -= 8 * k;
    }

    /// Room for `bytes` more bytes past the write position (and the 8 a flush stores).
    fn reserve(&mut self, bytes: usize) {
        let len = self.pos.saturating_add(bytes).saturating_add(16);
        if len > self.out.len() {
            self.out.reserve_exact(len - self.out.len());
            self.out.resize(len, 0);
        }
    }

    /// Pads to a byte boundary with zero bits.
    fn align(&mut self) {
        self.n = self.n.div_ceil(8) * 8;
        self.flush();
    }

    /// Appends bytes (on a byte boundary).
    fn bytes(&mut self, b: &[u8]) {
        debug_assert_eq!(self.n, 0);
        self.reserve(b.len());
        self.out[self.pos..self.pos + b.len()].copy_from_slice(b);
        self.pos += b.len();
    }
}

/// What [`parse`] finds: literal bytes and runs of zeros.
trait Sink {
    fn literals8(&mut self, bytes: &[u8; 8]);
    fn literal(&mut self, b: u8);
    fn run(&mut self, n: usize);
}

/// Splits `data` into literals and runs of zeros, eight bytes at a time: a run is a string of
/// zero words (8 bytes) with the zero bytes that end the word before it and begin the word
/// after it. Other zero bytes are literals (cheap: the code is fitted to the block). The same
/// parse feeds the histogram and then the encoder, so they agree by construction. (Starting
/// a run at any word's trailing zeros, as `fdeflate` does, ran the coder at 290 MB/s instead
/// of 710 on the io_timing photo, histogram unsampled: mispredicted branches on noisy data.)
#[inline(always)]
fn parse<S: Sink>(data: &[u8], s: &mut S) {
    let words = data.len() / 8;
    let word = |i: usize| -> [u8; 8] {
        let mut w = [0u8; 8];
        w.copy_from_slice(&data[8 * i..8 * i + 8]);
        w
    };
    let mut run = 0usize;
    let mut i = 0;
    while i < words {
        let bytes = word(i);
        let w = u64::from_le_bytes(bytes);
        i += 1;
        if w == 0 {
            run += 8;
            continue;
        }
        let next_zero = i < words && u64::from_le_bytes(word(i)) == 0;
        if run == 0 && !next_zero {
            s.literals8(&bytes);
            continue;
        }
        let mut start = 0;
        if run > 0 {
            start = (w.trailing_zeros() / 8) as usize;
            s.run(run + start);
        }
        let end = if next_zero { 8 - (w.leading_zeros() / 8) as usize } else { 8 };
        for &b in &bytes[start..end] {
            s.literal(b);
        }
        run = 8 - end;
    }
    for &b in &data[8 * words..] {
        if b == 0 {
            run += 1;
        } else {
            if run > 0 {
                s.run(run);
                run = 0;
            }
            s.literal(b);
        }
    }
    if run > 0 {
        s.run(run);
    }
}

/// The symbols of a run of `n` zeros: a literal zero (`token(0)`), then matches at distance
/// 1 (`token(length)`) of up to 258 bytes; a remainder under 3 as literal zeros.
#[inline(always)]
fn run_tokens(n: usize, mut token: impl FnMut(usize)) {
    token(0);
    let mut rem = n.saturating_sub(1);
    while rem >= 258 {
        token(258);
        rem -= 258;
    }
    if rem >= 3 {
        token(rem);
    } else {
        (0..rem).for_each(|_| token(0));
    }
}

/// Symbol counts: literals in four tables (consecutive bytes hit different tables, so equal
/// bytes do not wait on each other's increment), length symbols in one.
struct Histogram {
    literals: [[u32; 256]; 4],
    lengths: [u32; 29],
}

impl Sink for Histogram {
    #[inline(always)]
    fn literals8(&mut self, bytes: &[u8; 8]) {
        for (k, &b) in bytes.iter().enumerate() {
            self.literals[k & 3][b as usize] += 1;
        }
    }
    #[inline(always)]
    fn literal(&mut self, b: u8) {
        self.literals[0][b as usize] += 1;
    }
    #[inline(always)]
    fn run(&mut self, n: usize) {
        let (literals, lengths) = (&mut self.literals[0], &mut self.lengths);
        run_tokens(n, |len| if len == 0 { literals[0] += 1 } else { lengths[LENGTH_SYMBOL[len] as usize] += 1 });
    }
}

/// Writes the symbols with a block's code: per literal/length symbol, the code (bit-reversed,
/// ready to send) and its length (two tables: 7 % faster than one of both packed, which
/// needs a mask and a shift per symbol); distance 1 is one bit, `0`.
struct Encoder<'a> {
    w: &'a mut BitWriter,
    code: [u16; LITLEN],
    len: [u8; LITLEN],
}

impl Encoder<'_> {
    #[inline(always)]
    fn symbol(&mut self, s: usize) {
        self.w.put(u64::from(self.code[s]), u32::from(self.len[s]));
    }
}

impl Sink for Encoder<'_> {
    #[inline(always)]
    fn literals8(&mut self, bytes: &[u8; 8]) {
        // Four codes of at most 14 bits per flush.
        for half in [&bytes[..4], &bytes[4..]] {
            let (mut bits, mut n) = (0u64, 0u32);
            for &b in half {
                bits |= u64::from(self.code[b as usize]) << n;
                n += u32::from(self.len[b as usize]);
            }
            self.w.put(bits, n);
            self.w.flush();
        }
    }
    #[inline(always)]
    fn literal(&mut self, b: u8) {
        self.symbol(b as usize);
        self.w.flush();
    }
    #[inline(always)]
    fn run(&mut self, n: usize) {
        run_tokens(n, |len| {
            if len == 0 {
                self.symbol(0);
            } else {
                let s = LENGTH_SYMBOL[len] as usize;
                self.symbol(257 + s);
                self.w.put((len - LENGTH_BASE[s] as usize) as u64, u32::from(LENGTH_EXTRA[s]));
                self.w.put(0, 1);
            }
            self.w.flush();
        });
    }
}

/// One block of `data`: dynamic Huffman, or stored where that is no larger. Returns whether
/// it was stored (and so ended on a byte boundary).
fn block(w: &mut BitWriter, data: &[u8], last: bool) -> bool {
    let mut hist = Histogram { literals: [[0; 256]; 4], lengths: [0; 29] };
    // A large block's code is fitted to a sample: one in four pieces of 4 KB (every symbol
    // then counted once more, so that any symbol has a code). On the io_timing photo the
    // coder ran 1.45x faster for 0.25 % more bytes.
    let sampled = data.len() >= SAMPLED_BLOCK;
    let mut sample_bytes = 0;
    for piece in data.chunks(if sampled { SAMPLE_PIECE } else { data.len().max(1) }).step_by(if sampled { SAMPLE_EVERY } else { 1 }) {
        parse(piece, &mut hist);
        sample_bytes += piece.len();
    }
    let mut freq = [0u32; LITLEN];
    for (b, f) in freq[..256].iter_mut().enumerate() {
        *f = hist.literals.iter().map(|t| t[b]).sum::<u32>() + u32::from(sampled);
    }
    freq[END_OF_BLOCK] = 1;
    for (f, &c) in freq[257..].iter_mut().zip(&hist.lengths) {
        *f = c + u32::from(sampled);
    }
    let mut len = [0u8; LITLEN];
    huffman_lengths(&freq, MAX_CODE_BITS, &mut len);
    let hlit = 257.max(LITLEN - len.iter().rev().take_while(|&&l| l == 0).count());
    // The lengths of the literal/length code, then of the distance code: distance 1 alone,
    // one code of one bit (RFC 1951 allows a single distance code).
    let mut lens = len[..hlit].to_vec();
    lens.push(1);
    let tokens = code_length_tokens(&lens);
    let mut cl_freq = [0u32; 19];
    tokens.iter().for_each(|&(s, _)| cl_freq[s as usize] += 1);
    if cl_freq.iter().filter(|&&f| f > 0).count() < 2 {
        // A code-length code must be complete (zlib rejects a lone 1-bit code there): give
        // it a second, unused symbol.
        let spare = if cl_freq[0] == 0 { 0 } else { 1 };
        cl_freq[spare] = 1;
    }
    let mut cl_len = [0u8; 19];
    huffman_lengths(&cl_freq, MAX_CL_BITS, &mut cl_len);
    let hclen = 4.max(19 - CL_ORDER.iter().rev().take_while(|&&s| cl_len[s] == 0).count());
    let header_bits =
        3 + 14 + 3 * hclen as u64 + tokens.iter().map(|&(s, _)| u64::from(cl_len[s as usize]) + cl_extra(s) as u64).sum::<u64>();
    // The body's size: exact for a whole histogram, scaled from the sample's otherwise (it
    // only decides stored or not, and how much room to reserve).
    let sample_bits = (0..LITLEN)
        .map(|s| {
            // A length symbol's extra bits and distance 1's one bit.
            let extra = if s > END_OF_BLOCK { u64::from(LENGTH_EXTRA[s - 257]) + 1 } else { 0 };
            u64::from(freq[s]) * (u64::from(len[s]) + extra)
        })
        .sum::<u64>();
    let body_bits = (sample_bits as f64 * data.len() as f64 / sample_bytes.max(1) as f64) as u64;
    let stored_bits = 8 * (data.len() as u64 + 5 * data.len().div_ceil(65535).max(1) as u64);
    if header_bits + body_bits >= stored_bits {
        return stored(w, data, last);
    }
    w.reserve(((header_bits + body_bits + body_bits / 32) / 8) as usize + 64);
    // Header: BFINAL, BTYPE 2 (dynamic), HLIT, HDIST (one code), HCLEN.
    w.put(u64::from(last) | 2 << 1, 3);
    w.put((hlit - 257) as u64 | ((hclen - 4) as u64) << 10, 14);
    w.flush();
    for &s in &CL_ORDER[..hclen] {
        w.put(u64::from(cl_len[s]), 3);
        w.flush();
    }
    let mut cl_code = [0u16; 19];
    canonical_codes(&cl_len, &mut cl_code);
    for &(s, extra) in &tokens {
        w.put(u64::from(cl_code[s as usize]), u32::from(cl_len[s as usize]));
        w.put(u64::from(extra), cl_extra(s));
        w.flush();
    }
    let mut code = [0u16; LITLEN];
    canonical_codes(&len, &mut code);
    let mut enc = Encoder { w, code, len };
    parse(data, &mut enc);
    enc.symbol(END_OF_BLOCK);
    enc.w.flush();
    false
}

/// Extra bits of code-length symbol `s` (16: repeat 3-6, 17: 3-10 zeros, 18: 11-138 zeros).
fn cl_extra(s: u8) -> u32 {
    match s {
        16 => 2,
        17 => 3,
        18 => 7,
        _ => 0,
    }
}

/// Stored blocks of `data` (65535 bytes each at most; one empty block for no data). Returns
/// true: it ends on a byte boundary.
fn stored(w: &mut BitWriter, data: &[u8], last: bool) -> bool {
    let blocks = data.len().div_ceil(65535).max(1);
    for k in 0..blocks {
        let piece = &data[(k * 65535).min(data.len())..((k + 1) * 65535).min(data.len())];
        w.put(u64::from(last && k + 1 == blocks), 3);
        w.align();
        let len = piece.len() as u16;
        w.bytes(&[len as u8, (len >> 8) as u8, !len as u8, (!len >> 8) as u8]);
        w.bytes(piece);
    }
    true
}

/// Huffman code lengths for `freq`, at most `limit` bits, into `lens` (0 for unused symbols;
/// a lone symbol gets 1 bit). Ties are broken by symbol, so the result is deterministic.
fn huffman_lengths(freq: &[u32], limit: usize, lens: &mut [u8]) {
    lens.iter_mut().for_each(|l| *l = 0);
    let mut syms: Vec<(u32, u16)> = freq.iter().enumerate().filter(|&(_, &f)| f > 0).map(|(s, &f)| (f, s as u16)).collect();
    if syms.len() < 2 {
        syms.iter().for_each(|&(_, s)| lens[s as usize] = 1);
        return;
    }
    syms.sort_unstable();
    // Moffat and Katajainen's in-place minimum-redundancy code, on the ascending weights:
    // phase 1 builds the tree's internal weights and parent links, phase 2 the internal
    // nodes' depths, phase 3 the leaves' depths (`a[i]`: the length of the i-th rarest).
    let n = syms.len();
    let mut a: Vec<u64> = syms.iter().map(|&(f, _)| u64::from(f)).collect();
    let (mut root, mut leaf) = (0, 2);
    a[0] += a[1];
    for next in 1..n - 1 {
        if leaf >= n || a[root] < a[leaf] {
            a[next] = a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] = a[leaf];
            leaf += 1;
        }
        if leaf >= n || (root < next && a[root] < a[leaf]) {
            a[next] += a[root];
            a[root] = next as u64;
            root += 1;
        } else {
            a[next] += a[leaf];
            leaf += 1;
        }
    }
    a[n - 2] = 0;
    for next in (0..n - 2).rev() {
        a[next] = a[a[next] as usize] + 1;
    }
    let (mut avail, mut used, mut depth) = (1usize, 0usize, 0u64);
    let (mut root, mut next) = (n as isize - 2, n as isize - 1);
    while avail > 0 {
        while root >= 0 && a[root as usize] == depth {
            used += 1;
            root -= 1;
        }
        while avail > used && next >= 0 {
            a[next as usize] = depth;
            next -= 1;
            avail -= 1;
        }
        avail = 2 * used;
        depth += 1;
        used = 0;
    }
    // Counts per length, those over the limit moved to it; then the Kraft sum restored by
    // moving one code from the limit and splitting the deepest shorter code (miniz's
    // method): the lengths stay decodable and complete.
    let mut count = [0u32; 64];
    a.iter().for_each(|&l| count[(l as usize).min(limit)] += 1);
    let mut kraft: u64 = (1..=limit).map(|l| u64::from(count[l]) << (limit - l)).sum();
    while kraft > 1 << limit {
        count[limit] -= 1;
        if let Some(l) = (1..limit).rev().find(|&l| count[l] > 0) {
            count[l] -= 1;
            count[l + 1] += 2;
        }
        kraft -= 1;
    }
    // The longest codes to the rarest symbols.
    let mut rarest = syms.iter();
    for l in (1..=limit).rev() {
        for (_, s) in rarest.by_ref().take(count[l] as usize) {
            lens[*s as usize] = l as u8;
        }
    }
}

/// The canonical codes of `lens` (RFC 1951, 3.2.2), bit-reversed for sending.
fn canonical_codes(lens: &[u8], codes: &mut [u16]) {
    let mut count = [0u16; 16];
    lens.iter().for_each(|&l| count[l as usize & 15] += 1);
    count[0] = 0;
    let mut next = [0u16; 16];
    let mut code = 0u16;
    for l in 1..16 {
        code = (code + count[l - 1]) << 1;
        next[l] = code;
    }
    for (c, &l) in codes.iter_mut().zip(lens) {
        if l > 0 {
            *c = next[l as usize].reverse_bits() >> (16 - u32::from(l));
            next[l as usize] += 1;
        }
    }
}

/// The code lengths `lens` run-length coded as a block header sends them: (symbol 0..19,
/// extra bits' value); 16 repeats the previous length 3-6 times, 17 and 18 are zero runs.
fn code_length_tokens(lens: &[u8]) -> Vec<(u8, u8)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < lens.len() {
        let l = lens[i];
        let mut r = lens[i..].iter().take_while(|&&x| x == l).count();
        i += r;
        if l == 0 {
            while r >= 11 {
                let k = r.min(138);
                out.push((18, (k - 11) as u8));
                r -= k;
            }
            if r >= 3 {
                out.push((17, (r - 3) as u8));
                r = 0;
            }
        } else {
            out.push((l, 0));
            r -= 1;
            while r >= 3 {
                let k = r.min(6);
                out.push((16, (k - 3) as u8));
                r -= k;
            }
        }
        out.extend(std::iter::repeat_n((l, 0), r));
    }
    out
}

#[cfg(test)]
mod tests;
