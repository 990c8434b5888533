//! Point-like highlights: pixels far brighter than most of their neighbourhood.
//!
//! A fill that averages its surroundings (Telea) carries a small HDR highlight next to the hole
//! across the whole hidden region, where a blurred foreground later reveals it as a bright
//! blob (issue 12: radiance 46 smeared to 8 over a background whose truth peaks at 0.71). The
//! fill therefore does not use these pixels as sources; they stay visible in the layer.

use crate::image::Image;
use rayon::prelude::*;

/// Half-size of the square neighbourhood a pixel is compared with (a 9x9 window). A point
/// source up to ~4 px across covers less than a quarter of it.
pub const WINDOW_HALF: usize = 6;
/// The neighbourhood's reference level: this quantile of its luminance. Above the median so
/// that a bright stripe of a high-contrast texture (half the window) is not a highlight; below
/// 1 - (highlight area share) so that the reference is the surroundings, not the highlight.
pub const REFERENCE_QUANTILE: f32 = 0.75;
/// A highlight is brighter than `RATIO` times its reference plus [`FLOOR`] (linear light).
/// 3x: a clipped highlight (1.0) on a mid-grey surface (0.2) qualifies, a bright texture
/// stripe (0.6 against 0.5) does not.
pub const RATIO: f32 = 3.0;
/// Absolute margin (linear light) so that noise on near-black surfaces is never a highlight.
pub const FLOOR: f32 = 0.05;

/// Rec. 709 luminance of a linear RGB pixel.
#[inline]
pub fn luminance(px: &[f32]) -> f32 {
    0.2126 * px[0] + 0.7152 * px[1] + 0.0722 * px[2]
}

