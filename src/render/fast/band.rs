//! The on-focal band: the targets whose occlusion term is computed, and the interpolation
//! nodes of `B(x, d_x)` over their disparities.
//!
//! Where a target is defocused (`q = 1`) its occlusion is 1 and only the plain scatter `A`
//! matters. Inside the band, `B = F + Σ_k hat_k(d_x)·U_k` with nodes `δ_k` evenly spaced over
//! the band's target disparities; each source is classified once against all nodes
//! ([`Class`]) so the passes skip what adds nothing.
//!
//! The official profile's `B` weighs sources by `g(d_y - d_x)` ([`Side::Front`]). The physical
//! profile uses the same band (targets whose CoC is below `band_coc`, about 2 px) for its
//! in-layer depth groups: the sources in front of a target ([`Side::Front`]) and behind it
//! ([`Side::Behind`], weight `g(d_x - d_y)`), each interpolated over the same nodes.

use super::super::RenderSettings;
use super::super::lens::{STEP_GAIN, in_front};

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

/// Whether a target at relative disparity `d` is in the on-focal band (occlusion on; in the
/// physical profile the band holds the targets that can need in-layer depth groups).
#[inline]
pub(super) fn in_band(d: f32, s: &RenderSettings, band_coc: f32) -> bool {
    s.occlusion && d.abs() * s.blur < band_coc
}

/// Whether a side with `full` full and `out` out sources is cheaper to scatter as its
/// complement (see [`Band::complement_if_cheaper`]).
pub(super) fn complement_pays(full: usize, out: usize) -> bool {
    out < full
}

/// Which sources a band pass collects, by their weight at node `δ`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Side {
    /// Sources in front of the target: `g(d_y - δ)` (the official `B`, the physical front
    /// group).
    Front,
    /// Sources behind the target: `g(δ - d_y)` (the physical behind group).
    Behind,
}

impl Side {
    /// Both sides, in slot order.
    pub(super) const BOTH: [Side; 2] = [Side::Front, Side::Behind];

    /// Index of the side (slot blocks, presence tables).
    pub(super) fn index(self) -> usize {
        self as usize
    }
}

/// The accumulator slot of a band pass with `m` nodes: slot 0 is the plain scatter `A`, then
/// per side (in [`Side::BOTH`] order) its full pass and one partial pass per node `0..m`. The
/// stripes number their own nodes `ka..=kb` from 0, the coarse grids the band's.
#[inline]
pub(super) fn slot(side: Side, node: Option<usize>, m: usize) -> usize {
    1 + side.index() * (1 + m) + node.map_or(0, |k| 1 + k)
}

/// The pass of `slot` (≥ 1) among `m` nodes: its side, and its node (None: the full pass).
#[inline]
pub(super) fn pass_of(slot: usize, m: usize) -> (Side, Option<usize>) {
    let (side, k) = ((slot - 1) / (1 + m), (slot - 1) % (1 + m));
    (Side::BOTH[side], k.checked_sub(1))
}

/// How a source relates to the on-focal band's nodes, on one [`Side`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Class {
    /// Weight `≤ G_EPS` at every node: adds nothing to this side's passes.
    Out,
    /// Weighted per node.
    Partial,
    /// Weight `≥ 1 - G_EPS` at every node: adds its full value once, to the side's full pass.
    Full,
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
    /// Front side: sources with `d ≤ hidden` are [`Class::Out`], with `d ≥ front`
    /// [`Class::Full`]. Behind side: `d ≥ hidden_behind` is out, `d ≤ full_behind` full.
    hidden: f32,
    front: f32,
    hidden_behind: f32,
    full_behind: f32,
    /// Per [`Side`]: whether its passes scatter the complement (weight `1 - g`, see
    /// [`Band::pass_class`]); set from the sources' classes ([`Band::complement_if_cheaper`]).
    complement: [bool; 2],
}

impl Band {
    /// Nodes from `lo` to `hi` (inclusive) at most `node_step` apart.
    pub(super) fn new(lo: f32, hi: f32, node_step: f32) -> Self {
        let n = (((hi - lo) / node_step).ceil() as usize) + 1;
        let step = if n > 1 { (hi - lo) / (n - 1) as f32 } else { 0.0 };
        // g(δ) = ½ + ½·tanh(10(δ - 0.1)) ≤ ε  ⇔  δ ≤ 0.1 - atanh(1 - 2ε)/10; symmetric above.
        let z = (0.5 * ((1.0 - G_EPS) / G_EPS).ln() / 10.0) as f32;
        // g(δ - d) ≤ ε  ⇔  d ≥ δ - 0.1 + z; ≥ 1 - ε  ⇔  d ≤ δ - 0.1 - z.
        Band {
            lo,
            step,
            n,
            hidden: lo + 0.1 - z,
            front: hi + 0.1 + z,
            hidden_behind: hi - 0.1 + z,
            full_behind: lo - 0.1 - z,
            complement: [false; 2],
        }
    }

