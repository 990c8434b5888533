//! The lens window: which offsets of the square `lens × lens` window are taps.
//!
//! The official mask is a disk with a strict inequality, `sqrt(i² + j²) < lens/2` (integer
//! half-size), so the outermost ring of the window is never used and `lens = 1` has no taps.

/// One tap of the lens window: row offset `di`, column offset `dj`, distance `r` in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tap {
    pub di: i32,
    pub dj: i32,
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
}
