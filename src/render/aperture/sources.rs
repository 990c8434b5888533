//! A layer's sources as a non-disc aperture spreads them in the physical profile's exact
//! kernel: each source's flux norm and each tap's coverage, and for the backward pass their
//! derivatives in the source's circle of confusion. The exact kernel ([`crate::render::exact`])
//! and the differentiable tape (`render::backward::physical`) both read the shape through
//! this type, so the forward the tape differentiates is the kernel's.
//!
//! Conventions as [`Geometry::coverage`]: a tap `(di, dj)` puts the target `(-dj, di)` from
//! the source (y up); a source in front of the focal plane (`d > 0`) shows the shape
//! point-reflected; with a cat's eye each source's light crosses its cut of the lens
//! ([`CatEye::cut`] of its pixel's [`CatEye::offset`], replicated at the border), spread at
//! the whole shape's flux norm, and each target multiplies what reaches it by its gain
//! ([`ShapedSources::target_gain`]).
//!
//! Derivatives: a shape's coverage is an area of the outline (a polygon, a mask, a bubble's
//! weighted area) integrated over pixel squares, continuous in the CoC `r` and smooth between
//! the radii where an outline's vertex or axis-parallel edge crosses a square's side. Its
//! derivative is taken as the central difference of that same coverage over `r·(1 ± 1e-3)`
//! (f64 values, the step measured between the f32 radii actually evaluated) rather than a
//! second, boundary-integral routine per kind of outline: one definition, so the gradient
//! cannot drift from the forward; at a kink it is the mean of the two one-sided slopes.
//! Truncation error ~1e-6 of the slope where smooth. Three coverage evaluations per tap.

use super::shape::{CatEye, CatGains, CutCircle, Geometry, POINT_COC_PX};
use super::{Aperture, Tap};
use rayon::prelude::*;

/// Relative step of the central differences in the CoC.
const STEP: f64 = 1e-3;

/// The shaped sources of one `width × height` layer. Allocates one cut per pixel and a
/// lattice of gains with a cat's eye, nothing otherwise.
pub struct ShapedSources {
    shape: &'static Geometry,
    cat: Option<CatEye>,
    cuts: Option<Vec<[f32; 2]>>,
    gains: Option<CatGains>,
    width: usize,
}

impl ShapedSources {
    /// None for the disc, which the kernels draw with their own radial ramp.
    pub fn new(aperture: Aperture, width: usize, height: usize) -> Option<ShapedSources> {
        let shape = aperture.geometry()?;
        let cat = aperture.cat_eye(width, height);
        let cuts: Option<Vec<[f32; 2]>> =
            cat.map(|c| (0..width * height).into_par_iter().map(|j| c.offset((j % width) as f32, (j / width) as f32)).collect());
        let gains = cat.map(|c| c.gains(shape));
        Some(ShapedSources { shape, cat, cuts, gains, width })
    }

    /// The shape.
    pub fn geometry(&self) -> &'static Geometry {
        self.shape
    }

    /// Whether sources carry cuts (a cat's eye): then coverage depends on the source, not only
    /// on its CoC and side, and cannot be shared in tables.
    pub fn cut(&self) -> bool {
        self.cuts.is_some()
    }

    /// The flux norm of a source of CoC `r` px (see [`Geometry::norm`]): the whole shape's,
    /// with or without a cat's eye (whose targets normalize the light that passes,
    /// [`ShapedSources::target_gain`]).
    pub fn norm(&self, r: f32) -> f32 {
        self.shape.norm(r)
    }

    /// What target `t` (row-major) multiplies the light of the sources reaching it by: a
    /// cat's eye's [`Geometry::cat_gain`] of its pixel, 1 otherwise. A source that stays in
    /// its own pixel takes none ([`ShapedSources::gain_of`]).
    #[inline]
    pub fn target_gain(&self, t: usize) -> f32 {
        self.gains.as_ref().map_or(1.0, |g| g.at(t % self.width, t / self.width))
    }

    /// The factor of a source of CoC `r` at a target of gain `target` ([`Self::target_gain`]):
    /// the gain, but 1 for a source that stays in its own pixel (CoC below [`POINT_COC_PX`]),
    /// which is the target's own light whole, as every ray of an in-focus point lands there.
    #[inline]
    pub fn gain_of(r: f32, target: f32) -> f32 {
        if r < POINT_COC_PX { 1.0 } else { target }
    }

    /// The cut of source `j` of CoC `r` (see [`CatEye::cut`]); None without a cat's eye.
    fn cut_of(&self, j: usize, r: f32, front: bool) -> Option<CutCircle> {
        Some(self.cat?.cut(self.cuts.as_ref()?[j], r, front))
    }

    /// The coverage of tap `t` by source `j` of CoC `r` (see [`Geometry::coverage_cut`]).
    pub fn coverage(&self, j: usize, r: f32, front: bool, t: &Tap) -> f32 {
        self.shape.coverage_cut(r, -t.dj as f32, t.di as f32, front, self.cut_of(j, r, front))
    }

    /// `(norm, ∂norm/∂r)`: the area `A·r²` has the slope `2·A·r`.
    pub fn norm_grad(&self, r: f32) -> (f32, f32) {
        let n = self.shape.norm(r);
        (n, if r < POINT_COC_PX { 0.0 } else { 2.0 * n / r })
    }

    /// `(coverage, ∂coverage/∂r)` of tap `t` by source `j` (central difference, see the
    /// module's comment; a cat's eye's cut moves with `r`).
    pub fn coverage_grad(&self, j: usize, r: f32, front: bool, t: &Tap) -> (f32, f32) {
        let (v, g) = central(r, |r| self.shape.coverage_cut_f64(r, -t.dj as f32, t.di as f32, front, self.cut_of(j, r, front)));
        (v as f32, g as f32)
    }
}

