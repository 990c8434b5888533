//! A layer of the scene as the renderer sees it.

use crate::error::{Error, Result};
use crate::image::{Image, ImageRef};
use rayon::prelude::*;
use std::borrow::Cow;

/// Channels of a layer pixel: R, G, B (linear light, not premultiplied), A, D. A layer image
/// is row-major, `width·height·CHANNELS` f32, pixel `i` at `data[i·CHANNELS..(i+1)·CHANNELS]`.
pub const CHANNELS: usize = 5;
/// Index of red in a layer pixel; green and blue follow it (`R..R + 3`).
pub const R: usize = 0;
/// Index of alpha in a layer pixel, in [0, 1].
pub const A: usize = 3;
/// Index of normalized disparity in a layer pixel (1 near … 0 far).
pub const D: usize = 4;

/// The largest of a pixel's three colour channels (`px` starts with R, G, B: a layer pixel or
/// a premultiplied `[r·a, g·a, b·a, a]` value).
#[inline(always)]
pub fn max_rgb(px: &[f32]) -> f32 {
    px[R].max(px[R + 1]).max(px[R + 2])
}

/// Pixels per block of the whole-layer scans ([`pixel_blocks`]).
pub const SCAN_BLOCK: usize = 4096;

/// The layer pixels of `data` (a layer image's values, [`CHANNELS`] per pixel) in blocks of
/// [`SCAN_BLOCK`] pixels for rayon, each block scanned by one plain loop: with a parallel item
/// per pixel, rayon's bookkeeping cost more than the test each item made (a 2 MP preview's
/// whole-layer scans were ~10% of its render, 2026-11-28). Block `k` starts at pixel
/// `k·SCAN_BLOCK`.
pub fn pixel_blocks(data: &[f32]) -> rayon::slice::Chunks<'_, f32> {
    data.par_chunks(SCAN_BLOCK * CHANNELS)
}

/// An RGBA layer with its own disparity: a 5-channel image (R, G, B, A, D), row-major,
/// [`CHANNELS`] values per pixel.
///
/// Colours are linear light, **not** premultiplied; alpha in [0, 1]; D is normalized
/// disparity (1 near … 0 far, before the focus is subtracted). Layers are ordered front first.
///
/// A layer owns its pixels ([`Layer::new`], `Layer<'static>`) or borrows them from the caller
/// ([`Layer::borrowed`]: a Python call renders NumPy's buffers in place; copying two 1 MP
/// layers in was most of the call's overhead over the library's render, issue 37). Rendering
/// only reads a layer; [`Layer::map_colors`] copies borrowed pixels first.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer<'a> {
    width: usize,
    height: usize,
    data: Cow<'a, [f32]>,
    /// What the renderer asks of the whole layer on every render (see [`Stats`]).
    stats: Stats,
}

/// A layer's whole-image facts, taken once when it is made (and its colours again when they
/// change): a refocus from built layers asked them per render, each a pass over the layer's
/// memory (the viewer's 2 MP preview spent ~15% of its time in those passes, 2026-11-28).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Stats {
    /// Every value is finite (a layer is made only then).
    finite: bool,
    /// Some pixel has alpha > 0.
    visible: bool,
    /// Every pixel has alpha ≥ 1.
    opaque: bool,
    /// Per channel `[min, max]` of the visible colours (`[+inf, -inf]` when none).
    colours: [[f32; 2]; 3],
    /// `[min, max]` of the visible disparities (`[+inf, -inf]` when none).
    disparity: [f32; 2],
}

impl Stats {
    const EMPTY: Stats = Stats {
        finite: true,
        visible: false,
        opaque: true,
        colours: [[f32::INFINITY, f32::NEG_INFINITY]; 3],
        disparity: [f32::INFINITY, f32::NEG_INFINITY],
    };

