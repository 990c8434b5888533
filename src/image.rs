//! `Image`: the one pixel container of the library.
//!
//! Row-major, interleaved `f32` channels, row 0 at the top. Values are whatever the producer
//! says (linear radiance, alpha, disparity...); the type carries no colour space. Every stage,
//! loader and kernel works on this one type so that nothing is written twice per pixel type.

/// A `width × height` raster of `channels` interleaved `f32` values per pixel (see the
/// module doc).
#[derive(Debug, PartialEq)]
pub struct Image {
    /// Pixels per row.
    pub width: usize,
    /// Rows, top first.
    pub height: usize,
    /// Values per pixel (1 grey/matte/disparity, 3 RGB, 5 layer R,G,B,A,D...).
    pub channels: usize,
    /// `height * width * channels` values, interleaved.
    pub data: Vec<f32>,
}

/// A borrowed `width × height × channels` raster, laid out as [`Image`]: what a pass that only
/// reads needs, whoever owns the values (an [`Image`], or a caller's buffer under a
/// [`crate::render::Layer`]). `Copy`; allocates nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageRef<'a> {
    /// Pixels per row.
    pub width: usize,
    /// Rows, top first.
    pub height: usize,
    /// Values per pixel.
    pub channels: usize,
    /// `height * width * channels` values, interleaved.
    pub data: &'a [f32],
}

impl<'a> From<&'a Image> for ImageRef<'a> {
    fn from(img: &'a Image) -> Self {
        img.as_image_ref()
    }
}

impl<'a> ImageRef<'a> {
    /// True when the image has no pixels (zero width or height).
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }

    /// The `channels` values of pixel (x, y); `x < width`, `y < height` (beyond the data, panics).
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &'a [f32] {
        let i = (y * self.width + x) * self.channels;
        &self.data[i..i + self.channels]
    }

    /// The values copied into an owned [`Image`], block by block in parallel: a 12 MP photo is
    /// ~150 MB, and a serial copy (its page faults included) was ~60 ms of one core on the
    /// end-to-end run's critical path (issue 39). Allocates the copy.
    pub fn to_image(&self) -> Image {
        use rayon::prelude::*;
        let data = if self.data.len() <= BLOCK {
            self.data.to_vec()
        } else {
            // Zeroed pages come from the allocator unwritten; each block's first write faults
            // them in on the thread that copies it.
            let mut data = vec![0f32; self.data.len()];
            data.par_chunks_mut(BLOCK).zip(self.data.par_chunks(BLOCK)).for_each(|(d, s)| d.copy_from_slice(s));
            data
        };
        Image { width: self.width, height: self.height, channels: self.channels, data }
    }

    /// Copies channel `c` out as a one-channel image.
    pub fn channel(&self, c: usize) -> Image {
        assert!(c < self.channels, "channel {c} out of range");
        let data = self.data.iter().skip(c).step_by(self.channels).copied().collect();
        Image { width: self.width, height: self.height, channels: 1, data }
    }

    /// Picks channels by index (in the given order) into a new image.
    pub fn select_channels(&self, which: &[usize]) -> Image {
        let mut out = Image::new(self.width, self.height, which.len());
        for (dst, src) in out.data.chunks_exact_mut(which.len()).zip(self.data.chunks_exact(self.channels)) {
            for (d, &c) in dst.iter_mut().zip(which) {
                *d = src[c];
            }
        }
        out
    }
}

/// Values per parallel block of the whole-image passes (copies, maps, scans): 64 K floats,
/// enough work to outweigh a task's overhead.
const BLOCK: usize = 1 << 16;

/// Copies block by block in parallel ([`ImageRef::to_image`]). Allocates the copy.
impl Clone for Image {
    fn clone(&self) -> Self {
        self.as_image_ref().to_image()
    }
}