/// Which of the `candidates` (pixel indices) of `rgb` (linear RGB, 3 channels) are point-like
/// highlights: luminance above `RATIO · q + FLOOR`, with `q` the [`REFERENCE_QUANTILE`] of the
/// luminance in the (2·[`WINDOW_HALF`]+1)² window around the pixel (clipped at the borders).
///
/// The quantile is never formed: `l > RATIO·v + FLOOR` holds for every `v` below some bound
/// (float multiplication and addition are monotone), so it holds for the k-th smallest value
/// exactly when it holds for at least k + 1 of the window's values. The window is counted until
/// that is decided (on an ordinary pixel, after the first n - k values that fail). Same answer
/// as a selection of `q`, bit for bit. Cost: per candidate at most one pass over its window
/// (169 values), in parallel; allocates the answer.
pub fn point_highlights(rgb: &Image, candidates: &[usize]) -> Vec<bool> {
    let (w, h) = (rgb.width, rgb.height);
    candidates
        .par_iter()
        .map(|&i| {
            let (x, y) = (i % w, i / w);
            let l = luminance(&rgb.data[i * 3..i * 3 + 3]);
            if l <= FLOOR {
                return false;
            }
            let (ys, xs) =
                (y.saturating_sub(WINDOW_HALF)..(y + WINDOW_HALF + 1).min(h), x.saturating_sub(WINDOW_HALF)..(x + WINDOW_HALF + 1).min(w));
            let n = ys.len() * xs.len();
            // q is the k-th smallest (0-based) of the n values.
            let k = ((n - 1) as f32 * REFERENCE_QUANTILE).round() as usize;
            let (mut below, mut above) = (0, 0);
            for yy in ys {
                let row = &rgb.data[(yy * w + xs.start) * 3..(yy * w + xs.end) * 3];
                for px in row.chunks_exact(3) {
                    if l > RATIO * luminance(px) + FLOOR {
                        below += 1;
                        if below > k {
                            return true;
                        }
                    } else {
                        above += 1;
                        if above >= n - k {
                            return false;
                        }
                    }
                }
            }
            below > k
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(w: usize, h: usize, v: f32) -> Image {
        Image::filled(w, h, 3, v)
    }

    /// The counting test against the plain formula (the quantile by selection), on seeded
    /// random HDR images with sparse bright dots, borders included.
    #[test]
    fn counting_is_the_quantile_formula() {
        let (w, h) = (31, 23);
        let mut s = 3u64;
        let mut rnd = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 24) as f32
        };
        for _ in 0..4 {
            let data = (0..w * h * 3).map(|_| if rnd() < 0.04 { 20.0 * rnd() } else { rnd() * 0.5 }).collect();
            let img = Image::from_vec(w, h, 3, data).unwrap();
            let all: Vec<usize> = (0..w * h).collect();
            let got = point_highlights(&img, &all);
            for &i in &all {
                let (x, y) = (i % w, i / w);
                let l = luminance(img.pixel(x, y));
                let mut win: Vec<f32> = (y.saturating_sub(WINDOW_HALF)..(y + WINDOW_HALF + 1).min(h))
                    .flat_map(|yy| (x.saturating_sub(WINDOW_HALF)..(x + WINDOW_HALF + 1).min(w)).map(move |xx| (xx, yy)))
                    .map(|(xx, yy)| luminance(img.pixel(xx, yy)))
                    .collect();
                let k = ((win.len() - 1) as f32 * REFERENCE_QUANTILE).round() as usize;
                let q = *win.select_nth_unstable_by(k, f32::total_cmp).1;
                assert_eq!(got[i], l > FLOOR && l > RATIO * q + FLOOR, "pixel ({x}, {y})");
            }
        }
    }

    /// "Above" the bound is strict: a pixel exactly at `RATIO · q + FLOOR` is not a highlight,
    /// the next brighter value is (the random images above never meet the bound exactly).
    #[test]
    fn a_pixel_exactly_at_the_bound_is_not_a_highlight() {
        let ground = 0.25f32;
        let bound = RATIO * luminance(&[ground; 3]) + FLOOR;
        // A grey whose luminance is the bound to the last bit, searched among its neighbours.
        let mut g = bound;
        for _ in 0..64 {
            if luminance(&[g; 3]) >= bound {
                break;
            }
            g = g.next_up();
        }
        while luminance(&[g.next_down(); 3]) >= bound {
            g = g.next_down();
        }
        assert_eq!(luminance(&[g; 3]), bound, "no grey meets the bound exactly");
        let (w, h) = (15, 15);
        let centre = 7 * w + 7;
        for (v, want) in [(g, false), (g.next_up(), true)] {
            let mut img = grey(w, h, ground);
            img.data[centre * 3..centre * 3 + 3].fill(v);
            assert_eq!(point_highlights(&img, &[centre]), vec![want], "luminance {} against the bound {bound}", luminance(&[v; 3]));
        }
    }

    /// Rec. 709's weights, each channel's own (the highlight tests use grey pixels, where a
    /// wrong sign on one weight only scales every luminance alike).
    #[test]
    fn luminance_weighs_each_channel_as_rec_709() {
        assert_eq!(luminance(&[1.0, 0.0, 0.0]), 0.2126);
        assert_eq!(luminance(&[0.0, 1.0, 0.0]), 0.7152);
        assert_eq!(luminance(&[0.0, 0.0, 1.0]), 0.0722);
        assert!((luminance(&[2.0, 2.0, 2.0]) - 2.0).abs() < 1e-6);
    }

    #[test]
    fn a_dot_is_a_highlight_a_stripe_is_not() {
        let (w, h) = (20, 20);
        let mut img = grey(w, h, 0.2);
        // A 2x2 dot at (5, 5).
        for (x, y) in [(5, 5), (6, 5), (5, 6), (6, 6)] {
            img.pixel_mut(x, y).fill(8.0);
        }
        // Vertical stripes, 2 px bright / 2 px dark, on the right half.
        for y in 0..h {
            for x in 10..w {
                img.pixel_mut(x, y).fill(if (x / 2) % 2 == 0 { 0.9 } else { 0.1 });
            }
        }
        let all: Vec<usize> = (0..w * h).collect();
        let hl = point_highlights(&img, &all);
        let marked: Vec<usize> = all.iter().copied().filter(|&i| hl[i]).collect();
        assert_eq!(marked, vec![5 * w + 5, 5 * w + 6, 6 * w + 5, 6 * w + 6]);
    }

    #[test]
    fn a_large_bright_area_is_not_point_like() {
        let (w, h) = (24, 24);
        let mut img = grey(w, h, 0.1);
        for y in 4..20 {
            for x in 4..20 {
                img.pixel_mut(x, y).fill(5.0);
            }
        }
        // The centre of a 16x16 bright square is its own surroundings.
        assert!(!point_highlights(&img, &[12 * w + 12])[0]);
    }
}
