//! The all-in-focus photo's light as depth from defocus renders it.
//!
//! An integer photo stores every light as white. Rendered from it, a light that the defocused
//! photo shows blurred has far too little light to spread, and the estimate is pulled towards
//! less blur around it (the shared portrait from 8-bit photos: disparity error 0.282 from the
//! linear pair, 0.358 from the 8-bit one). The highlights stage puts the lights back
//! ([`crate::stages::light_recovery`]); the defocused photos then check each one. Blur moves
//! light but makes none, so over a window that holds all a light can spread, a defocused photo
//! shows how much light the clipped photo lacks there. A recovered light brighter than that (a
//! clipped white surface the fit took for a light: the bench's generated scenes are clipped
//! at white before they are traced) is dimmed to it. A window where a defocused photo is
//! clipped too says only "at least": the fit is kept there.

use super::dfd::Shot;
use super::dfd_plan::focus_room;
use crate::color::PhotoEncoding;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::lens::coc_radius;
use crate::stages::highlights::luminance;
use crate::stages::light_recovery::{HighlightsOptions, Recovered, blobs, recover};
use std::borrow::Cow;

/// The all-in-focus photo `aif`, stored with `encoding`, as dfd renders it for the defocused
/// `shots` (blur `blur`, pixels per unit of disparity): an integer photo's clipped lights
/// recovered by the highlights stage (`auto`, its default options; no depth or matte is known
/// yet), each dimmed to the light its surroundings in the shots show (see the module's
/// comment); a linear photo, or one with no light to recover, borrowed as it is. Allocates a
/// copy of the photo and a byte per pixel when it changes it; O(pixels) plus, per recovered
/// light, O(its window · (shots + 1)). Errors: none in practice (those of
/// [`recover`] without occluders or a model); photos that are not RGB of one size (usage).
pub fn aif_light<'a>(aif: &'a Image, encoding: PhotoEncoding, shots: &[Shot], blur: f32) -> Result<Cow<'a, Image>> {
    let shape = |i: &Image| (i.width, i.height, i.channels);
    if let Some(s) = shots.iter().find(|s| shape(s.photo) != shape(aif)).or(shots.first().filter(|_| aif.channels != 3)) {
        let ((w, h, c), (sw, sh, sc)) = (shape(aif), shape(s.photo));
        return Err(Error::usage(format!(
            "the all-in-focus photo is {w}x{h} with {c} channels and a defocused one {sw}x{sh} with {sc}: they must be the same size, RGB"
        )));
    }
    let mut out = match recover(aif, encoding, &HighlightsOptions::default(), &Default::default(), None)? {
        Recovered::Changed(img, _) => img,
        Recovered::Examined(_) | Recovered::Unchanged(_) => return Ok(Cow::Borrowed(aif)),
    };
    let (w, h) = (aif.width, aif.height);
    // The farthest a light spreads in any shot: the largest CoC radius over [0, 1], and a pixel.
    let reach = shots.iter().map(|s| coc_radius(focus_room(s.focus), blur)).fold(0f32, f32::max).ceil() as usize + 2;
    let recovered = out.clone();
    let mut mask: Vec<u8> = recovered.data.chunks_exact(3).zip(aif.data.chunks_exact(3)).map(|(r, a)| (r != a) as u8).collect();
    let (lights, _) = blobs(&mut mask, w, h, usize::MAX);
    for light in lights {
        let (x0, y0, x1, y1) = light.bbox;
        let window = (x0.saturating_sub(reach), y0.saturating_sub(reach), (x1 + reach).min(w - 1), (y1 + reach).min(h - 1));
        let sum = |img: &Image| window_luminance(img, window);
        let base = sum(aif);
        let added = sum(&recovered) - base;
        // What each shot shows beyond the clipped photo; None where it is clipped itself.
        let shown: Option<f64> = shots
            .iter()
            .map(|s| (!clipped_in(s, window)).then(|| sum(s.photo) - base))
            .collect::<Option<Vec<f64>>>()
            .and_then(|v| v.into_iter().reduce(f64::max));
        let Some(shown) = shown else { continue };
        let keep = if added > 0.0 { (shown / added).clamp(0.0, 1.0) as f32 } else { 1.0 };
        if keep < 1.0 {
            for &i in &light.pixels {
                for c in 0..3 {
                    let (a, r) = (aif.data[i * 3 + c], recovered.data[i * 3 + c]);
                    out.data[i * 3 + c] = a + keep * (r - a);
                }
            }
        }
    }
    Ok(Cow::Owned(out))
}

