//! The lens window: which offsets of the square `lens × lens` window are taps.
//!
//! The official mask is a disk with a strict inequality, `sqrt(i² + j²) < lens/2` (integer
//! half-size), so the outermost ring of the window is never used and `lens = 1` has no taps.
//!
//! What the aperture looks like inside that window (blades, an image, an anamorphic squeeze)
//! is [`shape`]'s.

pub mod polygon;
pub mod shape;
pub mod sources;
pub use shape::{Aperture, CatEye, ShapeSpec};

/// One tap of the lens window: row offset `di`, column offset `dj`, distance `r` in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tap {
    /// Row offset from the window centre, pixels.
    pub di: i32,
    /// Column offset from the window centre, pixels.
    pub dj: i32,
    /// Distance from the centre, `sqrt(di² + dj²)` pixels.
    pub r: f32,
}

/// The taps of a disk aperture for a window of odd side `lens`, in the official summation
/// order (row offset outer, column offset inner). Masked-out offsets are omitted; they would
/// only add exact zeros. Allocates one `Tap` per used offset.
pub fn disk_taps(lens: usize) -> Vec<Tap> {
    let p = (lens / 2) as i32;
    let mut taps = Vec::new();
    for di in -p..=p {
        for dj in -p..=p {
            let r = ((di * di + dj * dj) as f32).sqrt();
            if r < p as f32 {
                taps.push(Tap { di, dj, r });
            }
        }
    }
    taps
}

/// The taps of [`disk_taps`] closer than `reach` pixels to the centre, in the same order,
/// without building the whole window: O(min(lens, 2·reach)²).
pub fn disk_taps_within(lens: usize, reach: f32) -> Vec<Tap> {
    let p = (lens / 2) as i32;
    // Rows and columns beyond `reach` hold no kept tap.
    let q = if reach.is_finite() { (reach.max(0.0).ceil() as i64).min(p as i64) as i32 } else { p };
    let mut taps = Vec::new();
    for di in -q..=q {
        for dj in -q..=q {
            let r = ((di * di + dj * dj) as f32).sqrt();
            if r < p as f32 && r < reach {
                taps.push(Tap { di, dj, r });
            }
        }
    }
    taps
}

/// `disk_taps(lens).len()`, counted per row in O(lens) without allocating.
pub fn disk_tap_count(lens: usize) -> u64 {
    let p = (lens / 2) as i64;
    (-p..=p)
        .map(|di| {
            // Largest |dj| with sqrt(di² + dj²) < p, as the f32 test of `disk_taps` decides.
            let rem = p * p - di * di;
            if rem <= 0 {
                return 0;
            }
            let mut m = (rem as f64).sqrt() as i64;
            while m > 0 && ((di * di + m * m) as f32).sqrt() >= p as f32 {
                m -= 1;
            }
            while ((di * di + (m + 1) * (m + 1)) as f32).sqrt() < p as f32 {
                m += 1;
            }
            if ((di * di + m * m) as f32).sqrt() < p as f32 { 2 * m as u64 + 1 } else { 0 }
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strict_disk() {
        assert!(disk_taps(1).is_empty());
        let t = disk_taps(15);
        assert!(!t.iter().any(|t| t.di == 0 && t.dj.abs() == 7));
        assert!(t.iter().any(|t| t.di == 0 && t.dj == 6));
        assert!(t.iter().any(|t| t.di == 0 && t.dj == 0));
    }

    #[test]
    fn count_and_reach_agree_with_the_full_window() {
        for lens in [1usize, 3, 5, 15, 31, 61, 125, 301] {
            let all = disk_taps(lens);
            assert_eq!(disk_tap_count(lens), all.len() as u64, "lens {lens}");
            for reach in [0.0f32, 0.5, 1.0, 2.5, 7.3, 40.0, f32::INFINITY] {
                let want: Vec<Tap> = all.iter().copied().filter(|t| t.r < reach).collect();
                assert_eq!(disk_taps_within(lens, reach), want, "lens {lens} reach {reach}");
            }
        }
    }
}
