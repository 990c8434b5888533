use super::*;

/// Deterministic pseudo-random bytes (SplitMix64).
fn noise(n: usize, seed: u64) -> Vec<u8> {
    let mut z = seed;
    (0..n)
        .map(|_| {
            z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut x = z;
            x = (x ^ (x >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            x = (x ^ (x >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            (x ^ (x >> 31)) as u8
        })
        .collect()
}

/// A photo-like image's packed samples: a smooth gradient per channel plus noise of
/// `amplitude` levels (0: smooth), `bytes` per sample.
fn picture(w: usize, h: usize, c: usize, bytes: usize, amplitude: u8, seed: u64) -> Vec<u8> {
    let n = noise(w * h * c, seed);
    let mut out = Vec::with_capacity(w * h * c * bytes);
    for (i, &r) in n.iter().enumerate() {
        let (x, y, k) = ((i / c) % w, i / c / w, i % c);
        let base = (x * 40 / w.max(1) + y * 100 / h.max(1) + k * 30) as i32;
        let v = (base + if amplitude > 0 { i32::from(r % (2 * amplitude + 1)) - i32::from(amplitude) } else { 0 }).clamp(0, 255);
        if bytes == 2 {
            out.extend_from_slice(&((v as u16) << 8 | (r as u16 & 0x3f)).to_be_bytes());
        } else {
            out.push(v as u8);
        }
    }
    out
}

fn colour(c: usize) -> png::ColorType {
    [png::ColorType::Grayscale, png::ColorType::GrayscaleAlpha, png::ColorType::Rgb, png::ColorType::Rgba][c - 1]
}

fn depth(bytes: usize) -> png::BitDepth {
    if bytes == 2 { png::BitDepth::Sixteen } else { png::BitDepth::Eight }
}

/// `samples` (w x h, c channels, `bytes` per sample) encoded here with bands of about
/// `band_bytes`.
fn encoded(samples: &[u8], w: usize, h: usize, c: usize, bytes: usize, band_bytes: usize) -> Vec<u8> {
    let row = w * c * bytes;
    let mut file = Vec::new();
    encode_bands(&mut file, w as u32, h as u32, colour(c), depth(bytes), band_bytes, |y, dst: &mut [u8]| {
        dst.copy_from_slice(&samples[y * row..][..dst.len()]);
    })
    .unwrap();
    file
}

/// The same samples through the `png` crate's encoder as `encode_png` used it before
/// (its stream writer, `Compression::Fast`: fdeflate, `Filter::Adaptive`).
fn encoded_by_png_crate(samples: &[u8], w: usize, h: usize, c: usize, bytes: usize) -> Vec<u8> {
    let mut file = Vec::new();
    let mut enc = png::Encoder::new(&mut file, w as u32, h as u32);
    enc.set_color(colour(c));
    enc.set_depth(depth(bytes));
    enc.set_compression(png::Compression::Fast);
    enc.set_filter(png::Filter::Adaptive);
    let mut writer = enc.write_header().unwrap();
    let mut stream = writer.stream_writer().unwrap();
    stream.write_all(samples).unwrap();
    stream.finish().unwrap();
    drop(writer);
    file
}

/// Decoded by the `png` crate: the samples.
fn decoded(file: &[u8]) -> Vec<u8> {
    let mut reader = png::Decoder::new(std::io::Cursor::new(file)).read_info().unwrap();
    let mut out = vec![0u8; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut out).unwrap();
    out
}

/// The IDAT chunks' data, concatenated (the zlib stream), the chunk CRCs checked.
fn zlib_stream(file: &[u8]) -> Vec<u8> {
    let mut z = Vec::new();
    let mut i = 8;
    while i + 12 <= file.len() {
        let len = u32::from_be_bytes(file[i..i + 4].try_into().unwrap()) as usize;
        let (kind, data) = (&file[i + 4..i + 8], &file[i + 8..i + 8 + len]);
        let crc = u32::from_be_bytes(file[i + 8 + len..i + 12 + len].try_into().unwrap());
        assert_eq!(crc32(&[kind, data].concat()), crc, "chunk CRC");
        if kind == b"IDAT" {
            z.extend_from_slice(data);
        }
        i += 12 + len;
    }
    z
}

/// Bitwise CRC-32 (PNG's), independent of the `png` crate's.
fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in data {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xEDB8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// Adler-32 by its definition.
fn adler32_slow(data: &[u8]) -> u32 {
    let (mut a, mut b) = (1u32, 0u32);
    for &x in data {
        a = (a + u32::from(x)) % 65521;
        b = (b + a) % 65521;
    }
    b << 16 | a
}

/// Every depth and channel count, odd sizes, one row, one column, one pixel, and bands
/// of one row to many: the `png` crate decodes the samples exactly; the zlib stream is
/// valid for an independent decoder (miniz_oxide), with the right Adler-32; and the
/// filtered bytes are the `png` crate's own (the same adaptive filter choice).
#[test]
fn round_trip_and_stream_match_the_png_crate() {
    for (w, h) in [(1, 1), (1, 9), (9, 1), (13, 37), (64, 3), (200, 20)] {
        for c in 1..=4 {
            for bytes in [1, 2] {
                let samples = picture(w, h, c, bytes, 3, (w * 131 + h * 7 + c) as u64);
                for band_bytes in [1, 100, 4096, BAND_BYTES] {
                    let what = format!("{w}x{h}x{c}, {} bits, bands of {band_bytes} bytes", 8 * bytes);
                    let file = encoded(&samples, w, h, c, bytes, band_bytes);
                    assert!(decoded(&file) == samples, "{what}: round trip");
                    let z = zlib_stream(&file);
                    assert_eq!(&z[..2], &[0x78, 0x01], "{what}: zlib header");
                    let filtered = miniz_oxide::inflate::decompress_to_vec_zlib(&z).unwrap_or_else(|e| panic!("{what}: {e:?}"));
                    assert_eq!(u32::from_be_bytes(z[z.len() - 4..].try_into().unwrap()), adler32_slow(&filtered), "{what}: Adler-32");
                    let theirs =
                        miniz_oxide::inflate::decompress_to_vec_zlib(&zlib_stream(&encoded_by_png_crate(&samples, w, h, c, bytes)))
                            .unwrap();
                    assert!(filtered == theirs, "{what}: filtered bytes differ from the png crate's");
                }
            }
        }
    }
}

/// The same bytes whatever the thread count: pools of 1 and 3 threads, and this thread
/// outside any pool.
#[test]
fn output_is_the_same_for_any_thread_count() {
    let (w, h, c) = (150, 60, 3);
    for bytes in [1, 2] {
        let samples = picture(w, h, c, bytes, 4, 5);
        let outside = encoded(&samples, w, h, c, bytes, 2000);
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let inside = pool.install(|| encoded(&samples, w, h, c, bytes, 2000));
            assert!(inside == outside, "{threads} threads, {} bits", 8 * bytes);
        }
    }
}

/// No bigger than the `png` crate's fdeflate file (what `encode_png` wrote before) by
/// more than 2 %, on a noisy picture, a smooth one and a flat one, with small bands (every
/// symbol counted) and the real ones (a sampled histogram); in practice smaller on noisy
/// data (the code fitted per block: -21 % on the io_timing photo).
#[test]
fn size_is_within_2_percent_of_fdeflate() {
    let (w, h) = (256, 256);
    for (name, amplitude) in [("noisy", 6), ("smooth", 0), ("flat", 255)] {
        for bytes in [1, 2] {
            let samples = if amplitude == 255 { vec![77u8; w * h * 3 * bytes] } else { picture(w, h, 3, bytes, amplitude, 9) };
            let theirs = encoded_by_png_crate(&samples, w, h, 3, bytes).len();
            for band_bytes in [16 << 10, BAND_BYTES] {
                let file = encoded(&samples, w, h, 3, bytes, band_bytes);
                assert!(decoded(&file) == samples, "{name}, {} bits: round trip", 8 * bytes);
                let ours = file.len();
                assert!(
                    ours as f64 <= theirs as f64 * 1.02,
                    "{name}, {} bits, bands of {band_bytes}: {ours} bytes against fdeflate's {theirs}",
                    8 * bytes
                );
            }
        }
    }
}

/// A row longer than a block ([`BLOCK_BYTES`]) is split into several blocks of one band.
#[test]
fn long_rows_take_several_blocks() {
    let (w, h) = (BLOCK_BYTES / 3 + 1000, 2);
    let samples = picture(w, h, 3, 1, 2, 4);
    let file = encoded(&samples, w, h, 3, 1, BAND_BYTES);
    assert!(decoded(&file) == samples);
    let filtered = miniz_oxide::inflate::decompress_to_vec_zlib(&zlib_stream(&file)).unwrap();
    assert_eq!(filtered.len(), h * (3 * w + 1));
}

/// Incompressible rows go into stored blocks: the file is the samples plus a few bytes,
/// with small blocks and sampled ones.
#[test]
fn noise_is_stored() {
    let (w, h) = (300, 200);
    let samples = noise(w * h * 4, 3);
    for band_bytes in [32 << 10, BAND_BYTES] {
        let file = encoded(&samples, w, h, 4, 1, band_bytes);
        assert!(decoded(&file) == samples);
        let overhead = file.len() as f64 / (samples.len() + h) as f64;
        assert!(overhead < 1.002, "{} bytes for {} filtered", file.len(), samples.len() + h);
    }
}

/// zlib's combination equals the checksum of the concatenation, at lengths around and
/// above the modulus.
#[test]
fn adler32_combines() {
    let data = noise(200_000, 1);
    for split in [0, 1, 65520, 65521, 65522, 131_100, 200_000] {
        let (a, b) = data.split_at(split);
        assert_eq!(adler32_combine(adler32_slow(a), adler32_slow(b), b.len() as u64), adler32_slow(&data), "split at {split}");
    }
}

/// Skewed counts (Fibonacci: an unlimited code would be 29 bits deep) stay within the
/// limit and complete (Kraft sum exactly 1); so do two symbols and flat histograms.
#[test]
fn huffman_lengths_are_limited_and_complete() {
    let mut fib = vec![1u32, 1];
    while fib.len() < 30 {
        fib.push(fib[fib.len() - 1] + fib[fib.len() - 2]);
    }
    let cases = [
        (fib[..19].to_vec(), MAX_CL_BITS),
        (vec![5, 0, 1], MAX_CL_BITS),
        (vec![3; 19], MAX_CL_BITS),
        (fib, MAX_CODE_BITS),
        (vec![3; LITLEN], MAX_CODE_BITS),
        ((0..LITLEN).map(|i| (i * i % 97) as u32).collect(), MAX_CODE_BITS),
    ];
    for (freq, limit) in cases {
        let mut lens = vec![0u8; freq.len()];
        huffman_lengths(&freq, limit, &mut lens);
        assert!(lens.iter().zip(&freq).all(|(&l, &f)| (l > 0) == (f > 0) && l as usize <= limit), "{lens:?}");
        let kraft: f64 = lens.iter().filter(|&&l| l > 0).map(|&l| 0.5f64.powi(l as i32)).sum();
        assert!((kraft - 1.0).abs() < 1e-12, "Kraft sum {kraft} for {lens:?}");
    }
}

/// An empty image is an error, not a division by zero.
#[test]
fn empty_image_is_an_error() {
    for (w, h) in [(0, 5), (5, 0)] {
        let e = encode(Vec::new(), w, h, colour(1), depth(1), |_, _: &mut [u8]| {}).unwrap_err();
        assert!(e.contains(&format!("{w}x{h}")), "{e}");
    }
}

/// A writer that fails after `left` bytes.
struct Failing {
    left: usize,
}

impl Write for Failing {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        if self.left == 0 {
            return Err(std::io::Error::other("disk full"));
        }
        let n = buf.len().min(self.left);
        self.left -= n;
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// A write error mid-image comes back as an error (the other bands abandoned, no hang).
#[test]
fn write_error_is_returned() {
    let (w, h) = (100, 400);
    let samples = picture(w, h, 3, 1, 4, 2);
    for left in [0, 10, 100, 5000] {
        let e = encode_bands(Failing { left }, w as u32, h as u32, colour(3), depth(1), 1000, |y, dst: &mut [u8]| {
            dst.copy_from_slice(&samples[y * w * 3..][..dst.len()]);
        })
        .unwrap_err();
        assert!(e.starts_with("PNG encoder failed") && e.contains("disk full"), "{e}");
    }
}