/// Sum of the luminance of `img` over `window` (x0, y0, x1, y1 inclusive).
fn window_luminance(img: &Image, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> f64 {
    (y0..=y1)
        .map(|y| img.data[(y * img.width + x0) * 3..(y * img.width + x1 + 1) * 3].chunks_exact(3).map(|p| luminance(p) as f64).sum::<f64>())
        .sum()
}

/// True when a sample of `shot`'s photo in `window` is at or above its clip level.
fn clipped_in(shot: &Shot, (x0, y0, x1, y1): (usize, usize, usize, usize)) -> bool {
    let Some(clip) = shot.clip else { return false };
    let p = shot.photo;
    (y0..=y1).any(|y| p.data[(y * p.width + x0) * 3..(y * p.width + x1 + 1) * 3].iter().any(|&v| v >= clip))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::bench::inputs::{Input, photo};
    use crate::render::{Aperture, Kernel, Layer, Profile, RenderSettings, render};

    /// Paints lights of `radiance` over RGB `img`: discs of `radius` px centred at `centres`
    /// (pixel centres at +0.5), anti-aliased by 4x4 samples per pixel.
    pub(crate) fn paint_lights(img: &mut Image, centres: &[(f32, f32)], radius: f32, radiance: f32) {
        let w = img.width;
        for (i, px) in img.data.chunks_exact_mut(3).enumerate() {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let inside = |&(cx, cy): &(f32, f32)| {
                (0..16).filter(|k| (x + (k % 4) as f32 / 4.0 + 0.125 - cx).hypot(y + (k / 4) as f32 / 4.0 + 0.125 - cy) <= radius).count()
            };
            let c = centres.iter().map(inside).sum::<usize>() as f32 / 16.0;
            px.iter_mut().for_each(|v| *v = *v * (1.0 - c) + radiance * c);
        }
    }

    /// A light of radiance 4 (a disc 3 px across) on a grey wall at disparity 0.4, clipped in
    /// the 8-bit all-in-focus photo. A defocused photo that shows the light's blur keeps the
    /// light recovered; one that shows no light beyond white has it taken back, to the photo as
    /// stored. A linear photo is borrowed.
    #[test]
    fn a_recovered_light_is_kept_only_where_the_defocused_photo_shows_it() {
        let (w, h) = (40usize, 40usize);
        let (cx, cy) = (20.3f32, 19.6f32);
        let mut linear = Image::filled(w, h, 3, 0.3);
        paint_lights(&mut linear, &[(cx, cy)], 1.5, 4.0);
        let s = RenderSettings {
            blur: 8.0,
            focus: 1.0,
            lens: 2 * (5 + 3) + 1,
            occlusion: true,
            profile: Profile::Physical,
            aperture: Aperture::DISC,
        };
        let layer = Layer::from_parts(&linear, &Image::filled(w, h, 1, 1.0), &Image::filled(w, h, 1, 0.4), "wall").unwrap();
        let blurred = render(&[layer], &s, Kernel::Exact).unwrap();
        let encoding = Input::Srgb8.encoding();
        let (aif8, target8) = (photo(&linear, Input::Srgb8).0.into_owned(), photo(&blurred, Input::Srgb8).0.into_owned());
        let clip = super::super::dfd::clip_level(encoding);
        assert!(target8.data.iter().all(|&v| v < clip.unwrap()), "the defocused light is not clipped");
        let centre = ((cy as usize) * w + cx as usize) * 3;
        let shows = aif_light(&aif8, encoding, &[Shot { photo: &target8, focus: 1.0, clip }], s.blur).unwrap();
        eprintln!("light's centre: photo {}, recovered {}", aif8.data[centre], shows.data[centre]);
        assert!(shows.data[centre] > 2.0, "kept: {}", shows.data[centre]);
        // A defocused photo darker than the clipped one everywhere: no light to spread.
        let dark = Image::from_vec(w, h, 3, aif8.data.iter().map(|v| v.min(0.5)).collect()).unwrap();
        let none = aif_light(&aif8, encoding, &[Shot { photo: &dark, focus: 1.0, clip }], s.blur).unwrap();
        assert_eq!(none.data, aif8.data);
        assert!(matches!(aif_light(&linear, PhotoEncoding::Linear, &[Shot::linear(&blurred, 1.0)], s.blur).unwrap(), Cow::Borrowed(_)));
        // Photos of two sizes: a usage error, not an index out of bounds.
        let small = Image::new(8, 8, 3);
        let e = aif_light(&aif8, encoding, &[Shot::linear(&small, 1.0)], s.blur).unwrap_err().to_string();
        assert!(e.contains("40x40") && e.contains("8x8"), "{e}");
    }
}
