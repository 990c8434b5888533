//! Scores along the subject's true outline, where a viewer looks first (issue 42): PSNR over
//! the frame hides a jagged or fringed edge a few pixels wide.
//!
//! - **Outline band**: pixels within [`BAND_PX`] of the true matte's edge (a pixel whose alpha
//!   is strictly between 0 and 1, or whose 4-neighbour lies on the other side of 0.5).
//! - **Range violations**: the fraction of band pixels whose render leaves the range the ground
//!   truth spans in the [`WINDOW_PX`]-radius window around it, in any channel, by more than
//!   [`TOLERANCE`] (sRGB, clipped to [0, 1]). The truth there mixes the subject's and the
//!   background's values as the lens does; a dark fringe or a halo of the wrong side's colour
//!   lies outside every such mix.
//! - **Alpha error**: the mean |α − α_true| over the band, for a method that builds a
//!   foreground matte (the pipeline's front layer).

use super::metrics::srgb;
use crate::image::Image;
use crate::stages::mask::dilate;

/// Half-width of the outline band, pixels.
pub const BAND_PX: f32 = 2.0;
/// Radius (pixels, square window) of the truth's neighbourhood whose range a pixel may span.
pub const WINDOW_PX: usize = 2;
/// How far (sRGB units) a pixel may leave that range before it counts: 4/255.
pub const TOLERANCE: f32 = 4.0 / 255.0;

/// The outline band of a true matte.
pub struct Outline {
    band: Vec<bool>,
    width: usize,
    height: usize,
}

/// A render's scores along the outline.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OutlineScores {
    /// Fraction of band pixels out of the truth's local range (0 … 1; 0 with no band).
    pub violations: f64,
    /// Mean absolute alpha error over the band (methods that build a matte).
    pub alpha_mae: Option<f64>,
}

impl Outline {
    /// The band of `matte` (one channel, [0, 1]).
    pub fn of(matte: &Image) -> Outline {
        let (w, h) = (matte.width, matte.height);
        let a = &matte.data;
        let side = |i: usize| a[i] >= 0.5;
        let edge: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                let soft = a[i] > 0.0 && a[i] < 1.0;
                let cross = (x + 1 < w && side(i) != side(i + 1)) || (y + 1 < h && side(i) != side(i + w));
                let cross_back = (x > 0 && side(i) != side(i - 1)) || (y > 0 && side(i) != side(i - w));
                soft || cross || cross_back
            })
            .collect();
        Outline { band: dilate(&edge, w, h, BAND_PX), width: w, height: h }
    }

    /// Pixels in the band.
    pub fn len(&self) -> usize {
        self.band.iter().filter(|&&b| b).count()
    }

    /// Whether the band is empty (a matte with no edge).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Scores `render` against the truth `gt` (both linear RGB of the matte's size) and, when
    /// given, a matte `alpha` against the true `matte`.
    pub fn score(&self, render: &Image, gt: &Image, alpha: Option<(&Image, &Image)>) -> OutlineScores {
        let n = self.len();
        if n == 0 {
            return OutlineScores { violations: 0.0, alpha_mae: alpha.map(|_| 0.0) };
        }
        let (o, t) = (srgb(render), srgb(gt));
        let (w, h, r) = (self.width, self.height, WINDOW_PX);
        let out_of_range = |i: usize| {
            let (x, y) = (i % w, i / w);
            (0..3).any(|c| {
                let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        let v = t.data[(yy * w + xx) * 3 + c];
                        lo = lo.min(v);
                        hi = hi.max(v);
                    }
                }
                let v = o.data[i * 3 + c];
                v < lo - TOLERANCE || v > hi + TOLERANCE
            })
        };
        let band = || self.band.iter().enumerate().filter(|(_, b)| **b).map(|(i, _)| i);
        let bad = band().filter(|&i| out_of_range(i)).count();
        let alpha_mae = alpha.map(|(a, truth)| band().map(|i| (a.data[i] - truth.data[i]).abs() as f64).sum::<f64>() / n as f64);
        OutlineScores { violations: bad as f64 / n as f64, alpha_mae }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dark_fringe_counts_and_a_mix_does_not() {
        let (w, h) = (32, 16);
        let matte = Image::from_vec(w, h, 1, (0..w * h).map(|i| ((i % w) < 16) as u8 as f32).collect()).unwrap();
        let gt = Image::from_vec(w, h, 3, (0..w * h).flat_map(|i| [if i % w < 16 { 0.8 } else { 0.2 }; 3]).collect()).unwrap();
        let outline = Outline::of(&matte);
        // Band: columns 13..=18 (the edge pair 15|16 grown by 2), every row.
        assert_eq!(outline.len(), 6 * h);
        assert_eq!(outline.score(&gt, &gt, Some((&matte, &matte))), OutlineScores { violations: 0.0, alpha_mae: Some(0.0) });
        // A 50/50 mix on the edge column stays within the local range.
        let mut mixed = gt.clone();
        (0..h).for_each(|y| mixed.pixel_mut(15, y).fill(0.5));
        assert_eq!(outline.score(&mixed, &gt, None).violations, 0.0);
        // A black column on the edge leaves it: one band column of six.
        let mut fringe = gt.clone();
        (0..h).for_each(|y| fringe.pixel_mut(16, y).fill(0.0));
        assert!((outline.score(&fringe, &gt, None).violations - 1.0 / 6.0).abs() < 1e-12);
        // Alpha off by one on one column of the band.
        let mut a = matte.clone();
        (0..h).for_each(|y| a.data[y * w + 16] = 1.0);
        assert!((outline.score(&gt, &gt, Some((&a, &matte))).alpha_mae.unwrap() - 1.0 / 6.0).abs() < 1e-12);
    }
}