    /// The stats of a layer image's values. One parallel pass.
    fn of(data: &[f32]) -> Stats {
        pixel_blocks(data)
            .map(|b| {
                let mut st = Stats::EMPTY;
                for px in b.chunks_exact(CHANNELS) {
                    st.finite &= px.iter().fold(true, |ok, v| ok & v.is_finite());
                    st.opaque &= px[A] >= 1.0;
                    if px[A] > 0.0 {
                        st.visible = true;
                        for c in 0..3 {
                            st.colours[c] = [st.colours[c][0].min(px[R + c]), st.colours[c][1].max(px[R + c])];
                        }
                        st.disparity = [st.disparity[0].min(px[D]), st.disparity[1].max(px[D])];
                    }
                }
                st
            })
            .reduce(|| Stats::EMPTY, Stats::merge)
    }

    fn merge(a: Stats, b: Stats) -> Stats {
        let range = |x: [f32; 2], y: [f32; 2]| [x[0].min(y[0]), x[1].max(y[1])];
        Stats {
            finite: a.finite & b.finite,
            visible: a.visible | b.visible,
            opaque: a.opaque & b.opaque,
            colours: std::array::from_fn(|c| range(a.colours[c], b.colours[c])),
            disparity: range(a.disparity, b.disparity),
        }
    }
}

impl Layer<'static> {
    /// A layer that owns `image`'s pixels. Checks the shape and that every value is finite.
    /// `what` names the source in errors.
    pub fn new(image: Image, what: &str) -> Result<Self> {
        if image.channels != CHANNELS {
            return Err(Error::input(what, format!("a layer needs 5 channels (R,G,B,A,D), found {}", image.channels)));
        }
        Layer::checked(image.width, image.height, Cow::Owned(image.data), what)
    }

    /// Builds a layer from linear RGB, alpha and disparity planes of equal size.
    pub fn from_parts(rgb: &Image, alpha: &Image, disparity: &Image, what: &str) -> Result<Self> {
        if (rgb.width, rgb.height) != (alpha.width, alpha.height) || (rgb.width, rgb.height) != (disparity.width, disparity.height) {
            return Err(Error::Internal(format!("{what}: layer parts differ in size")));
        }
        Layer::new(Image::stack(&[rgb, alpha, disparity]), what)
    }
}

impl<'a> Layer<'a> {
    /// A layer over the caller's pixels (`width·height·`[`CHANNELS`] values, the layout of
    /// [`CHANNELS`]), without a copy; checked as [`Layer::new`] checks.
    pub fn borrowed(width: usize, height: usize, data: &'a [f32], what: &str) -> Result<Self> {
        if width.checked_mul(height).and_then(|n| n.checked_mul(CHANNELS)) != Some(data.len()) {
            return Err(Error::input(
                what,
                format!(
                    "a {width}x{height} layer needs {} values, found {}",
                    width.saturating_mul(height).saturating_mul(CHANNELS),
                    data.len()
                ),
            ));
        }
        Layer::checked(width, height, Cow::Borrowed(data), what)
    }

    /// The one check of both constructors: some pixels, every value finite (one parallel pass
    /// that also takes the stats, without an early exit: at 12.2 MP a layer is 61 M values,
    /// and a first-hit search on one thread took tens of ms).
    fn checked(width: usize, height: usize, data: Cow<'a, [f32]>, what: &str) -> Result<Self> {
        if width == 0 || height == 0 {
            return Err(Error::input(what, "layer is empty (0 pixels)"));
        }
        let stats = Stats::of(&data);
        if let Some(i) = (!stats.finite).then(|| data.iter().position(|v| !v.is_finite())).flatten() {
            let px = i / CHANNELS;
            return Err(Error::input(
                what,
                format!(
                    "non-finite value in channel {} at pixel ({}, {})",
                    "RGBAD".as_bytes()[i % CHANNELS] as char,
                    px % width,
                    px / width
                ),
            ));
        }
        Ok(Layer { width, height, data, stats })
    }

