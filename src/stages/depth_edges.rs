//! How far a depth map's edges spread past the matte's.
//!
//! A depth map from an estimator is coarser and smoother than the photo: across the subject's
//! outline its disparity ramps over several pixels instead of stepping where the matte does.
//! Inside the outline the foreground then takes background depth (and blurs as if it were
//! far), outside it the background takes foreground depth. Measuring the ramp's width on each
//! side lets the stages trust depth only where it is clean: the foreground's disparity is
//! taken that far inside the outline and extended outwards ([`super::fill_depth`]), the
//! background's is re-synthesized that far outside it ([`super::background`]). With a depth
//! map whose edges are on the photo's, both widths come out at about a pixel and nothing
//! changes.

use super::mask::{grown_bbox, median, root, sq_distance_upto};
use crate::image::Image;
use rayon::prelude::*;
use serde::Serialize;

/// Widest ramp measured, pixels per side (estimators' edges are rarely softer; a wider search
/// would also cross into other objects).
pub const MAX_WIDTH: usize = 12;
/// The plateau on each side is read this far from the outline: [`MAX_WIDTH`] + 1 … + 3.
const PLATEAU: (f32, f32) = (MAX_WIDTH as f32 + 1.0, MAX_WIDTH as f32 + 3.0);
/// A boundary sample counts only where the plateaus differ by this much disparity (elsewhere
/// the depth has no edge to measure).
const MIN_STEP: f32 = 0.03;
/// At most this many samples are used (evenly spread), which bounds the cost at 12 MP.
const MAX_SAMPLES: usize = 5_000;
/// Share of the step still counted as ramp: the ramp ends where the profile is within 10% of
/// its plateau.
const SETTLED: f32 = 0.1;

/// The measured ramp widths (pixels) on each side of the outline, and how many samples
/// measured them (0: no depth edge along the outline; the widths are then 0).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct EdgeWidths {
    /// Inside the matte: foreground pixels within this distance of the outline carry
    /// background depth.
    pub inside_px: f32,
    /// Outside the matte: background pixels within this distance carry foreground depth.
    pub outside_px: f32,
    /// Samples measured.
    pub samples: usize,
}