/// `(f(r), f'(r))` by central difference over `r·(1 ± STEP)`, one-sided where the lower point
/// would fall below [`POINT_COC_PX`] (a point source, where the shape's weights jump to its
/// own pixel); 0 below it.
fn central(r: f32, f: impl Fn(f32) -> f64) -> (f64, f64) {
    let v = f(r);
    if r < POINT_COC_PX || !r.is_finite() {
        return (v, 0.0);
    }
    let h = (r as f64 * STEP).max(1e-6);
    let hi = (r as f64 + h) as f32;
    let lo = (r as f64 - h) as f32;
    let lo = if lo < POINT_COC_PX { r } else { lo };
    // The step between the radii actually evaluated (f32), not the one asked for.
    let (fl, fh) = (if lo == r { v } else { f(lo) }, f(hi));
    let dr = hi as f64 - lo as f64;
    (v, if dr > 0.0 { (fh - fl) / dr } else { 0.0 })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::aperture::ShapeSpec;

    /// The derivative agrees with a wide central difference away from kinks, for a rotated
    /// hexagon (no axis-parallel edges), a bubble, and a cat's eye's coverage (its cut moves
    /// with the CoC).
    #[test]
    fn derivatives_in_the_coc_match_wider_differences() {
        let hex = Aperture::new(&ShapeSpec::Blades { n: 6, rotation: 17.0, curvature: 0.0 }, 1.0, "test").unwrap();
        let bubble = Aperture::with_bubble(&ShapeSpec::Blades { n: 7, rotation: 5.0, curvature: 0.4 }, 1.3, 0.5, "test").unwrap();
        let cat =
            Aperture::new(&ShapeSpec::Blades { n: 9, rotation: 3.0, curvature: 0.0 }, 1.0, "test").unwrap().with_cat_eye(0.8).unwrap();
        for a in [hex, bubble, cat] {
            let s = ShapedSources::new(a, 40, 30).unwrap();
            for (j, r, front) in [(0usize, 6.3f32, false), (615, 4.1, true), (1199, 9.7, false)] {
                let (n, dn) = s.norm_grad(r);
                assert_eq!(n, s.norm(r));
                let wide = (s.norm(r * 1.01) as f64 - s.norm(r * 0.99) as f64) / (0.02 * r as f64);
                assert!((dn as f64 - wide).abs() < 2e-3 * wide.abs().max(1.0), "{a:?} norm slope {dn} vs {wide}");
                for (di, dj) in [(0, 0), (2, -3), (-4, 1), (5, 5), (0, -8)] {
                    let t = Tap { di, dj, r: ((di * di + dj * dj) as f32).sqrt() };
                    let (c, dc) = s.coverage_grad(j, r, front, &t);
                    assert!((c - s.coverage(j, r, front, &t)).abs() < 1e-6);
                    let f = |r: f32| s.coverage(j, r, front, &t) as f64;
                    let wide = (f(r * 1.002) - f(r * 0.998)) / (0.004 * r as f64);
                    assert!((dc as f64 - wide).abs() < 0.02 * wide.abs() + 2e-3, "{a:?} tap {di},{dj} r {r}: {dc} vs {wide}");
                }
            }
        }
    }

    #[test]
    fn a_point_source_has_no_slope() {
        assert_eq!(central(0.0, |r| r as f64), (0.0, 0.0));
        assert_eq!(central(POINT_COC_PX * 0.5, |r| r as f64).1, 0.0);
        // Just above the point threshold the difference is one-sided, never across the jump.
        let (_, g) = central(POINT_COC_PX * 1.0001, |r| if r < POINT_COC_PX { 100.0 } else { r as f64 });
        assert!((g - 1.0).abs() < 1e-3, "{g}");
    }
}