    /// The same layer owning its pixels (a copy when they were borrowed).
    pub fn into_owned(self) -> Layer<'static> {
        Layer { width: self.width, height: self.height, data: Cow::Owned(self.data.into_owned()), stats: self.stats }
    }

    /// The layer's 5-channel image (see [`CHANNELS`]), borrowed.
    pub fn image(&self) -> ImageRef<'_> {
        ImageRef { width: self.width, height: self.height, channels: CHANNELS, data: &self.data }
    }

    /// The layer as a 5-channel [`Image`], by value (no copy when it owns its pixels).
    pub fn into_image(self) -> Image {
        Image::from_vec(self.width, self.height, CHANNELS, self.data.into_owned()).expect("a layer's length is its shape")
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Alpha of pixel `i` (row-major index).
    pub fn alpha(&self, i: usize) -> f32 {
        self.data[i * CHANNELS + A]
    }

    /// Normalized disparity of pixel `i` (row-major index), before the focus is subtracted.
    pub fn disparity(&self, i: usize) -> f32 {
        self.data[i * CHANNELS + D]
    }

    /// True if no pixel has alpha > 0: such a layer contributes nothing.
    pub fn is_transparent(&self) -> bool {
        !self.stats.visible
    }

    /// Per-channel `[min, max]` of the colours of visible pixels (alpha > 0); `[0, 0]` when
    /// nothing is visible.
    pub fn colour_range(&self) -> [[f32; 2]; 3] {
        self.stats.colours.map(|c| if c[0] <= c[1] { c } else { [0.0, 0.0] })
    }

    /// True if every pixel has alpha ≥ 1.
    pub fn is_opaque(&self) -> bool {
        self.stats.opaque
    }

    /// Applies `f` to the colour channels only (e.g. the official naive gamma).
    pub fn map_colors(&mut self, f: impl Fn(f32) -> f32) {
        for px in self.data.to_mut().chunks_exact_mut(CHANNELS) {
            for c in &mut px[..3] {
                *c = f(*c);
            }
        }
        self.stats = Stats::of(&self.data);
    }

    /// `[min, max]` of the disparities of the visible pixels (alpha > 0); None when nothing
    /// is visible. O(1).
    pub fn visible_disparity(&self) -> Option<[f32; 2]> {
        self.stats.visible.then_some(self.stats.disparity)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Aperture, Kernel, Profile, RenderSettings, lens, max_scatter_radius, render};

    /// A `w × h` layer whose pixel `i` is `f(i)`.
    fn layer(w: usize, h: usize, f: impl Fn(usize) -> [f32; CHANNELS]) -> Layer<'static> {
        let data = (0..w * h).flat_map(&f).collect();
        Layer::new(Image::from_vec(w, h, CHANNELS, data).unwrap(), "test").unwrap()
    }

    /// A borrowed layer is the owned one: the same stats, image and render; its checks name
    /// the source (a length that is not the shape's, a non-finite value, no pixels); changing
    /// its colours copies them and leaves the caller's values as they were.
    #[test]
    fn a_borrowed_layer_is_the_owned_one_and_never_writes() {
        let (w, h) = (13, 7);
        let owned = layer(w, h, |i| [0.1 * (i % 7) as f32, 0.5, 2.0, if i % 3 == 0 { 0.0 } else { 1.0 }, 0.3 + 0.01 * i as f32]);
        let values = owned.image().data.to_vec();
        let borrowed = Layer::borrowed(w, h, &values, "caller").unwrap();
        assert_eq!(borrowed, owned);
        assert_eq!(
            (borrowed.colour_range(), borrowed.visible_disparity(), borrowed.is_opaque()),
            (owned.colour_range(), owned.visible_disparity(), owned.is_opaque())
        );
        let s = RenderSettings { blur: 6.0, focus: 0.4, lens: 15, occlusion: true, profile: Profile::Physical, aperture: Aperture::DISC };
        for k in [Kernel::Fast { quality: 2 }, Kernel::Exact] {
            assert_eq!(render(std::slice::from_ref(&borrowed), &s, k).unwrap(), render(std::slice::from_ref(&owned), &s, k).unwrap());
        }
        let mut dim = borrowed.clone();
        dim.map_colors(|c| 0.5 * c);
        assert_eq!(values, owned.image().data, "the caller's values are untouched");
        assert_eq!(dim.into_owned().colour_range(), owned.colour_range().map(|[lo, hi]| [0.5 * lo, 0.5 * hi]));
        let err = |r: Result<Layer<'_>>| r.unwrap_err().to_string();
        assert!(err(Layer::borrowed(w, h + 1, &values, "caller")).contains("caller"));
        assert!(err(Layer::borrowed(w, h + 1, &values, "caller")).contains(&format!(
            "needs {} values, found {}",
            w * (h + 1) * CHANNELS,
            values.len()
        )));
        assert!(err(Layer::borrowed(0, 0, &[], "nothing")).contains("empty"));
        let mut nan = values.clone();
        nan[(2 * w + 5) * CHANNELS + D] = f32::NAN;
        assert!(err(Layer::borrowed(w, h, &nan, "caller")).contains("channel D at pixel (5, 2)"));
        assert!(err(Layer::borrowed(usize::MAX, 3, &values, "caller")).contains("needs"));
    }

    /// The stats taken when a layer is made answer as a pass over its pixels would: a frame
    /// of several scan blocks, hidden pixels with the extreme colours and disparities left out,
    /// the largest scatter radius equal to the largest over the visible pixels at foci inside
    /// and outside their range, and the colours taken again after `map_colors`.
    #[test]
    fn stats_are_the_pixels_own() {
        let (w, h) = (97, 131);
        let px = |i: usize| {
            let t = ((i * 7919) % 1000) as f32 / 1000.0;
            let a = if i.is_multiple_of(5) { 0.0 } else { 0.25 + 0.75 * t };
            // Hidden pixels hold values beyond every visible one.
            if a == 0.0 { [9.0, -9.0, 9.0, 0.0, 5.0] } else { [t, 0.5 * t + 0.1, 2.0 - t, a, 0.2 + 0.6 * t] }
        };
        let l = layer(w, h, px);
        assert!(w * h > 2 * SCAN_BLOCK);
        let shown: Vec<[f32; CHANNELS]> = (0..w * h).map(px).filter(|p| p[A] > 0.0).collect();
        let range = |c: usize| shown.iter().fold([f32::INFINITY, f32::NEG_INFINITY], |r, p| [r[0].min(p[c]), r[1].max(p[c])]);
        assert_eq!(l.colour_range(), [range(0), range(1), range(2)]);
        assert_eq!(l.visible_disparity(), Some(range(D)));
        assert!(!l.is_transparent() && !l.is_opaque());
        for focus in [-0.5, 0.0, 0.2, 0.45, 0.8, 1.3] {
            let brute = shown.iter().map(|p| lens::scatter_radius(p[D] - focus, 30.0)).fold(1.0, f32::max);
            assert_eq!(max_scatter_radius(std::slice::from_ref(&l), 30.0, focus), brute, "focus {focus}");
        }
        let mut dim = l.clone();
        dim.map_colors(|c| 0.5 * c);
        assert_eq!(dim.colour_range(), [range(0), range(1), range(2)].map(|[lo, hi]| [0.5 * lo, 0.5 * hi]));
        // Nothing visible: no range, radius 1; everything opaque.
        let clear = layer(3, 2, |_| [0.3, 0.3, 0.3, 0.0, 0.5]);
        assert!(clear.is_transparent() && clear.visible_disparity().is_none() && clear.colour_range() == [[0.0; 2]; 3]);
        assert_eq!(max_scatter_radius(&[clear], 30.0, 0.0), 1.0);
        assert!(layer(3, 2, |_| [0.3, 0.3, 0.3, 1.0, 0.5]).is_opaque());
    }
}