    /// Disparity `δ_k` of node k.
    // Inline: called per band target and node from the stripes (another module).
    #[inline]
    pub(super) fn node(&self, k: usize) -> f32 {
        self.lo + self.step * k as f32
    }

    /// How a source at relative disparity `d` relates to every node, on `side`.
    #[inline]
    pub(super) fn class(&self, side: Side, d: f32) -> Class {
        let (out, full) = match side {
            Side::Front => (d <= self.hidden, d >= self.front),
            Side::Behind => (d >= self.hidden_behind, d <= self.full_behind),
        };
        if out {
            Class::Out
        } else if full {
            Class::Full
        } else {
            Class::Partial
        }
    }

    /// Scatters the complement of `side` (weight `1 - g`: then its value at a target is `A`
    /// minus the passes) when fewer sources would be full in it than in the side itself
    /// (`full` and `out`: the side's full and out sources): the full pass costs a scatter of
    /// its sources, the out ones are skipped. A layer mostly behind its sharp targets scatters
    /// the few sources not behind them, not the many that are.
    pub(super) fn complement_if_cheaper(&mut self, side: Side, full: usize, out: usize) {
        self.complement[side.index()] = complement_pays(full, out);
    }

    /// Whether the passes of `side` hold its complement.
    #[inline]
    pub(super) fn complemented(&self, side: Side) -> bool {
        self.complement[side.index()]
    }

    /// How a source enters the passes of `side`: [`Band::class`], with full and out swapped
    /// where the side is complemented.
    #[inline]
    pub(super) fn pass_class(&self, side: Side, d: f32) -> Class {
        match (self.class(side, d), self.complemented(side)) {
            (Class::Full, true) => Class::Out,
            (Class::Out, true) => Class::Full,
            (c, _) => c,
        }
    }

    /// A partial source's weight in the passes of `side` at node k: [`Band::weight`], or one
    /// minus it where the side is complemented.
    #[inline]
    pub(super) fn pass_weight(&self, side: Side, k: usize, d: f32) -> f32 {
        let g = self.weight(side, k, d);
        if self.complemented(side) { 1.0 - g } else { g }
    }

    /// A partial source's weight at node k, on `side`: `g(d - δ_k)` in front, `g(δ_k - d)`
    /// behind.
    #[inline]
    pub(super) fn weight(&self, side: Side, k: usize, d: f32) -> f32 {
        match side {
            Side::Front => in_front(d, self.node(k)),
            Side::Behind => in_front(self.node(k), d),
        }
    }

    /// What the passes of `side` hold, interpolated at a target at `d_target`, of a source at
    /// `d_source` with unit value: 1 (full), 0 (out) or `Σ_k hat_k(d_target)·weight_k`.
    pub(super) fn interpolated(&self, side: Side, d_source: f32, d_target: f32) -> f32 {
        match self.class(side, d_source) {
            Class::Out => 0.0,
            Class::Full => 1.0,
            Class::Partial => {
                let (ka, kb) = self.nodes_for(d_target, d_target);
                (ka..=kb).map(|k| self.hat(k, d_target) * self.weight(side, k, d_source)).sum()
            }
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
    use super::super::super::lens::focal_defocus;
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
    fn slots_and_passes_are_inverse() {
        for m in 1..5 {
            let mut seen = vec![false; 1 + 2 * (1 + m)];
            seen[0] = true;
            for side in Side::BOTH {
                for node in std::iter::once(None).chain((0..m).map(Some)) {
                    let s = slot(side, node, m);
                    assert!(!seen[s], "slot {s} twice");
                    seen[s] = true;
                    assert_eq!(pass_of(s, m), (side, node));
                }
            }
            assert!(seen.iter().all(|&v| v));
        }
        // The official layout: F at 1, U_k at 2 + k.
        assert_eq!((slot(Side::Front, None, 3), slot(Side::Front, Some(2), 3)), (1, 4));
    }

    #[test]
    fn classes_bound_the_occlusion_weight_at_every_node() {
        let band = Band::new(-0.02, 0.03, 0.01);
        for i in -400..=400 {
            let d = i as f32 * 0.001;
            for side in Side::BOTH {
                let g: Vec<f32> = (0..band.n).map(|k| band.weight(side, k, d)).collect();
                match band.class(side, d) {
                    Class::Out => assert!(g.iter().all(|&g| g as f64 <= 1.1 * G_EPS), "{side:?} {d}: {g:?}"),
                    Class::Full => assert!(g.iter().all(|&g| g as f64 >= 1.0 - 1.1 * G_EPS), "{side:?} {d}: {g:?}"),
                    Class::Partial => {}
                }
            }
        }
    }

    #[test]
    fn band_threshold_is_where_one_minus_q_reaches_eps() {
        let s = RenderSettings {
            blur: 10.0,
            focus: 0.0,
            lens: 3,
            occlusion: true,
            profile: crate::render::Profile::Official,
            aperture: crate::render::Aperture::DISC,
        };
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