/// Measures the ramp of `disp` across the outline of `inside` (the matte's hard mask, e.g.
/// `alpha ≥ 0.5`): the median normalized profile of the disparity against the signed distance
/// to the outline, each sample normalized by the median plateaus on both sides within a
/// window around it. Where the inside has no plateau (a part thinner than [`PLATEAU`]'s
/// distance: bars, wires), the outside samples are normalized by the part's own outline pixel
/// farthest from the outside plateau, and with no inside sample at all the ramp is taken as
/// symmetric: a smoothed map keeps a thin subject's depth ramp outside it, an exact one none
/// (issue 12: on the tuning seed 3 with the realistic depth, thin-only subjects' depth was used
/// as given, 0.36-0.73 disparity off). Cost: two distance transforms (exact up to the plateau)
/// on the outline's box (in parallel; the signed distance is kept on that box only, 4 bytes
/// per pixel of it) and one window median per sample (at most [`MAX_SAMPLES`]), in parallel.
pub fn measure(disp: &Image, inside: &[bool], w: usize, h: usize) -> EdgeWidths {
    let reach = PLATEAU.1 + 1.0;
    // Every pixel within `reach` of the outline lies in the inside's box grown by `reach`:
    // both transforms run there only (a small subject in a large frame costs little).
    let Some(bb) = grown_bbox(inside, w, h, reach + 1.0) else { return EdgeWidths::default() };
    // Signed distance on the box (row-major over it): > 0 inside (distance to the outside),
    // < 0 outside; outside the box it is infinite, which no test below accepts.
    let (x0, y0, x1, y1) = bb;
    let bw = x1 - x0;
    // Every test below reads distances up to PLATEAU.1 < reach: exact up to `reach` is enough.
    let (to_out, to_in) = rayon::join(|| sq_distance_upto(inside, w, bb, false, reach), || sq_distance_upto(inside, w, bb, true, reach));
    let mut signed_box = vec![0.0f32; to_out.len()];
    signed_box.par_chunks_mut(bw).enumerate().for_each(|(y, row)| {
        let (inside, i0) = (&inside[(y0 + y) * w + x0..][..bw], y * bw);
        for (x, s) in row.iter_mut().enumerate() {
            *s = if inside[x] { root(to_out[i0 + x]) } else { -root(to_in[i0 + x]) };
        }
    });
    drop((to_out, to_in));
    // The band's pixels as box coordinates, in raster order.
    let band: Vec<(usize, usize)> = signed_box
        .par_chunks(bw)
        .enumerate()
        .flat_map_iter(|(y, row)| row.iter().enumerate().filter(|(_, s)| s.abs() <= MAX_WIDTH as f32 + 0.5).map(move |(x, _)| (x, y)))
        .collect();
    if band.is_empty() {
        return EdgeWidths::default();
    }
    let stride = band.len().div_ceil(MAX_SAMPLES);
    let r = PLATEAU.1.ceil() as usize + 2;
    let (bh, signed) = (y1 - y0, &signed_box);
    // (signed distance bucket, normalized disparity) per usable sample.
    let samples: Vec<(i32, f32)> = band
        .par_iter()
        .step_by(stride)
        .filter_map(|&(x, y)| {
            let (mut fin, mut fout, mut near_in) = (Vec::new(), Vec::new(), Vec::new());
            // The window, clipped to the box: beyond it the signed distance is infinite, which
            // no plateau test accepts.
            for yy in y.saturating_sub(r)..(y + r + 1).min(bh) {
                let (xs, xe) = (x.saturating_sub(r), (x + r + 1).min(bw));
                let srow = &signed[yy * bw + xs..yy * bw + xe];
                let drow = &disp.data[(y0 + yy) * w + x0 + xs..(y0 + yy) * w + x0 + xe];
                for (&s, &d) in srow.iter().zip(drow) {
                    if s >= PLATEAU.0 && s <= PLATEAU.1 {
                        fin.push(d);
                    } else if -s >= PLATEAU.0 && -s <= PLATEAU.1 {
                        fout.push(d);
                    } else if s > 0.0 && s <= 2.0 {
                        near_in.push(d);
                    }
                }
            }
            let dout = median(&mut fout)?;
            let (s, d) = (signed[y * bw + x], disp.data[(y0 + y) * w + x0 + x]);
            let din = match median(&mut fin) {
                Some(din) => din,
                // A part thinner than the plateau's distance (a bar, a wire) has no inside
                // plateau: its own pixels at the outline, the one farthest from the outside
                // plateau, stand in for it, and only the outside of the ramp is measured.
                None if s < 0.0 => near_in.iter().copied().fold(dout, |m, v| if (v - dout).abs() > (m - dout).abs() { v } else { m }),
                None => return None,
            };
            ((din - dout).abs() >= MIN_STEP).then(|| (s.round() as i32, (d - dout) / (din - dout)))
        })
        .collect();
    if samples.is_empty() {
        return EdgeWidths::default();
    }
    let m = MAX_WIDTH as i32;
    let profile: Vec<Option<f32>> = (-m..=m)
        .map(|k| {
            let mut v: Vec<f32> = samples.iter().filter(|s| s.0 == k).map(|s| s.1).collect();
            median(&mut v)
        })
        .collect();
    let at = |k: i32| profile[(k + m) as usize];
    // The ramp reaches as far out as the profile is still off its plateau.
    let inside_px = (1..=m).rev().find(|&k| at(k).is_some_and(|t| t < 1.0 - SETTLED)).unwrap_or(0) as f32;
    let outside_px = (1..=m).rev().find(|&k| at(-k).is_some_and(|t| t > SETTLED)).unwrap_or(0) as f32;
    // Only thin parts measured: the ramp is taken as symmetric (a smoothing is).
    let inside_px = if (1..=m).all(|k| at(k).is_none()) { outside_px } else { inside_px };
    EdgeWidths { inside_px, outside_px, samples: samples.len() }
}

/// A Gaussian edge rises from 10% to 90% over ±1.28 σ: the measured ramp (pixels per side, to
/// 10% of the step) is about 1.28 σ of the smoothing that made it.
const RAMP_PER_SIGMA: f32 = 1.28;
/// The foreground estimate is trusted where the smoothed matte keeps at least this weight
/// (the division below amplifies depth noise by at most its inverse).
const MIN_WEIGHT: f32 = 0.2;

