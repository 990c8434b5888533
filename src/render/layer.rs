//! A layer of the scene as the renderer sees it.

use crate::error::{Error, Result};
use crate::image::Image;
use rayon::prelude::*;

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

/// An RGBA layer with its own disparity: a 5-channel [`Image`] (R, G, B, A, D).
///
/// Colours are linear light, **not** premultiplied; alpha in [0, 1]; D is normalized
/// disparity (1 near … 0 far, before the focus is subtracted). Layers are ordered front first.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    image: Image,
}

impl Layer {
    /// Checks the shape and that every value is finite. `what` names the source in errors.
    pub fn new(image: Image, what: &str) -> Result<Self> {
        if image.channels != CHANNELS {
            return Err(Error::input(what, format!("a layer needs 5 channels (R,G,B,A,D), found {}", image.channels)));
        }
        if image.is_empty() {
            return Err(Error::input(what, "layer is empty (0 pixels)"));
        }
        // In parallel and without an early exit per value (the loop vectorizes): at 12.2 MP a
        // layer is 61 M values, and a first-hit search on one thread took tens of ms.
        let finite = image.data.par_chunks(1 << 16).all(|c| c.iter().fold(true, |ok, v| ok & v.is_finite()));
        if let Some(i) = (!finite).then(|| image.data.iter().position(|v| !v.is_finite())).flatten() {
            let px = i / CHANNELS;
            return Err(Error::input(
                what,
                format!(
                    "non-finite value in channel {} at pixel ({}, {})",
                    "RGBAD".as_bytes()[i % CHANNELS] as char,
                    px % image.width,
                    px / image.width
                ),
            ));
        }
        Ok(Layer { image })
    }

    /// Builds a layer from linear RGB, alpha and disparity planes of equal size.
    pub fn from_parts(rgb: &Image, alpha: &Image, disparity: &Image, what: &str) -> Result<Self> {
        if (rgb.width, rgb.height) != (alpha.width, alpha.height) || (rgb.width, rgb.height) != (disparity.width, disparity.height) {
            return Err(Error::Internal(format!("{what}: layer parts differ in size")));
        }
        Layer::new(Image::stack(&[rgb, alpha, disparity]), what)
    }

    /// The layer's 5-channel image (see [`CHANNELS`]).
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The layer's 5-channel image, by value.
    pub fn into_image(self) -> Image {
        self.image
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.image.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.image.height
    }

    /// Alpha of pixel `i` (row-major index).
    pub fn alpha(&self, i: usize) -> f32 {
        self.image.data[i * CHANNELS + A]
    }

    /// Normalized disparity of pixel `i` (row-major index), before the focus is subtracted.
    pub fn disparity(&self, i: usize) -> f32 {
        self.image.data[i * CHANNELS + D]
    }

    /// True if no pixel has alpha > 0: such a layer contributes nothing.
    pub fn is_transparent(&self) -> bool {
        self.image.data.par_chunks_exact(CHANNELS).all(|px| px[A] <= 0.0)
    }

    /// Per-channel `[min, max]` of the colours of visible pixels (alpha > 0); `[0, 0]` when
    /// nothing is visible.
    pub fn colour_range(&self) -> [[f32; 2]; 3] {
        let empty = [[f32::INFINITY, f32::NEG_INFINITY]; 3];
        let r = self
            .image
            .data
            .par_chunks_exact(CHANNELS)
            .filter(|px| px[A] > 0.0)
            .fold(
                || empty,
                |mut r, px| {
                    for c in 0..3 {
                        r[c] = [r[c][0].min(px[c]), r[c][1].max(px[c])];
                    }
                    r
                },
            )
            .reduce(|| empty, |a, b| std::array::from_fn(|c| [a[c][0].min(b[c][0]), a[c][1].max(b[c][1])]));
        r.map(|c| if c[0] <= c[1] { c } else { [0.0, 0.0] })
    }

    /// True if every pixel has alpha ≥ 1.
    pub fn is_opaque(&self) -> bool {
        self.image.data.par_chunks_exact(CHANNELS).all(|px| px[A] >= 1.0)
    }

    /// Applies `f` to the colour channels only (e.g. the official naive gamma).
    pub fn map_colors(&mut self, f: impl Fn(f32) -> f32) {
        for px in self.image.data.chunks_exact_mut(CHANNELS) {
            for c in &mut px[..3] {
                *c = f(*c);
            }
        }
    }
}
