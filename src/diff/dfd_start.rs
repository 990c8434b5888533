//! Where the optimisation of [`super::dfd`] starts, and what a defocused photo cannot tell.
//!
//! A start that cannot move. In the physical profile (the default smoothing, a disk edge one
//! pixel wide) a source whose CoC radius `K·|d − focus|` is at most half a pixel
//! ([`DEAD_COC_PX`]) covers no neighbour and keeps weight 1 on its own pixel, whatever `d`:
//! the render, and so the loss, does not change with its disparity, and the gradient is
//! exactly zero. A map started in that band stays there: `dfd --focus 0.5` from the default
//! start 0.5 returned its start untouched (loss 0.58972 → 0.58972), as did `--init 1
//! --focus 1` and pyramids whose first level (K halves at each level) put the start there.
//! Such a start is replaced ([`movable_start`]) by one half-way out to the end of the range
//! on the side of the focal plane with more room, which moves at every level the plan keeps.
//! (A local defocus estimate as the start, each pixel taking the uniform blur that matched the
//! photo best around it, was tried: as good on two-plane scenes at focus 0.5 and 0.6 and
//! worse at 0.3 (error of |d − focus| 0.019 against 0.013), and as the default start it cut
//! the shared portrait's far-focus re-render from 35.5 to 24 dB: a textureless sky's guess is
//! worse than a uniform one.)
//!
//! What the photo cannot tell, said in the report rather than guessed silently:
//! - **Near or far.** A photo focused at `f` shows each pixel's `|d − f|` (the size of its
//!   blur), not the side of the focal plane it lies on: where both `f − δ` and `f + δ` are in
//!   [0, 1] (`δ ≤ min(f, 1 − f)`) they render alike, up to the occlusion at depth edges, and
//!   the optimisation (which cannot cross the dead band) keeps the side of its start
//!   ([`ambiguous_share`] counts such pixels for a warning). At `f = 0` or `f = 1` every
//!   pixel has one side.
//! - **Nothing at all.** Where `K·max(f, 1 − f)` is under half a pixel no disparity of [0, 1]
//!   blurs anything ([`undetermined`]): the map is the start, and the run says so.

use super::dfd_plan::focus_room;
use crate::image::Image;
use crate::render::lens::coc_radius;

/// The CoC radius, pixels, at or below which a pixel's render does not depend on its
/// disparity (the physical profile with a one-pixel disk edge: `lens::disk_coverage_smooth`
/// reaches a neighbour one pixel away only beyond half a pixel). Also the smallest blur a
/// photo shows.
pub const DEAD_COC_PX: f32 = 0.5;

/// The CoC radius, pixels, that a replaced start has at least at the first level: clear of
/// [`DEAD_COC_PX`], where the gradient is still zero.
const LIVE_COC_PX: f32 = 0.75;

/// The disparity at CoC radius `r` (pixels) for blur `k` and focus `f` (in [0, 1]): behind the
/// focal plane (`f − r/k`) where [0, 1] has room for it, in front (`f + r/k`, at most 1)
/// otherwise; `f` when `k` or `r` is 0.
pub fn disparity_at_radius(r: f32, k: f32, f: f32) -> f32 {
    if k <= 0.0 || r <= 0.0 {
        return f;
    }
    let delta = r / k;
    if f - delta >= 0.0 { f - delta } else { (f + delta).min(1.0) }
}

/// Whether no disparity of [0, 1] blurs a pixel by more than [`DEAD_COC_PX`] at blur `k` and
/// focus `f`: the photo then says nothing about the map.
pub fn undetermined(k: f32, f: f32) -> bool {
    coc_radius(focus_room(f), k) <= DEAD_COC_PX
}

