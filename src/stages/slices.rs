//! More than two layers (`--layers auto|N`): the background cut at gaps of its depth.
//!
//! The pipeline's front layer is the salient foreground (matte, model or depth split); what is
//! behind it is one opaque layer by default. A background that lies on separate depth planes
//! (a wall behind a table, a street behind a car) can be peeled further, front to back: the
//! background's pixels nearer than a cut become a layer of their own, what they hide is
//! inpainted for the layers behind, and so on. The renderer then shows that inpainted content
//! where a blurred nearer slice turns translucent, as a lens does (the per-plane layering of the
//! bench's `drbokeh-sliced`).
//!
//! This module only chooses the cuts (normalized disparities, nearest first) from the visible
//! background's disparity; the pipeline peels the layers.

use super::layer_count::LayerCount;
use super::segment::{SegmentOptions, otsu_threshold};
use crate::image::Image;
use serde::Serialize;

/// Histogram bins over the disparity range [0, 1].
const BINS: usize = 256;

/// A bin whose smoothed count is below this fraction of the lower of the two peaks around it
/// is part of a valley between two depth populations. A depth map smoothed like an estimator's
/// fills a gap between two planes with a thin ramp of values: on the bench's `realistic-depth`
/// scenes (seed 3) that ramp stays below 12% of the smaller plane's peak.
const GAP_DENSITY: f64 = 0.15;

/// How far (pixels) on each side of a cut the depth jump is read: past the ramp of a depth
/// map smoothed like an estimator's (the bench's realistic depth: 4x4 blocks, bilinear, then a
/// Gaussian of 1.5 px).
const EDGE_SPAN_PX: usize = 3;

/// How much the jump across a cut may still grow from [`EDGE_SPAN_PX`] to three times that
/// distance for the cut to count as a depth edge: a ramp's grows 19/7 ≈ 2.7 times, an edge
/// smoothed over a few pixels hardly at all.
const RAMP_GROWTH: f32 = 1.5;

/// Bins the histogram is smoothed over before peaks and valleys are looked for (a plane's
/// values spread over a few bins once the depth map is smoothed).
const SMOOTH_BINS: usize = 5;

/// The background's cuts and why there are no (more) of them.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Cuts {
    /// Normalized disparities, nearest first: background pixels above `thresholds[0]` are the
    /// first background slice, those between `[0]` and `[1]` the next, and so on.
    pub thresholds: Vec<f32>,
    /// Why there are not more cuts (absent when the count asked for was reached).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub limit: Option<String>,
}

/// Chooses the cuts of the visible background (`background[i]`: pixel i shows the background)
/// of `disp` (one channel, normalized) for `count` layers in all, the foreground included.
/// Every slice keeps at least `opts.layer_min_fraction` of the image, and a cut must be a real
/// depth edge (median disparity jump across it at least `opts.min_jump`, levelled off a few
/// pixels out: see `is_depth_edge`), so a slanted ground is never cut. Cost: one histogram pass, and one pass over the image per candidate.
pub fn background_cuts(disp: &Image, background: &[bool], count: LayerCount, opts: &SegmentOptions) -> Cuts {
    let wanted = count.most().saturating_sub(2);
    if wanted == 0 {
        return Cuts::default();
    }
    let values: Vec<f32> = disp.data.iter().zip(background).filter(|(_, b)| **b).map(|(&d, _)| d).collect();
    let min_px = (opts.layer_min_fraction * disp.data.len() as f64).ceil().max(1.0) as usize;
    if values.len() < 2 * min_px {
        return Cuts { thresholds: Vec::new(), limit: Some("the visible background is too small to cut".into()) };
    }
    let candidates = match count {
        LayerCount::Auto => valleys(&values, opts.layer_gap),
        LayerCount::Fixed(_) => otsu_levels(&values, wanted, min_px),
    };
    let mut chosen: Vec<f32> = Vec::new();
    for t in candidates {
        if chosen.len() == wanted {
            break;
        }
        let mut trial = chosen.clone();
        trial.push(t);
        trial.sort_by(|a, b| b.total_cmp(a));
        if smallest_slice(&values, &trial) < min_px {
            continue;
        }
        if !is_depth_edge(disp, background, t, opts.min_jump) {
            continue;
        }
        chosen = trial;
    }
    let limit = (chosen.len() < wanted).then(|| match count {
        LayerCount::Auto if chosen.is_empty() => {
            format!("no valley between depth populations at least {} apart in the visible background's disparity, across a depth edge", opts.layer_gap)
        }
        LayerCount::Auto => format!("{} valley(s) in the visible background's disparity", chosen.len()),
        LayerCount::Fixed(n) => format!(
            "{n} layers asked for, the visible background's depth allows {} (slices of at least {:.1}% of the image across real depth edges)",
            chosen.len() + 2,
            opts.layer_min_fraction * 100.0
        ),
    });
    Cuts { thresholds: chosen, limit }
}

