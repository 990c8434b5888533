//! A layer of the scene as the renderer sees it.

use crate::error::{Error, Result};
use crate::image::Image;
use rayon::prelude::*;

/// Channel indices of a layer image.
pub const R: usize = 0;
/// Alpha: coverage in [0, 1], not premultiplied into R, G, B.
pub const A: usize = 3;
/// Normalized disparity (1 near … 0 far).
pub const D: usize = 4;

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
        if image.channels != 5 {
            return Err(Error::input(what, format!("a layer needs 5 channels (R,G,B,A,D), found {}", image.channels)));
        }
        if image.is_empty() {
            return Err(Error::input(what, "layer is empty (0 pixels)"));
        }
        if let Some(i) = image.data.iter().position(|v| !v.is_finite()) {
            let px = i / 5;
            return Err(Error::input(
                what,
                format!(
                    "non-finite value in channel {} at pixel ({}, {})",
                    "RGBAD".as_bytes()[i % 5] as char,
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

    /// The 5-channel image (R, G, B, A, D).
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The 5-channel image, without copying.
    pub fn into_image(self) -> Image {
        self.image
    }

    /// Width, pixels.
    pub fn width(&self) -> usize {
        self.image.width
    }

    /// Height, pixels.
    pub fn height(&self) -> usize {
        self.image.height
    }

    /// Alpha of pixel `i` (row-major index), in [0, 1].
    pub fn alpha(&self, i: usize) -> f32 {
        self.image.data[i * 5 + A]
    }

    /// Normalized disparity of pixel `i` (row-major index).
    pub fn disparity(&self, i: usize) -> f32 {
        self.image.data[i * 5 + D]
    }

    /// True if no pixel has alpha > 0: such a layer contributes nothing.
    pub fn is_transparent(&self) -> bool {
        self.image.data.par_chunks_exact(5).all(|px| px[A] <= 0.0)
    }

    /// Per-channel `[min, max]` of the colours of visible pixels (alpha > 0); `[0, 0]` when
    /// nothing is visible.
    pub fn colour_range(&self) -> [[f32; 2]; 3] {
        let empty = [[f32::INFINITY, f32::NEG_INFINITY]; 3];
        let r = self
            .image
            .data
            .par_chunks_exact(5)
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
        self.image.data.par_chunks_exact(5).all(|px| px[A] >= 1.0)
    }

    /// Applies `f` to the colour channels only (e.g. the official naive gamma).
    pub fn map_colors(&mut self, f: impl Fn(f32) -> f32) {
        for px in self.image.data.chunks_exact_mut(5) {
            for c in &mut px[..3] {
                *c = f(*c);
            }
        }
    }
}
