//! Bright (HDR) sources: the few that are drawn with their exact footprint at any radius.
//!
//! A disk's edge approximation, or a coarse grid's, errs in proportion to the source's value:
//! a highlight of 50 turns an LDR-sized error into a visible one. So the sources above a
//! colour level are drawn exactly ([`super::footprint::rim_disk`]), and the level rises so that
//! at most ~1% of the visible sources are bright, keeping the cost near-constant per pixel.

use super::super::layer::{A, CHANNELS, SCAN_BLOCK, max_rgb, pixel_blocks};
use crate::ImageRef;
use rayon::prelude::*;

/// The lowest colour that counts as bright. Disk edges err by up to ~0.015 for colours up to
/// white (the stress tests), so 1.25 keeps that under 0.02; it also leaves alone the slight
/// overshoots above 1 that inpainting produces in an 8-bit photo's background (treating those
/// as bright cost a 12 MP render 40%).
pub(super) const BRIGHT_MIN: f32 = 1.25;

/// Most visible sources drawn exactly as bright, as a divisor: 1 in 100. Their cost grows
/// with σ.
const BRIGHT_FRACTION: usize = 100;

/// Whether a source whose largest premultiplied channel is `c` at alpha `a` is brighter than
/// `level` (≥ [`BRIGHT_MIN`], see [`bright_level`]): such sources are drawn exactly.
#[inline]
pub(super) fn is_bright(c: f32, a: f32, level: f32) -> bool {
    c > a * level
}

/// The colour above which a source counts as bright: [`BRIGHT_MIN`], raised when more than 1%
/// of the `visible` sources are above it (a bright sky, an HDR photo exposed low) to the level
/// that keeps the brightest 1%. Edge errors grow with a source's value relative to its
/// surroundings, so the brightest sources are the ones that need the exact footprint.
/// Allocates the colours above [`BRIGHT_MIN`]; O(pixels) (selection, not a sort).
pub(super) fn bright_level(img: ImageRef<'_>, visible: usize) -> f32 {
    let mut above: Vec<f32> = pixel_blocks(img.data)
        .flat_map_iter(|b| b.chunks_exact(CHANNELS).filter(|px| px[A] > 0.0).map(max_rgb).filter(|&c| c > BRIGHT_MIN))
        .collect();
    let budget = (visible / BRIGHT_FRACTION).max(1);
    if above.len() <= budget {
        return BRIGHT_MIN;
    }
    let k = above.len() - budget - 1;
    let (_, &mut kth, _) = above.select_nth_unstable_by(k, f32::total_cmp);
    kth
}

/// The bright sources' level and their largest drawn radius: `(level, max)`, where `max` is
/// the largest of `drawn` over the visible pixels brighter than `level`. `any_max` is that
/// largest radius at [`BRIGHT_MIN`] (from the survey); 0 when nothing is bright, and then
/// the image is not read again.
pub(super) fn bright_sources(img: ImageRef<'_>, visible: usize, any_max: f32, drawn: impl Fn(usize) -> f32 + Sync) -> (f32, f32) {
    if any_max <= 0.0 {
        return (BRIGHT_MIN, 0.0);
    }
    let level = bright_level(img, visible);
    if level <= BRIGHT_MIN {
        return (level, any_max);
    }
    let max = pixel_blocks(img.data)
        .enumerate()
        .map(|(k, b)| {
            let bright = b.chunks_exact(CHANNELS).enumerate().filter(|(_, px)| px[A] > 0.0 && is_bright(max_rgb(px), 1.0, level));
            bright.map(|(i, _)| drawn(k * SCAN_BLOCK + i)).fold(0.0, f32::max)
        })
        .reduce(|| 0.0, f32::max);
    (level, max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Image;

    /// A 1-row layer image of the given colours (grey), alpha 1 except every 7th pixel.
    fn layer_of(colours: &[f32]) -> (Image, usize) {
        let mut data = Vec::new();
        let mut visible = 0;
        for (i, &c) in colours.iter().enumerate() {
            let a = if i % 7 == 3 { 0.0 } else { 1.0 };
            visible += (a > 0.0) as usize;
            data.extend_from_slice(&[c * 0.5, c, c * 0.25, a, 0.5]);
        }
        (Image::from_vec(colours.len(), 1, CHANNELS, data).unwrap(), visible)
    }

    #[test]
    fn bright_level_keeps_the_brightest_one_percent() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut uniform = move || {
            x ^= x >> 12;
            x ^= x << 25;
            x ^= x >> 27;
            (x.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32 / (1u64 << 24) as f32
        };
        // A bright sky: most colours above BRIGHT_MIN.
        let colours: Vec<f32> = (0..20_000).map(|_| 0.5 + 10.0 * uniform()).collect();
        let (img, visible) = layer_of(&colours);
        let level = bright_level(img.as_image_ref(), visible);
        let bright = img.data.chunks_exact(CHANNELS).filter(|px| px[A] > 0.0 && is_bright(max_rgb(px), 1.0, level)).count();
        assert!(level > BRIGHT_MIN);
        assert_eq!(bright, visible / BRIGHT_FRACTION, "level {level}");
        // Every bright source is brighter than every other visible one.
        let dimmest_bright =
            img.data.chunks_exact(CHANNELS).filter(|px| px[A] > 0.0 && max_rgb(px) > level).map(max_rgb).fold(f32::INFINITY, f32::min);
        let brightest_other =
            img.data.chunks_exact(CHANNELS).filter(|px| px[A] > 0.0 && max_rgb(px) <= level).map(max_rgb).fold(0.0, f32::max);
        assert!(dimmest_bright > brightest_other);

        // A few highlights: all of them bright, at the floor level.
        let mut few = vec![0.7f32; 20_000];
        for i in (0..few.len()).step_by(997) {
            few[i] = 40.0;
        }
        let (img, visible) = layer_of(&few);
        assert_eq!(bright_level(img.as_image_ref(), visible), BRIGHT_MIN);
        let (level, max) = bright_sources(img.as_image_ref(), visible, 9.0, |i| i as f32);
        assert_eq!((level, max), (BRIGHT_MIN, 9.0));
        let (img, visible) = layer_of(&colours);
        let (level, max) = bright_sources(img.as_image_ref(), visible, 9.0, |i| i as f32);
        let want = img
            .data
            .chunks_exact(CHANNELS)
            .enumerate()
            .filter(|(_, px)| px[A] > 0.0 && max_rgb(px) > level)
            .map(|(i, _)| i as f32)
            .fold(0.0, f32::max);
        assert_eq!(max, want);
        assert_eq!(bright_sources(img.as_image_ref(), visible, 0.0, |_| 1.0), (BRIGHT_MIN, 0.0));
    }
}