impl Image {
    /// A zero-filled image. Allocates `width * height * channels` floats.
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self::filled(width, height, channels, 0.0)
    }

    /// An image with every value `value`. Allocates `width * height * channels` floats.
    pub fn filled(width: usize, height: usize, channels: usize, value: f32) -> Self {
        Image { width, height, channels, data: vec![value; width * height * channels] }
    }

    /// Wraps `data`; returns `None` if its length does not match the shape.
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Option<Self> {
        (data.len() == width * height * channels).then_some(Image { width, height, channels, data })
    }

    /// The image as a borrowed [`ImageRef`].
    pub fn as_image_ref(&self) -> ImageRef<'_> {
        ImageRef { width: self.width, height: self.height, channels: self.channels, data: &self.data }
    }

    /// `width * height` (not counting channels).
    pub fn pixel_count(&self) -> usize {
        self.width * self.height
    }

    /// True when the image has no pixels (zero width or height).
    pub fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0
    }

    /// Index of the first channel of pixel (x, y) in `data`.
    #[inline]
    pub fn index(&self, x: usize, y: usize) -> usize {
        (y * self.width + x) * self.channels
    }

    /// The `channels` values of pixel (x, y); `x < width`, `y < height` (beyond the data, panics).
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[f32] {
        self.as_image_ref().pixel(x, y)
    }

    /// The `channels` values of pixel (x, y), writable; same bounds as [`Image::pixel`].
    #[inline]
    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let i = self.index(x, y);
        let c = self.channels;
        &mut self.data[i..i + c]
    }

    /// Copies channel `c` out as a one-channel image ([`ImageRef::channel`]).
    pub fn channel(&self, c: usize) -> Image {
        self.as_image_ref().channel(c)
    }

    /// Picks channels by index (in the given order) into a new image
    /// ([`ImageRef::select_channels`]).
    pub fn select_channels(&self, which: &[usize]) -> Image {
        self.as_image_ref().select_channels(which)
    }

    /// Stacks images of equal size channel-wise (e.g. RGB + A + D into RGBAD). Parallel over
    /// rows (rayon); allocates the result.
    pub fn stack(parts: &[&Image]) -> Image {
        use rayon::prelude::*;
        let (w, h) = (parts[0].width, parts[0].height);
        assert!(parts.iter().all(|p| p.width == w && p.height == h), "stack: size mismatch");
        let channels = parts.iter().map(|p| p.channels).sum();
        let mut out = Image::new(w, h, channels);
        if w == 0 || channels == 0 {
            return out;
        }
        // Part by part over a row, sample by sample: a `copy_from_slice` of 1 to 3 values per
        // pixel and part was a memcpy call each (8.7% of a one-thread end-to-end render).
        out.data.par_chunks_mut(w * channels).enumerate().for_each(|(y, row)| {
            let mut o = 0;
            for p in parts {
                let c = p.channels;
                let src = &p.data[y * w * c..(y + 1) * w * c];
                let pixels = row.chunks_exact_mut(channels).zip(src.chunks_exact(c.max(1)));
                match c {
                    1 => pixels.for_each(|(dst, s)| dst[o] = s[0]),
                    3 => pixels.for_each(|(dst, s)| {
                        dst[o] = s[0];
                        dst[o + 1] = s[1];
                        dst[o + 2] = s[2];
                    }),
                    _ => pixels.for_each(|(dst, s)| dst[o..o + c].copy_from_slice(s)),
                }
                o += c;
            }
        });
        out
    }

    /// Writes `src` (same channel count) over the rectangle whose top-left corner is (x0, y0);
    /// rows in parallel. Panics if it does not fit.
    pub fn paste(&mut self, src: &Image, x0: usize, y0: usize) {
        use rayon::prelude::*;
        assert!(src.channels == self.channels && x0 + src.width <= self.width && y0 + src.height <= self.height, "paste outside the image");
        let (c, w, sw) = (self.channels, self.width, src.width);
        if sw == 0 || c == 0 {
            return;
        }
        self.data[y0 * w * c..(y0 + src.height) * w * c]
            .par_chunks_exact_mut(w * c)
            .zip(src.data.par_chunks_exact(sw * c))
            .for_each(|(row, s)| row[x0 * c..(x0 + sw) * c].copy_from_slice(s));
    }

    /// Copies the rectangle of `w × h` pixels whose top-left corner is (x0, y0).
    pub fn crop(&self, x0: usize, y0: usize, w: usize, h: usize) -> Image {
        use rayon::prelude::*;
        assert!(x0 + w <= self.width && y0 + h <= self.height, "crop outside the image");
        let c = self.channels;
        let mut out = Image::new(w, h, c);
        if w == 0 || c == 0 {
            return out;
        }
        // Rows in parallel: the pipeline crops frame-sized planes (a 5 MP window of a 12 MP photo).
        out.data.par_chunks_exact_mut(w * c).enumerate().for_each(|(y, row)| {
            let s = self.index(x0, y0 + y);
            row.copy_from_slice(&self.data[s..s + w * c]);
        });
        out
    }

    /// Applies `f` to every value in place; blocks of 64 K values in parallel (rayon).
    pub fn map_inplace(&mut self, f: impl Fn(f32) -> f32 + Sync) {
        use rayon::prelude::*;
        self.data.par_chunks_mut(BLOCK).for_each(|c| c.iter_mut().for_each(|v| *v = f(*v)));
    }

    /// The sum of all values in `f64`: blocks of 64 K values in parallel, their sums added in
    /// order, so the result is the same for any thread count.
    pub fn sum(&self) -> f64 {
        use rayon::prelude::*;
        // Eight running sums per block so that the additions vectorize: one is a chain of
        // dependent adds (~25 ms for a 12 MP photo on 2 cores).
        const LANES: usize = 8;
        let block_sum = |c: &[f32]| -> f64 {
            let mut lanes = [0f64; LANES];
            let whole = c.chunks_exact(LANES);
            let rest: f64 = whole.remainder().iter().map(|&v| v as f64).sum();
            for group in whole {
                for (l, &v) in lanes.iter_mut().zip(group) {
                    *l += v as f64;
                }
            }
            lanes.iter().sum::<f64>() + rest
        };
        let blocks: Vec<f64> = self.data.par_chunks(BLOCK).map(block_sum).collect();
        blocks.iter().sum()
    }

    /// True if every value is finite; blocks of 64 K values in parallel (rayon).
    pub fn all_finite(&self) -> bool {
        use rayon::prelude::*;
        self.data.par_chunks(BLOCK).all(|c| c.iter().all(|v| v.is_finite()))
    }
}