/// Cuts at the valleys of the histogram, deepest-sided first: a run of bins whose density
/// (histogram smoothed over [`SMOOTH_BINS`]) is below [`GAP_DENSITY`] of the lower of the
/// highest peaks on its two sides, where those peaks lie at least `min_gap` apart. An empty
/// gap between planes is such a valley, and so is the thin ramp a smoothed depth map puts
/// between them; a slanted surface, whose values spread evenly, has none. The cut is the
/// valley run's midpoint.
fn valleys(values: &[f32], min_gap: f32) -> Vec<f32> {
    let raw = histogram(values);
    let half = SMOOTH_BINS / 2;
    let hist: Vec<f64> = (0..BINS)
        .map(|b| {
            let (lo, hi) = (b.saturating_sub(half), (b + half).min(BINS - 1));
            raw[lo..=hi].iter().sum::<u64>() as f64 / (hi - lo + 1) as f64
        })
        .collect();
    // The highest bin at or left of b, and at or right of b.
    let mut left = vec![(0.0f64, 0usize); BINS];
    let mut right = vec![(0.0f64, 0usize); BINS];
    for b in 0..BINS {
        left[b] = if b > 0 && left[b - 1].0 >= hist[b] { left[b - 1] } else { (hist[b], b) };
    }
    for b in (0..BINS).rev() {
        right[b] = if b + 1 < BINS && right[b + 1].0 >= hist[b] { right[b + 1] } else { (hist[b], b) };
    }
    let low = |b: usize| b > 0 && b + 1 < BINS && hist[b] < GAP_DENSITY * left[b - 1].0.min(right[b + 1].0);
    let mut cuts = Vec::new();
    let mut b = 1;
    while b + 1 < BINS {
        if !low(b) {
            b += 1;
            continue;
        }
        let start = b;
        while b + 1 < BINS && low(b) {
            b += 1;
        }
        let (peak_l, peak_r) = (left[start - 1], right[b]);
        let apart = (peak_r.1 - peak_l.1) as f32 / (BINS - 1) as f32;
        if apart >= min_gap {
            let mid = (start as f32 + b as f32 - 1.0) / 2.0 / (BINS - 1) as f32;
            cuts.push((peak_l.0.min(peak_r.0), mid));
        }
    }
    cuts.sort_by(|a, b| b.0.total_cmp(&a.0));
    cuts.into_iter().map(|(_, t)| t).collect()
}

/// Up to `cuts` multi-level Otsu thresholds, found greedily: the class with the largest
/// within-class scatter (count × variance) is split at its own Otsu threshold, if both parts
/// keep `min_px` values. In the order found.
fn otsu_levels(values: &[f32], cuts: usize, min_px: usize) -> Vec<f32> {
    let mut classes: Vec<Vec<f32>> = vec![values.to_vec()];
    let mut found = Vec::new();
    while found.len() < cuts {
        let scatter = |c: &Vec<f32>| {
            let n = c.len() as f64;
            let mean = c.iter().map(|&v| v as f64).sum::<f64>() / n.max(1.0);
            c.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>()
        };
        let mut order: Vec<usize> = (0..classes.len()).collect();
        order.sort_by(|&a, &b| scatter(&classes[b]).total_cmp(&scatter(&classes[a])));
        let split = order.into_iter().find_map(|i| {
            let c = &classes[i];
            let (lo, hi) = c.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), &v| (l.min(v), h.max(v)));
            if hi - lo <= 1.0 / (BINS - 1) as f32 {
                return None;
            }
            // Otsu on the class's values stretched to [0, 1], mapped back.
            let span = hi - lo;
            let stretched: Vec<f32> = c.iter().map(|&v| (v - lo) / span).collect();
            let t = lo + otsu_threshold(&stretched) * span;
            let near = c.iter().filter(|&&v| v > t).count();
            (near >= min_px && c.len() - near >= min_px).then_some((i, t))
        });
        let Some((i, t)) = split else { break };
        let c = classes.swap_remove(i);
        let (near, far): (Vec<f32>, Vec<f32>) = c.into_iter().partition(|&v| v > t);
        classes.push(near);
        classes.push(far);
        found.push(t);
    }
    found
}

