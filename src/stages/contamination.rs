//! Which pixels just outside the foreground's matte carry foreground colour.
//!
//! A matte rarely ends exactly where the subject's colour does (estimated mattes, resampled
//! photos, lens softness), so the background fill used to replace a fixed band of `dilate`
//! pixels around it. That band also held visible background light: a highlight one pixel from
//! a thin bar vanished with its bokeh disk (issue 12). Here each band pixel is tested instead:
//! it is contaminated when a mix `B + t·(F - B)` of a nearby clean background colour `B` and
//! the nearby foreground colour `F`, with a visible share `t`, explains its colour much better
//! than any nearby clean background colour alone. Clean background (textured or not) and
//! colours no mix explains, such as a highlight, are kept.

use crate::image::Image;
use rayon::prelude::*;

/// Alpha from which a pixel's colour is taken as foreground colour.
pub const SOLID_ALPHA: f32 = 0.9;
/// Smallest share `t` of foreground colour that counts as contamination (a tenth of the
/// foreground/background difference is about the visible limit of a halo).
pub const MIN_MIX: f32 = 0.1;
/// A mix must explain the colour this much better (distance ratio) than pure background.
pub const BETTER: f32 = 0.5;

/// Median colour of the pixels of `rgb` in the square window of half-size `r` around `(x, y)`
/// that `take` accepts, per channel; None if none does. `scratch` is reused between calls.
fn window_median(
    rgb: &Image,
    (x, y): (usize, usize),
    r: usize,
    take: impl Fn(usize) -> bool,
    scratch: &mut [Vec<f32>; 3],
) -> Option<[f32; 3]> {
    for s in scratch.iter_mut() {
        s.clear();
    }
    for j in window(rgb, (x, y), r).filter(|&j| take(j)) {
        for (c, s) in scratch.iter_mut().enumerate() {
            s.push(rgb.data[j * 3 + c]);
        }
    }
    let [r, g, b] = scratch;
    Some([super::mask::median(r)?, super::mask::median(g)?, super::mask::median(b)?])
}

/// Pixel indices of the square window of half-size `r` around `(x, y)`, clipped to the image.
fn window(img: &Image, (x, y): (usize, usize), r: usize) -> impl Iterator<Item = usize> {
    let (w, h) = (img.width, img.height);
    (y.saturating_sub(r)..(y + r + 1).min(h)).flat_map(move |yy| (x.saturating_sub(r)..(x + r + 1).min(w)).map(move |xx| yy * w + xx))
}

/// Squared distance between two colours.
fn sq_dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>()
}

/// Squared distance from `c` to the mixes `b + t·(f - b)`, `t` in [`MIN_MIX`, 1].
fn sq_dist_to_mix(c: [f32; 3], b: [f32; 3], f: [f32; 3]) -> f32 {
    let v: [f32; 3] = std::array::from_fn(|k| f[k] - b[k]);
    let vv: f32 = v.iter().map(|x| x * x).sum();
    let t = if vv > 0.0 { ((0..3).map(|k| (c[k] - b[k]) * v[k]).sum::<f32>() / vv).clamp(MIN_MIX, 1.0) } else { MIN_MIX };
    sq_dist(c, std::array::from_fn(|k| b[k] + t * v[k]))
}

/// Whether colour `c` is a visible mix of foreground colour `f` into one of the background
/// colours `bg`: its distance to the nearest such mix is below [`BETTER`] times its distance to
/// the nearest background colour. A colour within 1% of a background colour is clean. (The
/// nearest distance is the root of the least squared one: the root is monotonic and correctly
/// rounded, so one root per minimum gives the bits of a root per colour.)
pub fn is_mix(c: [f32; 3], f: [f32; 3], bg: &[[f32; 3]]) -> bool {
    let d_bg = bg.iter().map(|&b| sq_dist(c, b)).fold(f32::INFINITY, f32::min).sqrt();
    let scale = c.iter().map(|x| x.abs()).sum::<f32>() / 3.0;
    if d_bg <= 0.01 * scale + 1e-5 {
        return false;
    }
    let d_mix = bg.iter().map(|&b| sq_dist_to_mix(c, b, f)).fold(f32::INFINITY, f32::min).sqrt();
    d_mix < BETTER * d_bg
}