impl ImageRef<'_> {
    /// Triangle-filter resize, any channel count: bilinear when enlarging, the triangle
    /// widened by the scale when shrinking (antialiasing); the same size returns a copy.
    /// Allocates the result and one intermediate (the source's height × the new width).
    /// Every output is a convex combination of inputs (weights ≥ 0, summing to 1), so values
    /// keep any range: written here rather than taken from the `image` crate, whose f32 resize
    /// clamps samples to [0, 1] (that made a depth map in metres a constant and cut HDR
    /// highlights to 1). NaN spreads into the outputs it touches.
    pub fn resized(&self, w: usize, h: usize) -> Image {
        use rayon::prelude::*;
        if (self.width, self.height) == (w, h) {
            return self.to_image();
        }
        let c = self.channels;
        if self.is_empty() || w == 0 || h == 0 {
            return Image::new(w, h, c);
        }
        let tx = taps(self.width, w);
        let ty = taps(self.height, h);
        // Horizontal pass: self.height rows of w pixels.
        let mut tmp = vec![0f32; self.height * w * c];
        tmp.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
            let src = &self.data[y * self.width * c..(y + 1) * self.width * c];
            for (x, (start, ws)) in tx.iter().enumerate() {
                for ch in 0..c {
                    let mut acc = 0f32;
                    for (k, wt) in ws.iter().enumerate() {
                        acc += wt * src[(start + k) * c + ch];
                    }
                    row[x * c + ch] = acc;
                }
            }
        });
        let mut out = Image::new(w, h, c);
        out.data.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
            let (start, ws) = &ty[y];
            for (k, wt) in ws.iter().enumerate() {
                let src = &tmp[(start + k) * w * c..(start + k + 1) * w * c];
                for (o, s) in row.iter_mut().zip(src) {
                    *o += wt * s;
                }
            }
        });
        out
    }
}

impl Image {
    /// Triangle-filter resize ([`ImageRef::resized`]).
    pub fn resized(&self, w: usize, h: usize) -> Image {
        self.as_image_ref().resized(w, h)
    }
}

