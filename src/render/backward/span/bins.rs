//! The depth bins the span render interpolates the in-layer depth terms over, and the walk
//! that evaluates their split for a run of targets bin after bin.

use super::BIN_STEP;
use crate::render::lens;

/// The depth bins: centres `δ_b = (first + b)·step`, relative disparity, on one lattice
/// whatever the layer's range (so the interpolation, hence the function, does not depend on
/// which depths are present). One bin without occlusion.
#[derive(Clone, Copy, Debug)]
pub(super) struct Bins {
    pub(super) first: i64,
    pub(super) count: usize,
    pub(super) step: f32,
    pub(super) grouped: bool,
    /// The official profile's split (see [`Bins::shape`]).
    pub(super) official: bool,
}

impl Bins {
    pub(super) fn new(d: &[f32], grouped: bool, official: bool) -> Self {
        if !grouped {
            return Bins { first: 0, count: 1, step: 1.0, grouped, official };
        }
        let (lo, hi) = d.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| (lo.min(v), hi.max(v)));
        let first = (lo / BIN_STEP).floor() as i64;
        let last = ((hi / BIN_STEP).floor() as i64 + 1).max(first + 1);
        Bins { first, count: (last - first + 1) as usize, step: BIN_STEP, grouped, official }
    }

    /// The split of a unit of a source's weight seen from a target, from the two tanh of the
    /// soft depth test (`t_front` for "the source is in front", `t_behind` the reverse), and
    /// its derivative in the source's depth. Physical: the three depth groups
    /// ([`lens::depth_groups_from_tanh`]). Official: `[f, 1, 0]` with `f` the in-front weight
    /// ([`lens::in_front_from_tanh`]): slot 0 sums the light the on-focal occlusion weighs by
    /// `f`, slot 1 all of it (the target mixes them as `(1 - q)·slot 0 + q·slot 1`).
    #[inline(always)]
    pub(super) fn shape(&self, t_front: f32, t_behind: f32) -> ([f32; 3], [f32; 3]) {
        if self.official {
            let (f, df) = lens::in_front_from_tanh(t_front);
            ([f, 1.0, 0.0], [df, 0.0, 0.0])
        } else {
            lens::depth_groups_from_tanh(t_front, t_behind)
        }
    }

    /// Where a target's own source belongs: the surface group (physical), or weight 1 in both
    /// slots (official: the centre tap is never occluded).
    pub(super) fn centre_split(&self) -> [f64; 3] {
        if self.official { [1.0, 1.0, 0.0] } else { [0.0, 1.0, 0.0] }
    }

    /// The centre of bin `b`.
    #[inline]
    pub(super) fn centre(&self, b: usize) -> f32 {
        (self.first + b as i64) as f32 * self.step
    }

    /// The two bins a source at relative disparity `d` is drawn into: `(bin, hat, ∂hat/∂d)`.
    #[inline]
    pub(super) fn locate(&self, d: f32) -> [(usize, f32, f32); 2] {
        if !self.grouped {
            return [(0, 1.0, 0.0), (0, 0.0, 0.0)];
        }
        let u = d / self.step - self.first as f32;
        let b0 = (u.floor().max(0.0) as usize).min(self.count - 2);
        let t = (u - b0 as f32).clamp(0.0, 1.0);
        [(b0, 1.0 - t, -1.0 / self.step), (b0 + 1, t, 1.0 / self.step)]
    }

    /// The group split of a unit of weight in bin `b` seen from a target at `dx`, and its
    /// derivative in the bin's depth (`-∂/∂dx`).
    #[inline]
    pub(super) fn split(&self, b: usize, dx: f32) -> ([f32; 3], [f32; 3]) {
        if self.grouped {
            let c = self.centre(b);
            self.shape(lens::in_front_tanh(c, dx), lens::in_front_tanh(dx, c))
        } else {
            ([0.0, 1.0, 0.0], [0.0; 3])
        }
    }
}

/// The depth-group split of a run of targets, bin after bin: the two tanh of
/// [`lens::depth_groups_from_tanh`] from the factored form ([`lens::in_front_tanh_pair`]): one
/// exp per target per run, one per bin, two divisions per target and bin (the tanh evaluated
/// per target and bin were 45% of a step at 512², K = 30). Where the bins span more than the
/// factored form allows, the tanh are evaluated directly. Only with occlusion (one bin
/// otherwise, split `[0, 1, 0]`).
pub(super) struct Walk {
    pub(super) tx: Vec<f64>,
    pub(super) nb: f64,
    pub(super) bin: usize,
    pub(super) centre: f32,
    pub(super) factored: bool,
}

impl Walk {
    pub(super) fn new(bins: &Bins) -> Self {
        let half = 0.5 * bins.count as f32 * bins.step;
        let centre = bins.centre(0) + half;
        Walk { tx: Vec::new(), nb: 0.0, bin: 0, centre, factored: bins.grouped && half + bins.step < lens::IN_FRONT_FACTORED_MAX }
    }

    /// Starts a run of targets of relative disparities `d`.
    pub(super) fn targets(&mut self, d: &[f32]) {
        if self.factored {
            self.tx.clear();
            self.tx.extend(d.iter().map(|&dx| lens::in_front_target_factor(dx, self.centre)));
        }
    }

    /// Moves to bin `b`.
    pub(super) fn goto(&mut self, bins: &Bins, b: usize) {
        self.bin = b;
        if self.factored {
            self.nb = lens::in_front_neighbour_factor(bins.centre(b), self.centre);
        }
    }

    /// The split of target `x` of the run (relative disparity `dx`) at the current bin and its
    /// derivative in the bin's depth.
    #[inline]
    pub(super) fn split(&self, bins: &Bins, x: usize, dx: f32) -> ([f32; 3], [f32; 3]) {
        if !bins.grouped {
            ([0.0, 1.0, 0.0], [0.0; 3])
        } else if self.factored {
            let (tf, tb) = lens::in_front_tanh_pair(self.nb * self.tx[x]);
            bins.shape(tf, tb)
        } else {
            bins.split(self.bin, dx)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The factored split against the tanh evaluated at every bin, over 101 bins (relative
    /// disparities -1 … 0) and targets across the range: the group weights agree to 1e-6,
    /// their slopes (up to 5) to 5e-6.
    #[test]
    fn walk_is_the_split_evaluated_directly() {
        let d: Vec<f32> = (0..300).map(|i| -1.0 + i as f32 / 299.0 + 0.003 * (i % 7) as f32).collect();
        for official in [false, true] {
            let bins = Bins::new(&d, true, official);
            let mut walk = Walk::new(&bins);
            assert!(walk.factored);
            walk.targets(&d);
            for b in 0..bins.count {
                walk.goto(&bins, b);
                for (x, &dx) in d.iter().enumerate() {
                    let (g, dg) = walk.split(&bins, x, dx);
                    let (want, dwant) = bins.split(b, dx);
                    for k in 0..3 {
                        assert!((g[k] - want[k]).abs() < 1e-6, "bin {b} d {dx}: {g:?} vs {want:?}");
                        assert!((dg[k] - dwant[k]).abs() < 5e-6, "bin {b} d {dx}: {dg:?} vs {dwant:?}");
                    }
                }
            }
        }
        // A range too wide for the factored form falls back to the tanh.
        assert!(!Walk::new(&Bins::new(&[-20.0, 20.0], true, false)).factored);
    }
}
