//! Longitudinal chromatic aberration: each colour channel imaged with its own circle of
//! confusion (`Aperture::with_chromatic`).
//!
//! A lens whose focal length depends on wavelength blurs red, green and blue by different
//! amounts. The renderer models it by rendering the whole layer stack once per channel with
//! K scaled by that channel's factor and keeping that channel of each pass: occlusion,
//! visibility and compositing are then each channel's own, as they would be in three
//! monochrome renders, and every kernel (exact, fast, the tracer, the differentiable one)
//! gets it without a second copy of its lens math. It costs three passes instead of one.

use crate::error::Result;
use crate::image::Image;

/// Runs `pass(scale, c)` for each colour channel `c` with that channel's CoC scale
/// (`scales[c]`, see `Aperture::channel_scales`) and returns, for each of the `N` images a
/// pass yields (3 channels each, of one size), channel `c` taken from pass `c`. Holds the
/// result and one pass's images at a time.
pub fn per_channel<const N: usize>(scales: [f32; 3], mut pass: impl FnMut(f32, usize) -> Result<[Image; N]>) -> Result<[Image; N]> {
    let mut out: Option<[Image; N]> = None;
    for (c, &scale) in scales.iter().enumerate() {
        let images = pass(scale, c)?;
        match out.as_mut() {
            None => out = Some(images),
            Some(out) => {
                for (o, img) in out.iter_mut().zip(&images) {
                    debug_assert_eq!((o.width, o.height, o.channels), (img.width, img.height, 3));
                    o.data.chunks_exact_mut(3).zip(img.data.chunks_exact(3)).for_each(|(o, p)| o[c] = p[c]);
                }
            }
        }
    }
    Ok(out.expect("three passes ran"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_channel_comes_from_its_own_pass() {
        let img = |v: f32| Image::from_vec(2, 1, 3, vec![v; 6]).unwrap();
        let mut seen = Vec::new();
        let [a, b] = per_channel([1.1, 1.0, 0.9], |scale, c| {
            seen.push((scale, c));
            Ok([img(c as f32), img(10.0 + c as f32)])
        })
        .unwrap();
        assert_eq!(seen, [(1.1, 0), (1.0, 1), (0.9, 2)]);
        assert_eq!(a.data, [0.0, 1.0, 2.0, 0.0, 1.0, 2.0]);
        assert_eq!(b.data, [10.0, 11.0, 12.0, 10.0, 11.0, 12.0]);
    }

    #[test]
    fn a_failing_pass_fails_the_whole() {
        let r = per_channel::<1>([1.0; 3], |_, c| if c == 1 { Err(crate::Error::usage("no")) } else { Ok([Image::new(1, 1, 3)]) });
        assert!(r.is_err());
    }
}
