//! The error measures published depth-from-defocus methods report (DDFF, DefocusNet,
//! AiFDepthNet, DFV, DEReD): AbsRel, RMSE and the δ < 1.25 accuracy, on depth and on inverse
//! depth, so that `bench --dfd` can be read beside their tables.
//!
//! The renderer's maps are normalized disparity (0 the farthest depth, 1 the nearest); a scene
//! that states its depth range `(z_min, z_max)` maps them back to depth
//! `z = 1 / (1/z_max + d·(1/z_min − 1/z_max))`. Estimates are clamped to [0, 1] first: outside
//! it the map names no depth of the scene (and a disparity below `−z_min / (z_max − z_min)`
//! would name a negative depth).

use crate::image::Image;

/// AbsRel, RMSE and δ < 1.25 of one quantity (depth or inverse depth) over the scored pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Errors {
    /// Mean of `|estimate − truth| / truth`.
    pub abs_rel: f64,
    /// Root of the mean squared difference, in the quantity's units (scene units for depth,
    /// their inverse for inverse depth).
    pub rmse: f64,
    /// Fraction of the pixels where `max(estimate / truth, truth / estimate) < 1.25`.
    pub delta1: f64,
}

/// [`Errors`] on depth and on inverse depth.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DepthErrors {
    /// On depth `z`.
    pub depth: Errors,
    /// On inverse depth `1/z` (metric disparity).
    pub inverse: Errors,
}

/// The depth and inverse-depth errors of the normalized disparity map `estimate` against
/// `truth` (one channel each, the same size) for a scene whose depths span `z_range =
/// (z_min, z_max)` (finite, `0 < z_min < z_max`), over the pixels at least `border` from every
/// side. None when no pixel is scored or the range is not such a span.
pub fn depth_errors(estimate: &Image, truth: &Image, z_range: (f64, f64), border: usize) -> Option<DepthErrors> {
    let (z_min, z_max) = z_range;
    if !(z_min > 0.0 && z_max > z_min && z_max.is_finite()) || estimate.data.len() != truth.data.len() {
        return None;
    }
    let span = 1.0 / z_min - 1.0 / z_max;
    let inverse = |d: f32| 1.0 / z_max + (d.clamp(0.0, 1.0) as f64) * span;
    let (w, h) = (truth.width, truth.height);
    let mut sums = [Sums::default(), Sums::default()];
    for y in border..h.saturating_sub(border) {
        for x in border..w.saturating_sub(border) {
            let i = y * w + x;
            let (e, t) = (inverse(estimate.data[i]), inverse(truth.data[i]));
            sums[0].add(1.0 / e, 1.0 / t);
            sums[1].add(e, t);
        }
    }
    Some(DepthErrors { depth: sums[0].errors()?, inverse: sums[1].errors()? })
}

/// Running sums of one quantity's errors.
#[derive(Default)]
struct Sums {
    rel: f64,
    sq: f64,
    within: usize,
    n: usize,
}

impl Sums {
    fn add(&mut self, e: f64, t: f64) {
        self.rel += (e - t).abs() / t;
        self.sq += (e - t) * (e - t);
        self.within += ((e / t).max(t / e) < 1.25) as usize;
        self.n += 1;
    }

    fn errors(&self) -> Option<Errors> {
        let n = self.n as f64;
        (self.n > 0).then(|| Errors { abs_rel: self.rel / n, rmse: (self.sq / n).sqrt(), delta1: self.within as f64 / n })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(v: &[f32]) -> Image {
        Image::from_vec(v.len(), 1, 1, v.to_vec()).unwrap()
    }

    /// Hand-computed on a range 2 … 14 (inverse depths 1/14 … 1/2): disparity 1 is depth 2,
    /// 0 is depth 14, 0.5 is 1 / (1/14 + 0.5·(1/2 − 1/14)) = 3.5.
    #[test]
    fn errors_match_hand_computed_values() {
        let truth = map(&[1.0, 0.0, 0.5, 0.5]);
        let exact = depth_errors(&truth, &truth, (2.0, 14.0), 0).unwrap();
        assert_eq!(exact.depth, Errors { abs_rel: 0.0, rmse: 0.0, delta1: 1.0 });
        assert_eq!(exact.inverse, Errors { abs_rel: 0.0, rmse: 0.0, delta1: 1.0 });
        // Depths 2, 14, 3.5, 3.5 estimated as 3.5, 14, 2, 14 (disparity 2 is clamped to 1).
        let e = depth_errors(&map(&[0.5, 0.0, 2.0, 0.0]), &truth, (2.0, 14.0), 0).unwrap();
        let rel = (1.5 / 2.0 + 0.0 + 1.5 / 3.5 + 10.5 / 3.5) / 4.0;
        let rmse = ((1.5f64 * 1.5 + 0.0 + 1.5 * 1.5 + 10.5 * 10.5) / 4.0).sqrt();
        assert!((e.depth.abs_rel - rel).abs() < 1e-9, "{e:?}");
        assert!((e.depth.rmse - rmse).abs() < 1e-9, "{e:?}");
        // Only the exact pixel is within 1.25 (3.5 / 2 = 1.75, 3.5 / 2 = 1.75, 14 / 3.5 = 4).
        assert_eq!(e.depth.delta1, 0.25);
        // Inverse depth: 1/2, 1/14, 2/7, 2/7 estimated as 2/7, 1/14, 1/2, 1/14.
        let (a, b) = (0.5f64, 2.0 / 7.0);
        let rel = ((a - b) / a + 0.0 + (a - b) / b + (b - 1.0 / 14.0) / b) / 4.0;
        assert!((e.inverse.abs_rel - rel).abs() < 1e-9, "{e:?}");
        // δ is symmetric in the ratio: the same pixels pass on inverse depth.
        assert_eq!(e.inverse.delta1, 0.25);
    }

    #[test]
    fn borders_and_bad_ranges_are_left_out() {
        let truth = map(&[0.3; 9]);
        let mut est = truth.clone();
        est.data[0] = 1.0;
        let square = |i: &Image| Image::from_vec(3, 3, 1, i.data.clone()).unwrap();
        // The corner is the only error; a border of 1 scores the centre alone.
        let e = depth_errors(&square(&est), &square(&truth), (1.0, 10.0), 1).unwrap();
        assert_eq!(e.depth.abs_rel, 0.0);
        assert!(depth_errors(&square(&est), &square(&truth), (1.0, 10.0), 0).unwrap().depth.abs_rel > 0.0);
        assert!(depth_errors(&square(&est), &square(&truth), (1.0, 10.0), 2).is_none(), "nothing scored");
        for bad in [(0.0, 10.0), (5.0, 5.0), (10.0, 1.0), (1.0, f64::INFINITY), (f64::NAN, 2.0)] {
            assert!(depth_errors(&truth, &truth, bad, 0).is_none(), "{bad:?}");
        }
    }
}
