//! `Image`: the one pixel container of the library.
//!
//! Row-major, interleaved `f32` channels, row 0 at the top. Values are whatever the producer
//! says (linear radiance, alpha, disparity...); the type carries no colour space. Every stage,
//! loader and kernel works on this one type so that nothing is written twice per pixel type.

/// A `width × height` raster of `channels` interleaved `f32` values per pixel (see the
/// module doc).
#[derive(Clone, Debug, PartialEq)]
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
        let i = self.index(x, y);
        &self.data[i..i + self.channels]
    }

    /// The `channels` values of pixel (x, y), writable; same bounds as [`Image::pixel`].
    #[inline]
    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let i = self.index(x, y);
        let c = self.channels;
        &mut self.data[i..i + c]
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
        self.data.par_chunks_mut(1 << 16).for_each(|c| c.iter_mut().for_each(|v| *v = f(*v)));
    }

    /// True if every value is finite.
    pub fn all_finite(&self) -> bool {
        self.data.iter().all(|v| v.is_finite())
    }
}

impl Image {
    /// Triangle-filter resize of a one-channel image (the `image` crate's: bilinear when
    /// enlarging, the triangle widened by the scale when shrinking); allocates the result.
    /// Values keep their range, whatever it is: the crate clamps f32 samples to [0, 1], which
    /// turned a depth map in metres into a constant and cut HDR highlights to 1, so a map
    /// outside [0, 1] is mapped into it (in f64, by its finite minimum and maximum) and back.
    /// The filter's weights are non-negative and sum to 1, so every output is a convex
    /// combination of inputs and lies within their range. NaN spreads into the outputs it
    /// touches.
    pub fn resized(&self, width: usize, height: usize) -> Image {
        assert_eq!(self.channels, 1, "resized: one channel only");
        let (lo, hi) = self.data.iter().filter(|v| v.is_finite()).fold((0f64, 1f64), |(lo, hi), &v| (lo.min(v as f64), hi.max(v as f64)));
        let inside = (lo, hi) == (0.0, 1.0);
        let span = hi - lo;
        let data = if inside { self.data.clone() } else { self.data.iter().map(|&v| ((v as f64 - lo) / span) as f32).collect() };
        let buf = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(self.width as u32, self.height as u32, data).expect("image size");
        let mut out = image::imageops::resize(&buf, width as u32, height as u32, image::imageops::FilterType::Triangle).into_raw();
        if !inside {
            out.iter_mut().for_each(|u| *u = (lo + *u as f64 * span) as f32);
        }
        Image::from_vec(width, height, 1, out).expect("image size")
    }
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
        // An HDR highlight: its energy survives shrinking (the mean of an 8×8 is kept by a
        // 4×4 of it within the filter's edge handling), and enlarging reaches it.
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
        // Inside [0, 1] the crate's result is untouched.
        let unit = Image::from_vec(3, 1, 1, vec![0.0, 0.25, 1.0]).unwrap();
        let buf = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(3, 1, unit.data.clone()).unwrap();
        let want = image::imageops::resize(&buf, 5, 2, image::imageops::FilterType::Triangle).into_raw();
        assert_eq!(unit.resized(5, 2).data, want);
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