/// The foreground's own disparity under a smoothed depth map, for subjects thinner than the
/// ramp (bars, wires, small objects: no pixel of theirs is beyond it).
///
/// The map is modelled as a Gaussian smoothing `G` (σ from the measured ramp) of the layered
/// scene: `D = G*(α·F) + G*((1 - α)·B)`, with `B` the background's disparity (the map
/// Telea-filled under the subject from beyond the ramp). Where `F` is locally constant,
/// `F = (D - G*((1 - α)·B)) / G*α`. Returns the estimate and the pixels where it holds (alpha
/// at least 0.5 and `G*α` at least [`MIN_WEIGHT`]); None when the ramp is under a pixel (the
/// map is as sharp as the matte). Cost: a Telea fill near the outline and two Gaussian blurs
/// of the subject's box; allocates a few planes.
pub fn foreground_estimate(disp: &Image, alpha: &Image, e: &EdgeWidths, radius: f32) -> crate::error::Result<Option<(Image, Vec<bool>)>> {
    let sigma = (e.inside_px + e.outside_px) / 2.0 / RAMP_PER_SIGMA;
    if e.samples == 0 || sigma < 0.75 {
        return Ok(None);
    }
    let (w, h) = (disp.width, disp.height);
    let some: Vec<bool> = alpha.data.par_iter().map(|&a| a > 0.0).collect();
    // The background's disparity is read beyond the ramp outside the subject.
    let hidden = super::mask::dilate(&some, w, h, e.outside_px + 1.0);
    let mut bg = disp.clone();
    let reach = super::mask::marching_reach(e.outside_px + 1.0 + 3.0 * sigma);
    super::inpaint::inpaint_telea(
        &mut bg,
        &hidden,
        super::inpaint::TeleaOptions { max_distance: Some(reach), ..super::inpaint::TeleaOptions::new(radius) },
    )?;
    let weighted = Image::from_vec(w, h, 1, alpha.data.par_iter().zip(&bg.data).map(|(&a, &b)| (1.0 - a) * b).collect()).expect("size");
    let (ga, gb) = rayon::join(|| super::mask::gaussian_blur(alpha, sigma), || super::mask::gaussian_blur(&weighted, sigma));
    let mut est = disp.clone();
    let mut valid = vec![false; w * h];
    // Rows in parallel (a serial pass per plane was a serial stretch of the peel, issue 39).
    est.data.par_chunks_mut(w).zip(valid.par_chunks_mut(w)).enumerate().for_each(|(y, (est, valid))| {
        for (x, (e, ok)) in est.iter_mut().zip(valid).enumerate() {
            let i = y * w + x;
            if alpha.data[i] >= 0.5 && ga.data[i] >= MIN_WEIGHT {
                *e = ((disp.data[i] - gb.data[i]) / ga.data[i]).clamp(0.0, 1.0);
                *ok = true;
            }
        }
    });
    Ok(Some((est, valid)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A disk of disparity 0.8 on 0.2, its depth edge smoothed by a ramp of `ramp` px per side.
    fn disk(ramp: f32) -> (Image, Vec<bool>, usize, usize) {
        let (w, h) = (96, 96);
        let mut d = Image::new(w, h, 1);
        let mut inside = vec![false; w * h];
        for y in 0..h {
            for x in 0..w {
                let r = ((x as f32 - 48.0).powi(2) + (y as f32 - 48.0).powi(2)).sqrt();
                let s = 25.0 - r; // signed distance to the outline
                inside[y * w + x] = s >= 0.0;
                let t = if ramp == 0.0 { (s >= 0.0) as u8 as f32 } else { ((s + ramp) / (2.0 * ramp)).clamp(0.0, 1.0) };
                d.data[y * w + x] = 0.2 + 0.6 * t;
            }
        }
        (d, inside, w, h)
    }

    /// Vertical bars 2 px wide (disparity 0.9 on 0.1), sharp or smoothed by a Gaussian.
    fn bars(sigma: f32) -> (Image, Vec<bool>, usize, usize) {
        let (w, h) = (120, 64);
        let inside: Vec<bool> = (0..w * h).map(|i| (i % w) % 40 >= 19 && (i % w) % 40 < 21).collect();
        let d = Image::from_vec(w, h, 1, inside.iter().map(|&b| if b { 0.9 } else { 0.1 }).collect()).unwrap();
        let d = if sigma > 0.0 { crate::stages::mask::gaussian_blur(&d, sigma) } else { d };
        (d, inside, w, h)
    }

    #[test]
    fn thin_parts_measure_the_ramp_outside_them() {
        let (d, inside, w, h) = bars(0.0);
        let e = measure(&d, &inside, w, h);
        assert!(e.samples > 0 && e.inside_px <= 1.0 && e.outside_px <= 1.0, "{e:?}");
        let (d, inside, w, h) = bars(2.5);
        let e = measure(&d, &inside, w, h);
        assert!(e.samples > 0 && e.outside_px >= 2.0 && e.inside_px == e.outside_px, "{e:?}");
    }

    #[test]
    fn sharp_edges_measure_about_a_pixel_and_ramps_their_width() {
        let (d, inside, w, h) = disk(0.0);
        let e = measure(&d, &inside, w, h);
        assert!(e.samples > 0 && e.inside_px <= 1.0 && e.outside_px <= 1.0, "{e:?}");
        let (d, inside, w, h) = disk(6.0);
        let e = measure(&d, &inside, w, h);
        assert!((4.0..=7.0).contains(&e.inside_px) && (4.0..=7.0).contains(&e.outside_px), "{e:?}");
    }

    #[test]
    fn no_depth_edge_no_width() {
        let (w, h) = (64, 64);
        let d = Image::filled(w, h, 1, 0.5);
        let inside: Vec<bool> = (0..w * h).map(|i| (i % w) < 32).collect();
        assert_eq!(measure(&d, &inside, w, h), EdgeWidths::default());
    }
}