/// The start to use instead of a uniform `init` that lies in the dead band at blur `k_first`
/// (the first level's K) and focus `f`; None when `init` can move. The replacement is half-way
/// out to the end of the range on the side with more room (behind the focal plane when both
/// have as much: `disparity_at_radius`), and at least [`LIVE_COC_PX`] of blur out where the
/// range allows; every level below the finest that the plan keeps has at least one pixel of
/// CoC over the range (`dfd_plan::MIN_LEVEL_COC`), so the replacement, at least
/// [`LIVE_COC_PX`] out, is clear of the dead band.
pub fn movable_start(init: f32, k_first: f32, f: f32) -> Option<f32> {
    if coc_radius(init - f, k_first) > DEAD_COC_PX {
        return None;
    }
    let end = coc_radius(focus_room(f), k_first);
    Some(disparity_at_radius((0.5 * end).max(LIVE_COC_PX).min(end), k_first, f))
}

/// The shares (fractions of the pixels) of map `d` that are blurred by more than
/// [`DEAD_COC_PX`] at blur `k` and lie where the other side of the focal plane `f` is in range
/// too: behind the focal plane, and in front of it.
pub fn ambiguous_share(d: &Image, k: f32, f: f32) -> (f64, f64) {
    let room = f.min(1.0 - f);
    let (mut behind, mut front) = (0usize, 0usize);
    for &v in &d.data {
        if coc_radius(v - f, k) > DEAD_COC_PX && (v - f).abs() <= room {
            if v < f {
                behind += 1;
            } else {
                front += 1;
            }
        }
    }
    let n = d.data.len().max(1) as f64;
    (behind as f64 / n, front as f64 / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Behind the focal plane where it fits, in front where only that fits; the focal plane
    /// itself for no blur.
    #[test]
    fn sides_of_the_focal_plane() {
        assert_eq!(disparity_at_radius(4.0, 8.0, 1.0), 0.5);
        assert_eq!(disparity_at_radius(4.0, 8.0, 0.0), 0.5);
        assert_eq!(disparity_at_radius(2.0, 8.0, 0.5), 0.25);
        assert_eq!(disparity_at_radius(6.0, 8.0, 0.5), 1.0);
        assert_eq!(disparity_at_radius(0.0, 8.0, 0.3), 0.3);
        assert_eq!(disparity_at_radius(3.0, 0.0, 0.3), 0.3);
        assert!(undetermined(1.0, 0.5) && !undetermined(1.1, 0.5) && undetermined(0.4, 1.0));
        // Focus 0.4: 0.2 and 0.6 could be either side, 0.9 only in front, 0.4 is sharp.
        let d = Image::from_vec(4, 1, 1, vec![0.4, 0.2, 0.6, 0.9]).unwrap();
        assert_eq!(ambiguous_share(&d, 8.0, 0.4), (0.25, 0.25));
    }

    /// A start in the dead band is moved half-way out on the roomier side, clear of the band;
    /// a start that moves is kept.
    #[test]
    fn dead_starts_are_moved() {
        // The cases: 0.5 at focus 0.5 (K 8; K 2 on a pyramid's first level, where
        // half-way out is still dead: 0.75 px out), 1 at 1.
        assert_eq!(movable_start(0.5, 8.0, 0.5), Some(0.25));
        assert_eq!(movable_start(0.5, 2.0, 0.5), Some(0.125));
        assert_eq!(movable_start(1.0, 8.0, 1.0), Some(0.5));
        // Focus 0.3: in front has more room.
        assert!(movable_start(0.35, 4.0, 0.3).is_some_and(|d| (d - 0.65).abs() < 1e-6));
        assert_eq!(movable_start(0.5, 8.0, 1.0), None);
        assert_eq!(movable_start(0.5, 8.0, 0.3), None);
        // Little blur: at least 0.75 px out, at most the range's end.
        assert_eq!(movable_start(1.0, 1.0, 1.0), Some(0.25));
        assert_eq!(movable_start(1.0, 0.6, 1.0), Some(0.0));
        for (init, k, f) in [(0.5f32, 8.0f32, 0.5f32), (0.5, 2.0, 0.5), (0.5, 2.0, 0.3), (0.97, 3.0, 1.0), (0.0, 1.5, 0.0)] {
            let d = movable_start(init, k, f).unwrap();
            assert!((0.0..=1.0).contains(&d) && coc_radius(d - f, k) > DEAD_COC_PX, "{init} {k} {f}: {d}");
        }
    }
}
