//! The on-focal band: the targets whose occlusion term is computed, and the interpolation
//! nodes of `B(x, d_x)` over their disparities.
//!
//! Where a target is defocused (`q = 1`) its occlusion is 1 and only the plain scatter `A`
//! matters. Inside the band, `B = F + Σ_k hat_k(d_x)·U_k` with nodes `δ_k` evenly spaced over
//! the band's target disparities; each source is classified once against all nodes
//! ([`Class`]) so the passes skip what adds nothing.

use super::super::RenderSettings;
use super::super::lens::{Profile, STEP_GAIN};

/// `1 - q` below which a target counts as defocused (occlusion ≡ 1).
const BAND_EPS: f32 = 1e-6;
/// `g` this close to 0 or 1 counts as saturated.
const G_EPS: f64 = 1e-5;

/// `|d|·K` below which a target is in the on-focal band: there `1 - q = exp(-3(|d|·K)²)`
/// exceeds `BAND_EPS`. The band test uses this threshold, never `q` itself, so the survey
/// and the stripes agree without evaluating the exponential twice.
pub(super) fn band_coc() -> f32 {
    ((1.0 / BAND_EPS as f64).ln() / STEP_GAIN as f64).sqrt() as f32
}

/// Whether a target at relative disparity `d` is in the on-focal band (never in the physical
/// profile, which has no on-focal occlusion term).
#[inline]
pub(super) fn in_band(d: f32, s: &RenderSettings, band_coc: f32) -> bool {
    s.occlusion && s.profile == Profile::Official && d.abs() * s.blur < band_coc
}

/// How a source relates to the on-focal band's nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Class {
    /// Behind every node: `g ≤ G_EPS`, adds nothing to `B`.
    Hidden,
    /// Partly occluding: weighted by `g(d - δ_k)` per node.
    Partial,
    /// In front of every node: `g ≥ 1 - G_EPS`, adds its full value to every node.
    Front,
}

/// The interpolation nodes over the band's target disparities `[lo, hi]`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Band {
    /// First node (the lowest target disparity in the band).
    lo: f32,
    /// Node spacing, in disparity (0 for a single node).
    step: f32,
    /// Number of nodes, ≥ 1.
    pub(super) n: usize,
    /// Sources with `d ≤ hidden` are [`Class::Hidden`], with `d ≥ front` [`Class::Front`].
    hidden: f32,
    front: f32,
}

impl Band {
    /// Nodes from `lo` to `hi` (inclusive) at most `node_step` apart.
    pub(super) fn new(lo: f32, hi: f32, node_step: f32) -> Self {
        let n = (((hi - lo) / node_step).ceil() as usize) + 1;
        let step = if n > 1 { (hi - lo) / (n - 1) as f32 } else { 0.0 };
        // g(δ) = ½ + ½·tanh(10(δ - 0.1)) ≤ ε  ⇔  δ ≤ 0.1 - atanh(1 - 2ε)/10; symmetric above.
        let z = (0.5 * ((1.0 - G_EPS) / G_EPS).ln() / 10.0) as f32;
        Band { lo, step, n, hidden: lo + 0.1 - z, front: hi + 0.1 + z }
    }

    /// Disparity `δ_k` of node k.
    // Inline: called per band target and node from the stripes (another module).
    #[inline]
    pub(super) fn node(&self, k: usize) -> f32 {
        self.lo + self.step * k as f32
    }

    /// How a source at relative disparity `d` relates to every node.
    #[inline]
    pub(super) fn class(&self, d: f32) -> Class {
        if d <= self.hidden {
            Class::Hidden
        } else if d >= self.front {
            Class::Front
        } else {
            Class::Partial
        }
    }

    /// Hat-function (linear interpolation) weight of node k at target disparity `d`.
    #[inline]
    pub(super) fn hat(&self, k: usize, d: f32) -> f32 {
        if self.n == 1 { 1.0 } else { (1.0 - ((d - self.node(k)) / self.step).abs()).max(0.0) }
    }