fn histogram(values: &[f32]) -> Vec<u64> {
    let mut hist = vec![0u64; BINS];
    for &v in values {
        hist[(v.clamp(0.0, 1.0) * (BINS - 1) as f32).round() as usize] += 1;
    }
    hist
}

/// The fewest values in any slice between consecutive `cuts` (sorted nearest first).
fn smallest_slice(values: &[f32], cuts: &[f32]) -> usize {
    let mut counts = vec![0usize; cuts.len() + 1];
    for &v in values {
        counts[cuts.iter().take_while(|&&t| v <= t).count()] += 1;
    }
    counts.into_iter().min().unwrap_or(0)
}

/// Whether cut `t` of the visible background follows a depth edge: the median jump across it
/// ([`edge_jump`], [`EDGE_SPAN_PX`] out on each side) is at least `min_jump`, and it has
/// levelled off there: three times farther out it is less than [`RAMP_GROWTH`] times as
/// large. Across a slanted surface the difference keeps growing with the distance (a
/// quantized ramp has histogram valleys between its levels and must not be cut).
fn is_depth_edge(disp: &Image, background: &[bool], t: f32, min_jump: f32) -> bool {
    let near = edge_jump(disp, background, t, EDGE_SPAN_PX);
    near >= min_jump && edge_jump(disp, background, t, 3 * EDGE_SPAN_PX) < RAMP_GROWTH * near
}

/// Median |ΔD| across cut `t` of the visible background: for every 4-neighbour pair that the
/// cut separates, the difference between the pixels `span` farther out on each side (both
/// background; positions past the image border are clamped to it), so that a depth edge a
/// smoothed map spreads over a few pixels still shows its full jump. 0 when no such pair
/// exists.
fn edge_jump(disp: &Image, background: &[bool], t: f32, span: usize) -> f32 {
    let (w, h) = (disp.width as isize, disp.height as isize);
    let d = &disp.data;
    let s = span as isize;
    let mut jumps = Vec::new();
    for y in 0..h {
        for x in 0..w {
            for (dx, dy) in [(1isize, 0isize), (0, 1)] {
                let (x1, y1) = (x + dx, y + dy);
                if x1 >= w || y1 >= h {
                    continue;
                }
                let (xa, ya) = ((x - s * dx).max(0), (y - s * dy).max(0));
                let (xb, yb) = ((x1 + s * dx).min(w - 1), (y1 + s * dy).min(h - 1));
                let (i, j) = ((y * w + x) as usize, (y1 * w + x1) as usize);
                let (a, b) = ((ya * w + xa) as usize, (yb * w + xb) as usize);
                if (d[i] > t) != (d[j] > t) && background[a] && background[b] && background[i] && background[j] {
                    jumps.push((d[a] - d[b]).abs());
                }
            }
        }
    }
    super::mask::median(&mut jumps).unwrap_or(0.0)
}