/// Filter taps of a triangle-filter resize along one axis: for each output index, the first
/// input index and the normalized weights. Downscaling widens the filter (antialiasing).
fn taps(src: usize, dst: usize) -> Vec<(usize, Vec<f32>)> {
    let scale = src as f64 / dst as f64;
    let support = scale.max(1.0);
    (0..dst)
        .map(|o| {
            let center = (o as f64 + 0.5) * scale;
            let lo = ((center - support).floor().max(0.0)) as usize;
            let hi = ((center + support).ceil() as usize).min(src);
            let mut w: Vec<f64> = (lo..hi).map(|i| (1.0 - ((i as f64 + 0.5 - center) / support).abs()).max(0.0)).collect();
            let sum: f64 = w.iter().sum();
            if sum <= 0.0 {
                // Degenerate (tiny source): nearest pixel.
                let i = (center.floor() as usize).min(src - 1);
                return (i, vec![1.0]);
            }
            w.iter_mut().for_each(|v| *v /= sum);
            // Trim zero taps at the ends.
            let first = w.iter().position(|&v| v > 0.0).unwrap_or(0);
            let last = w.iter().rposition(|&v| v > 0.0).unwrap_or(0);
            (lo + first, w[first..=last].iter().map(|&v| v as f32).collect())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Resizing keeps values outside [0, 1] (the `image` crate alone clamps f32 to [0, 1]):
    /// a depth map in metres, an HDR highlight and negative values survive, a 2× box of
    /// equal values is that value, and every output lies within the input's range.
    #[test]
    fn resize_keeps_any_range() {
        // Depth in metres: a 2×-downscale of 2×2 constant blocks gives the blocks' depths.
        let depth = Image::from_vec(4, 2, 1, vec![1.5, 1.5, 8.0, 8.0, 1.5, 1.5, 8.0, 8.0]).unwrap();
        let small = depth.resized(2, 1);
        assert!(small.data.iter().all(|&v| (1.5..=8.0).contains(&v)), "{:?}", small.data);
        assert!(small.data[0] < 4.0 && small.data[1] > 5.5, "{:?}", small.data);
        // An HDR highlight survives shrinking and enlarging (the clamp kept at most 1).
        let mut v = vec![0.5f32; 64];
        v[27] = 40.0;
        let hdr = Image::from_vec(8, 8, 1, v).unwrap();
        let down = hdr.resized(4, 4);
        assert!(down.data.iter().cloned().fold(0f32, f32::max) > 5.0, "{:?}", down.data);
        assert!(hdr.resized(16, 16).data.iter().cloned().fold(0f32, f32::max) > 20.0);
        // Negative values, and a constant outside [0, 1].
        let neg = Image::from_vec(2, 1, 1, vec![-3.0, -1.0]).unwrap().resized(4, 1);
        assert!(neg.data.iter().all(|&v| (-3.0..=-1.0).contains(&v)) && neg.data[0] < neg.data[3], "{:?}", neg.data);
        assert!(Image::filled(5, 3, 1, 4.0).resized(3, 2).data.iter().all(|&v| (v - 4.0).abs() < 1e-6));
        // Any channel count: each channel as if alone (here affine images of one map).
        let one = Image::from_vec(2, 1, 1, vec![0.0, 1.0]).unwrap().resized(3, 2);
        let rgb = Image::from_vec(2, 1, 3, vec![0.0, 10.0, -1.0, 1.0, 20.0, -2.0]).unwrap().resized(3, 2);
        for (i, &v) in one.data.iter().enumerate() {
            let want = [v, 10.0 + 10.0 * v, -1.0 - v];
            for (c, w) in want.iter().enumerate() {
                assert!((rgb.data[i * 3 + c] - w).abs() < 1e-5, "pixel {i} channel {c}: {:?}", rgb.data);
            }
        }
    }

    /// Stacking interleaves the parts' channels pixel by pixel, in order, at any size.
    #[test]
    fn stack_interleaves_the_parts() {
        for (w, h) in [(1usize, 1usize), (7, 3), (64, 5), (0, 4)] {
            let part = |c: usize, base: f32| Image::from_vec(w, h, c, (0..w * h * c).map(|i| base + i as f32).collect()).unwrap();
            let (rgb, a, d) = (part(3, 0.0), part(1, 1000.0), part(1, 2000.0));
            let out = Image::stack(&[&rgb, &a, &d]);
            assert_eq!((out.width, out.height, out.channels), (w, h, 5));
            for i in 0..w * h {
                let want = [rgb.data[3 * i], rgb.data[3 * i + 1], rgb.data[3 * i + 2], a.data[i], d.data[i]];
                assert_eq!(out.data[5 * i..5 * i + 5], want, "{w}x{h} pixel {i}");
            }
        }
    }
}