    /// The nodes whose hats are non-zero somewhere in `[a, b]`.
    pub(super) fn nodes_for(&self, a: f32, b: f32) -> (usize, usize) {
        if self.n == 1 {
            return (0, 0);
        }
        let ka = (((a - self.lo) / self.step).floor().max(0.0) as usize).min(self.n - 1);
        let kb = (((b - self.lo) / self.step).ceil().max(0.0) as usize).min(self.n - 1);
        (ka, kb)
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::lens::{focal_defocus, in_front};
    use super::*;

    /// Seeded uniform numbers in [0, 1) (xorshift64*).
    fn uniform(seed: u64) -> impl FnMut() -> f32 {
        let mut x = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    #[test]
    fn hats_sum_to_one_and_interpolate_linearly() {
        let mut u = uniform(15);
        for _ in 0..200 {
            let lo = u() * 2.0 - 1.0;
            let hi = lo + u() * 0.5;
            let band = Band::new(lo, hi, 0.005 + u() * 0.05);
            assert!(band.n >= 1 && (band.node(band.n - 1) - hi).abs() < 1e-5, "{band:?}");
            // A linear function of the node disparity is reproduced exactly between nodes.
            let (a, b) = (u() * 4.0 - 2.0, u() * 4.0 - 2.0);
            for _ in 0..50 {
                let d = lo + (hi - lo) * u();
                let (ka, kb) = band.nodes_for(d, d);
                let all: f32 = (0..band.n).map(|k| band.hat(k, d)).sum();
                let near: f32 = (ka..=kb).map(|k| band.hat(k, d)).sum();
                // f32 rounding of `(d - δ_k)/step`: a few ulps of d, divided by the step.
                let tol = 1e-6 + 4.0 * f32::EPSILON * (d.abs() + lo.abs()) / band.step.max(1e-3);
                assert!((all - 1.0).abs() <= tol, "hats sum to {all} at {d} ({band:?})");
                assert_eq!(all, near, "a hat outside nodes_for is non-zero at {d}");
                let f: f32 = (0..band.n).map(|k| band.hat(k, d) * (a + b * band.node(k))).sum();
                if band.n > 1 {
                    let tol = 2.0 * tol * (a.abs() + b.abs() * (d.abs() + 1.0));
                    assert!((f - (a + b * d)).abs() <= tol, "linear interpolation at {d}: {f} vs {}", a + b * d);
                }
            }
        }
    }

    #[test]
    fn classes_bound_the_occlusion_weight_at_every_node() {
        let band = Band::new(-0.02, 0.03, 0.01);
        for i in -400..=400 {
            let d = i as f32 * 0.001;
            let g: Vec<f32> = (0..band.n).map(|k| in_front(d, band.node(k))).collect();
            match band.class(d) {
                Class::Hidden => assert!(g.iter().all(|&g| g as f64 <= 1.1 * G_EPS), "{d}: {g:?}"),
                Class::Front => assert!(g.iter().all(|&g| g as f64 >= 1.0 - 1.1 * G_EPS), "{d}: {g:?}"),
                Class::Partial => {}
            }
        }
    }

    #[test]
    fn band_threshold_is_where_one_minus_q_reaches_eps() {
        let s = RenderSettings { blur: 10.0, focus: 0.0, lens: 3, occlusion: true, profile: crate::render::Profile::Official };
        let bc = band_coc();
        for i in 0..2000 {
            let d = i as f32 * 1e-4;
            let inside = in_band(d, &s, bc);
            // 1 - q in f64, from the plain formula (f32 `1 - q` is all rounding there).
            let one_minus_q = (-3.0 * (d as f64 * s.blur as f64).powi(2)).exp();
            assert_eq!(inside, d * s.blur < bc);
            if inside {
                assert!(one_minus_q >= 0.99 * BAND_EPS as f64 && focal_defocus(d, s.blur) < 1.0, "{d}: 1 - q = {one_minus_q}");
            } else {
                assert!(one_minus_q <= 1.01 * BAND_EPS as f64, "{d}: 1 - q = {one_minus_q}");
            }
        }
        assert!(!in_band(0.0, &RenderSettings { occlusion: false, ..s }, bc));
    }
}