/// Tests the `band` pixels (indices into `rgb`, linear RGB 3 channels): true where the pixel is
/// contaminated by the foreground. `F` is the median colour of the pixels with alpha at least
/// [`SOLID_ALPHA`] within `band_width + 3` px, the background colours those of the pixels
/// `clean(index)` accepts within `2·band_width + 3` px (square windows). A pixel with no such `F` or background
/// nearby cannot be judged and counts as contaminated (the conservative answer: it is
/// re-synthesized). Cost: per band pixel one window median and one pass over up to
/// (4·band_width + 7)² background samples, in parallel; allocates the answer.
pub fn contaminated(rgb: &Image, alpha: &Image, clean: impl Fn(usize) -> bool + Sync, band: &[usize], band_width: f32) -> Vec<bool> {
    let w = rgb.width;
    let rf = band_width.max(0.0).ceil() as usize + 3;
    let rb = 2 * band_width.max(0.0).ceil() as usize + 3;
    let colour = |j: usize| -> [f32; 3] { std::array::from_fn(|k| rgb.data[j * 3 + k]) };
    band.par_iter()
        .map_init(
            || ([Vec::new(), Vec::new(), Vec::new()], Vec::new()),
            |(scratch, bg), &i| {
                let xy = (i % w, i / w);
                let Some(f) = window_median(rgb, xy, rf, |j| alpha.data[j] >= SOLID_ALPHA, scratch) else { return true };
                bg.clear();
                bg.extend(window(rgb, xy, rb).filter(|&j| clean(j)).map(colour));
                if bg.is_empty() {
                    return true;
                }
                is_mix(colour(i), f, bg)
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each channel's median is its own: pixel `i` of a 3×3 image is `[i, 8 − i, 5·i mod 9]`,
    /// and the window without pixels 0 and 1 has the medians 5, 3 and 4 (of three different
    /// pixels). None when the filter takes no pixel.
    #[test]
    fn window_median_is_taken_per_channel() {
        let data: Vec<f32> = (0..9).flat_map(|i| [i as f32, (8 - i) as f32, ((5 * i) % 9) as f32]).collect();
        let img = Image::from_vec(3, 3, 3, data).unwrap();
        let mut scratch = Default::default();
        assert_eq!(window_median(&img, (1, 1), 1, |j| j > 1, &mut scratch), Some([5.0, 3.0, 4.0]));
        assert_eq!(window_median(&img, (1, 1), 1, |_| false, &mut scratch), None);
        // Clipped to the image: the corner's window is its 2×2 block (pixels 0, 1, 3, 4).
        assert_eq!(window_median(&img, (0, 0), 1, |j| j != 0, &mut scratch), Some([3.0, 5.0, 5.0]));
    }

    /// The distance to the mixes is to the segment `b + t·(f − b)`, `t` in [`MIN_MIX`, 1]:
    /// zero on it, the perpendicular distance beside it, the nearest end's past either end;
    /// where `f` is `b` the one mix is `b` (no 0/0). Found by mutants of the segment's squared
    /// length (`x·x` → `x + x`) and of its zero test (`>` → `>=`: NaN) that no test met.
    #[test]
    fn distance_to_the_mixes_is_to_the_segment() {
        let (b, f) = ([0.1f32, 0.2, 0.3], [0.9f32, 0.6, 0.3]);
        let at = |t: f32| -> [f32; 3] { std::array::from_fn(|k| b[k] + t * (f[k] - b[k])) };
        assert!(sq_dist_to_mix(at(0.5), b, f) < 1e-12);
        // 0.1 off the segment along z, perpendicular to f − b = (0.8, 0.4, 0).
        let beside = {
            let p = at(0.6);
            [p[0], p[1], p[2] + 0.1]
        };
        assert!((sq_dist_to_mix(beside, b, f) - 0.01).abs() < 1e-6, "{}", sq_dist_to_mix(beside, b, f));
        assert!((sq_dist_to_mix(at(1.5), b, f) - sq_dist(at(1.5), f)).abs() < 1e-6);
        assert!((sq_dist_to_mix(b, b, f) - sq_dist(b, at(MIN_MIX))).abs() < 1e-7);
        let c = [0.5f32, 0.5, 0.5];
        assert_eq!(sq_dist_to_mix(c, b, b), sq_dist(c, b));
    }

    /// The rule's two bounds, met exactly: a colour 1% of its mean from a background colour
    /// is clean (`≤`), though it lies on the mixes; a colour whose distance to the mixes is
    /// exactly [`BETTER`] times its distance to the background is not a mix (`<`). Found by
    /// mutants of the 1% bound and of the comparison that no test met.
    #[test]
    fn the_bounds_of_the_rule_are_as_stated() {
        let b = [0.5f32, 0.5, 0.5];
        let f = [0.53f32, 0.5, 0.5];
        // On the mixes (t ≈ 0.17) at 1% of its own mean from `b`: clean, and a mix 2% away.
        let delta = 0.005 / (1.0 - 0.01 / 3.0);
        assert!(!is_mix([0.5 + delta, 0.5, 0.5], f, &[b]), "1% from the background");
        assert!(is_mix([0.5 + 2.0 * delta, 0.5, 0.5], f, &[b]), "2% from the background");
        assert!(!is_mix([0.5 + 0.9 * delta, 0.5, 0.5], f, &[b]), "0.9% from the background");
        // Past the foreground colour: the nearest mix is `f` itself, 1 away, and `b` 2 away.
        assert!(!is_mix([2.0, 0.0, 0.0], [1.0, 0.0, 0.0], &[[0.0; 3]]), "exactly BETTER times");
        assert!(is_mix([1.9, 0.0, 0.0], [1.0, 0.0, 0.0], &[[0.0; 3]]), "below BETTER times");
    }

    /// `contaminated` on one band pixel at (12, 10) of a 40 × 30 frame whose other pixels are
    /// neither solid foreground nor clean background but for the ones placed (offsets from
    /// it): `F` comes from `band_width + 3` px around it and no further, the background from
    /// `2·band_width + 3` (band width 3: 6 and 9 px), both windows centred on the pixel's own
    /// column and row, and colours are read channel by channel. Found by mutants of the two
    /// radii, of the pixel's row (`i / w` → `i % w`) and of a colour's channel index that no
    /// test met.
    #[test]
    fn windows_reach_their_stated_radii() {
        let (w, h, (x, y)) = (40usize, 30usize, (12usize, 10usize));
        let (filler, red, green, blue) = ([0.3f32, 0.6, 0.9], [0.9f32, 0.1, 0.05], [0.1f32, 0.7, 0.2], [0.1f32, 0.2, 0.9]);
        // `placed`: (dx, dy, colour, solid foreground; else clean background).
        let run = |centre: [f32; 3], placed: &[(isize, isize, [f32; 3], bool)]| -> bool {
            let mut rgb = Image::new(w, h, 3);
            (0..w * h).for_each(|j| rgb.data[j * 3..j * 3 + 3].copy_from_slice(&filler));
            let mut alpha = Image::new(w, h, 1);
            let mut clean = vec![false; w * h];
            rgb.pixel_mut(x, y).copy_from_slice(&centre);
            for &(dx, dy, c, solid) in placed {
                let j = (y as isize + dy) as usize * w + (x as isize + dx) as usize;
                rgb.data[j * 3..j * 3 + 3].copy_from_slice(&c);
                if solid {
                    alpha.data[j] = 1.0;
                } else {
                    clean[j] = true;
                }
            }
            contaminated(&rgb, &alpha, |j| clean[j], &[y * w + x], 3.0)[0]
        };
        // The background colour itself 9 px above: clean. 12 px right: no background, so
        // contaminated.
        assert!(!run(blue, &[(-1, 0, red, true), (0, -9, blue, false)]), "background 9 px above");
        assert!(run(blue, &[(-1, 0, red, true), (12, 0, blue, false)]), "background 12 px right");
        // The foreground 6 px away makes a half-red pixel a mix; 8 px away none is found and
        // a blue one counts as contaminated, as it would not with that foreground.
        let half = std::array::from_fn(|k| 0.5 * (red[k] + green[k]));
        assert!(run(half, &[(6, 0, red, true), (-2, 0, green, false)]), "foreground 6 px right");
        assert!(run(blue, &[(8, 0, red, true), (-2, 0, green, false)]), "foreground 8 px right");
        assert!(!is_mix(blue, red, &[green]));
    }

    #[test]
    fn mixes_and_non_mixes() {
        let (b, f) = ([0.2, 0.3, 0.2], [0.8, 0.1, 0.1]);
        assert!(is_mix([0.5, 0.2, 0.15], f, &[b]), "half-way");
        assert!(!is_mix([0.21, 0.3, 0.2], f, &[b]), "clean background");
        assert!(!is_mix([40.0, 40.0, 40.0], f, &[b]), "a highlight is not a mix");
        // Striped background: the light stripe lies towards the foreground from the dark one,
        // but it is a background colour itself.
        assert!(!is_mix([0.45, 0.25, 0.18], [0.9, 0.2, 0.15], &[[0.1, 0.3, 0.2], [0.45, 0.25, 0.18]]), "texture");
    }

    #[test]
    fn a_halo_is_found_and_a_highlight_kept() {
        // Foreground red on the left (x < 6), background green; column 6 is a halo (half red),
        // except one highlight pixel; column 7 is clean.
        let (w, h) = (16, 9);
        let mut rgb = Image::new(w, h, 3);
        let mut alpha = Image::new(w, h, 1);
        for y in 0..h {
            for x in 0..w {
                let c = match x {
                    0..6 => [0.9, 0.05, 0.05],
                    6 => [0.5, 0.3, 0.05],
                    _ => [0.1, 0.55, 0.05],
                };
                rgb.pixel_mut(x, y).copy_from_slice(&c);
                alpha.data[y * w + x] = if x < 6 { 1.0 } else { 0.0 };
            }
        }
        rgb.pixel_mut(6, 4).copy_from_slice(&[30.0, 30.0, 30.0]);
        let clean: Vec<bool> = (0..w * h).map(|i| i % w >= 8).collect();
        let band: Vec<usize> = (0..h).flat_map(|y| [y * w + 6, y * w + 7]).collect();
        let got = contaminated(&rgb, &alpha, |j| clean[j], &band, 2.0);
        for (k, &i) in band.iter().enumerate() {
            let (x, y) = (i % w, i / w);
            let want = x == 6 && y != 4;
            assert_eq!(got[k], want, "pixel ({x}, {y})");
        }
    }
}