/// The soft alpha of the slice nearer than `t` in a background's disparity `disp`: the hard
/// split, its edge softened like the depth split's (`edge_softness`).
pub fn slice_alpha(disp: &Image, t: f32, edge_softness: f32) -> Image {
    let hard = Image::from_vec(disp.width, disp.height, 1, disp.data.iter().map(|&d| (d > t) as u8 as f32).collect()).expect("plane size");
    let mut alpha = super::mask::gaussian_blur(&hard, edge_softness);
    alpha.map_inplace(|a| a.clamp(0.0, 1.0));
    alpha
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(w: usize, h: usize, f: impl Fn(usize, usize) -> f32) -> Image {
        Image::from_vec(w, h, 1, (0..w * h).map(|i| f(i % w, i / w)).collect()).unwrap()
    }

    #[test]
    fn counts_parse_and_check() {
        assert_eq!(LayerCount::parse("auto"), Ok(LayerCount::Auto));
        assert_eq!(LayerCount::parse(" 3 "), Ok(LayerCount::Fixed(3)));
        for bad in ["0", "9", "-1", "two", ""] {
            assert!(LayerCount::parse(bad).is_err(), "{bad}");
        }
        assert!(LayerCount::Fixed(0).check("segment.layers").is_err());
        assert!(LayerCount::Fixed(2).check("segment.layers").is_ok());
    }

    #[test]
    fn auto_cuts_a_stepped_background_and_not_a_ramp() {
        let opts = SegmentOptions::default();
        let all = vec![true; 64 * 48];
        // Left half at 0.6, right half at 0.1: one gap, one cut between.
        let step = plane(64, 48, |x, _| if x < 32 { 0.6 } else { 0.1 });
        let cuts = background_cuts(&step, &all, LayerCount::Auto, &opts);
        assert_eq!(cuts.thresholds.len(), 1, "{cuts:?}");
        assert!((0.1..0.6).contains(&cuts.thresholds[0]));
        // Three planes: two cuts, nearest first.
        let three = plane(60, 48, |x, _| [0.9, 0.5, 0.1][x / 20]);
        let cuts = background_cuts(&three, &vec![true; 60 * 48], LayerCount::Auto, &opts);
        assert_eq!(cuts.thresholds.len(), 2, "{cuts:?}");
        assert!(cuts.thresholds[0] > 0.5 && cuts.thresholds[1] < 0.5 && cuts.thresholds[1] > 0.1);
        // A ground plane sloping smoothly: no gap, no cut.
        let ramp = plane(64, 48, |_, y| y as f32 / 47.0);
        let cuts = background_cuts(&ramp, &all, LayerCount::Auto, &opts);
        assert!(cuts.thresholds.is_empty() && cuts.limit.is_some(), "{cuts:?}");
        // Two layers asked for: never a cut.
        assert_eq!(background_cuts(&step, &all, LayerCount::Fixed(2), &opts), Cuts::default());
    }

    #[test]
    fn a_gap_without_an_edge_is_not_cut() {
        // Two background regions at different depths that only meet through the foreground:
        // neither is seen in front of the other, so there is no edge to cut along.
        let opts = SegmentOptions::default();
        let d = plane(64, 48, |x, _| {
            if x < 20 {
                0.7
            } else if x < 44 {
                0.5
            } else {
                0.1
            }
        });
        // The middle third is the foreground: the two background parts never meet.
        let bg: Vec<bool> = (0..64 * 48).map(|i| !(20..44).contains(&(i % 64))).collect();
        let cuts = background_cuts(&d, &bg, LayerCount::Auto, &opts);
        assert!(cuts.thresholds.is_empty(), "{cuts:?}");
    }

    #[test]
    fn fixed_counts_follow_otsu_and_respect_the_smallest_slice() {
        let opts = SegmentOptions::default();
        let three = plane(60, 48, |x, _| [0.9, 0.5, 0.1][x / 20]);
        let all = vec![true; 60 * 48];
        let cuts = background_cuts(&three, &all, LayerCount::Fixed(4), &opts);
        assert_eq!(cuts.thresholds.len(), 2, "{cuts:?}");
        assert!(cuts.limit.is_none());
        // More than the planes: as many as the depth allows, and says so.
        let cuts = background_cuts(&three, &all, LayerCount::Fixed(6), &opts);
        assert_eq!(cuts.thresholds.len(), 2, "{cuts:?}");
        assert!(cuts.limit.as_deref().is_some_and(|m| m.contains("6 layers asked for")), "{cuts:?}");
    }

    #[test]
    fn slice_alpha_is_soft_only_at_the_cut() {
        let d = plane(32, 8, |x, _| if x < 16 { 0.8 } else { 0.2 });
        let a = slice_alpha(&d, 0.5, 0.8);
        assert!(a.data[4 * 32 + 2] > 0.999 && a.data[4 * 32 + 29] < 1e-3);
        assert!(a.data[4 * 32 + 15] > 0.5 && a.data[4 * 32 + 15] < 1.0);
    }
}
