//! `ndarray` views in and out (feature `ndarray`): images, layers and gradients as
//! `(height, width, channels)` arrays, the layout [`Image`] already stores (row-major,
//! channels interleaved), so views and owned conversions are zero-copy; only an array in
//! another memory order is copied once on the way in.
//!
//! ```
//! use drbokeh::Image;
//! use drbokeh::render::{Layer, Profile, RenderSettings, Smoothing, Tape};
//! use ndarray::{Array3, s};
//!
//! // A 6×8 opaque layer: grey, disparity rising left to right.
//! let mut rgbad = Array3::<f32>::from_elem((6, 8, 5), 0.5);
//! rgbad.slice_mut(s![.., .., 3]).fill(1.0);
//! for (x, mut col) in rgbad.slice_mut(s![.., .., 4]).columns_mut().into_iter().enumerate() {
//!     col.fill(x as f32 / 8.0);
//! }
//! let layers = [Layer::from_array(rgbad, "array")?];
//! let s = RenderSettings { blur: 4.0, focus: 0.5, lens: 5, occlusion: true, profile: Profile::Official, aperture: drbokeh::render::Aperture::DISC };
//! let tape = Tape::record(&layers, &s, Smoothing::default())?;
//! assert_eq!(tape.image().view().dim(), (6, 8, 3));
//! let g = tape.vjp(&Image::from_array(Array3::from_elem((6, 8, 3), 1.0)))?;
//! // ∂L/∂disparity of every pixel, as a (6, 8) view into the gradient image.
//! let g_disparity = g.layers[0].view().slice_move(s![.., .., 4]);
//! assert!(g_disparity.iter().all(|v| v.is_finite()));
//! # Ok::<(), drbokeh::Error>(())
//! ```

use crate::error::Result;
use crate::image::{Image, ImageRef};
use crate::render::Layer;
use ndarray::{Array3, ArrayView3, ArrayViewMut3};

impl<'a> ImageRef<'a> {
    /// The values as a `(height, width, channels)` view, zero-copy.
    pub fn view(&self) -> ArrayView3<'a, f32> {
        ArrayView3::from_shape((self.height, self.width, self.channels), self.data).expect("image size")
    }
}

impl Image {
    /// The image as a `(height, width, channels)` view, zero-copy.
    pub fn view(&self) -> ArrayView3<'_, f32> {
        self.as_image_ref().view()
    }

    /// The image as a mutable `(height, width, channels)` view, zero-copy.
    pub fn view_mut(&mut self) -> ArrayViewMut3<'_, f32> {
        ArrayViewMut3::from_shape((self.height, self.width, self.channels), &mut self.data).expect("image size")
    }

    /// The image as an owned `(height, width, channels)` array, zero-copy (the buffer moves).
    pub fn into_array(self) -> Array3<f32> {
        Array3::from_shape_vec((self.height, self.width, self.channels), self.data).expect("image size")
    }

    /// An image from a `(height, width, channels)` array: zero-copy when the array owns a
    /// row-major (standard layout) buffer that it starts at, else one copy in logical order.
    pub fn from_array(a: Array3<f32>) -> Image {
        let (height, width, channels) = a.dim();
        let data = if a.is_standard_layout() {
            let (data, offset) = a.into_raw_vec_and_offset();
            if offset.unwrap_or(0) == 0 && data.len() == height * width * channels {
                data
            } else {
                // A standard-layout slice of a larger buffer: its elements are one
                // contiguous run starting at the offset.
                let start = offset.unwrap_or(0);
                data[start..start + height * width * channels].to_vec()
            }
        } else {
            a.iter().copied().collect()
        };
        Image { width, height, channels, data }
    }
}

impl Layer<'static> {
    /// A layer from a `(height, width, 5)` array of R, G, B, A, D (see
    /// [`crate::render::layer::CHANNELS`]), checked as [`Layer::new`] checks; zero-copy as
    /// [`Image::from_array`].
    pub fn from_array(a: Array3<f32>, what: &str) -> Result<Layer<'static>> {
        Layer::new(Image::from_array(a), what)
    }
}

impl Layer<'_> {
    /// The layer as a `(height, width, 5)` view, zero-copy.
    pub fn view(&self) -> ArrayView3<'_, f32> {
        self.image().view()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndarray::s;

    #[test]
    fn round_trips_share_the_buffer_and_copy_other_orders() {
        let img = Image::from_vec(3, 2, 2, (0..12).map(|v| v as f32).collect()).unwrap();
        let ptr = img.data.as_ptr();
        assert_eq!(img.view()[[1, 2, 1]], 11.0);
        let a = img.into_array();
        assert_eq!(a.as_ptr(), ptr);
        let back = Image::from_array(a);
        assert_eq!(back.data.as_ptr(), ptr);
        assert_eq!((back.width, back.height, back.channels), (3, 2, 2));
        // A transposed (Fortran-order) array is copied in logical order.
        let f = back.clone().into_array().reversed_axes().as_standard_layout().to_owned().reversed_axes();
        assert!(!f.is_standard_layout());
        assert_eq!(Image::from_array(f), back);
        // A standard-layout slice starting past its buffer's start.
        let mut a = back.clone().into_array();
        a.slice_collapse(s![1.., .., ..]);
        let sliced = Image::from_array(a);
        assert_eq!((sliced.width, sliced.height), (3, 1));
        assert_eq!(sliced.data, (6..12).map(|v| v as f32).collect::<Vec<_>>());
    }
}
