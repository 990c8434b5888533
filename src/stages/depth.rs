//! From a raw depth or disparity map to normalized disparity, and focus selection.
//!
//! Normalized disparity `D` is 1 at the scene's nearest point and 0 at its farthest:
//! `D = (1/z - 1/z_max) / (1/z_min - 1/z_max)` for depth, min-max for disparity.

use super::inpaint::{TeleaOptions, inpaint_telea};
use crate::error::{Error, Result};
use crate::image::Image;
use std::path::Path;

/// What the values of a depth map mean.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DepthKind {
    /// Distances z (> 0): larger = farther.
    #[default]
    Depth,
    /// Disparity-like values: larger = nearer.
    Disparity,
}

/// A normalized disparity map and how it was made.
#[derive(Clone, Debug)]
pub struct Disparity {
    /// One channel, values in [0, 1].
    pub map: Image,
    /// `(z_min, z_max)` of the valid depths (depth maps only): needed for a focus given as a metric depth.
    pub z_range: Option<(f64, f64)>,
    /// Fraction of pixels that were invalid and filled from their valid neighbours.
    pub filled_fraction: f64,
}

impl Disparity {
    /// True when the map has no depth range: every value is the same (a flat depth file
    /// normalizes to 0 everywhere). O(pixels), stops at the first other value.
    pub fn is_flat(&self) -> bool {
        let d = &self.map.data;
        d.iter().all(|&v| v == d[0])
    }

    /// Normalized disparity of metric depth `z` (depth maps only).
    pub fn disparity_of_depth(&self, z: f64) -> Result<f32> {
        let Some((zmin, zmax)) = self.z_range else {
            return Err(Error::usage("render.focus_depth needs a depth map (input.depth_kind = \"depth\"), not a disparity map"));
        };
        if !(z.is_finite() && z > 0.0) {
            return Err(Error::usage(format!("render.focus_depth must be a positive distance, got {z}")));
        }
        let span = 1.0 / zmin - 1.0 / zmax;
        let span = if span > 0.0 { span } else { 1.0 };
        Ok(((1.0 / z - 1.0 / zmax) / span) as f32)
    }

    /// Robust disparity at pixel (x, y): the median of the window of half-size
    /// `max(2, min(W,H)/200)` around it, so a click on an edge or a noisy pixel still focuses
    /// on the surface under it.
    pub fn disparity_at(&self, x: i64, y: i64) -> Result<f32> {
        let m = &self.map;
        if x < 0 || y < 0 || x >= m.width as i64 || y >= m.height as i64 {
            return Err(Error::usage(format!(
                "render.focus_at {x},{y} is outside the {}x{} image (x in 0..{}, y in 0..{})",
                m.width, m.height, m.width, m.height
            )));
        }
        let r = (m.width.min(m.height) / 200).max(2) as i64;
        let mut vals: Vec<f32> = Vec::new();
        for yy in (y - r).max(0)..=(y + r).min(m.height as i64 - 1) {
            for xx in (x - r).max(0)..=(x + r).min(m.width as i64 - 1) {
                vals.push(m.data[yy as usize * m.width + xx as usize]);
            }
        }
        vals.sort_by(f32::total_cmp);
        Ok(vals[vals.len() / 2])
    }
}

/// A depth map whose valid values span less than this fraction of their magnitude is flat
/// (f32 holds about 7 digits: 1e-6 is some 16 ulps).
const FLAT_RELATIVE: f64 = 1e-6;

/// Converts a raw one-channel map to normalized disparity.
///
/// Invalid values (non-finite; for depth also ≤ 0) are filled from valid neighbours with
/// Telea inpainting and reported in `filled_fraction`; a map with no valid value is an error
/// naming `path`. A flat map (one value, to [`FLAT_RELATIVE`]) gives D ≡ 0 ([`Disparity::is_flat`]).
pub fn normalize(raw: &Image, kind: DepthKind, path: &Path) -> Result<Disparity> {
    if raw.channels != 1 {
        return Err(Error::input(path, format!("a depth map needs one channel, found {}", raw.channels)));
    }
    use rayon::prelude::*;
    let valid = |v: f32| v.is_finite() && (kind == DepthKind::Disparity || v > 0.0);
    // Work in f64: 1/z of large depths loses precision in f32 before the subtraction. Computed
    // where needed, in parallel (a full-size f64 copy was ~100 MB of page faults at 12 MP).
    let lin = |v: f32| valid(v).then(|| if kind == DepthKind::Depth { 1.0 / v as f64 } else { v as f64 });
    let (n_valid, lo, hi) = raw
        .data
        .par_iter()
        .fold(
            || (0usize, f64::INFINITY, f64::NEG_INFINITY),
            |(n, a, b), &v| match lin(v) {
                Some(x) => (n + 1, a.min(x), b.max(x)),
                None => (n, a, b),
            },
        )
        .reduce(|| (0, f64::INFINITY, f64::NEG_INFINITY), |p, q| (p.0 + q.0, p.1.min(q.1), p.2.max(q.2)));
    if n_valid == 0 {
        let what = if kind == DepthKind::Depth { "finite and > 0" } else { "finite" };
        return Err(Error::input(path, format!("depth map has no valid value (every value must be {what})")));
    }
    // A range within float noise of the values (a few ulps of f32) is no range: it would be
    // stretched to [0, 1] and blur the noise.
    let span = if hi - lo > FLAT_RELATIVE * hi.abs().max(lo.abs()) { hi - lo } else { 0.0 };
    let data: Vec<f32> = raw
        .data
        .par_iter()
        .map(|&v| match lin(v) {
            Some(x) if span > 0.0 => ((x - lo) / span) as f32,
            _ => 0.0,
        })
        .collect();
    let mut map = Image::from_vec(raw.width, raw.height, 1, data).expect("same size");
    let n_invalid = raw.data.len() - n_valid;
    if n_invalid > 0 {
        let invalid: Vec<bool> = raw.data.par_iter().map(|&v| !valid(v)).collect();
        inpaint_telea(&mut map, &invalid, TeleaOptions::new(3.0))?;
        // Telea's gradient term may overshoot slightly: keep D inside [0, 1].
        map.map_inplace(|v| v.clamp(0.0, 1.0));
    }
    let z_range = (kind == DepthKind::Depth).then(|| (1.0 / hi, 1.0 / lo));
    Ok(Disparity { map, z_range, filled_fraction: n_invalid as f64 / raw.data.len() as f64 })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_to_disparity() {
        let raw = Image::from_vec(3, 1, 1, vec![1.0, 2.0, 4.0]).unwrap();
        let d = normalize(&raw, DepthKind::Depth, Path::new("d")).unwrap();
        assert_eq!(d.map.data, vec![1.0, 1.0 / 3.0, 0.0]);
        assert!((d.disparity_of_depth(2.0).unwrap() - 1.0 / 3.0).abs() < 1e-6);
        let bad = Image::from_vec(2, 1, 1, vec![f32::NAN, -1.0]).unwrap();
        assert!(normalize(&bad, DepthKind::Depth, Path::new("d.exr")).unwrap_err().to_string().contains("d.exr"));
    }

    #[test]
    fn flat_maps_are_flat() {
        // One value, and one value plus f32 rounding noise: no range to stretch.
        for vals in [vec![2.0, 2.0, 2.0], vec![3.0, 3.0 + 3.0 * f32::EPSILON, 3.0], vec![0.0, 0.0, 0.0]] {
            for kind in [DepthKind::Depth, DepthKind::Disparity] {
                let raw = Image::from_vec(3, 1, 1, vals.clone()).unwrap();
                let Ok(d) = normalize(&raw, kind, Path::new("d")) else { continue };
                assert!(d.is_flat() && d.map.data.iter().all(|&v| v == 0.0), "{vals:?} {kind:?}");
            }
        }
        // A small range that is not noise keeps its shape.
        let raw = Image::from_vec(3, 1, 1, vec![1.0, 1.001, 1.002]).unwrap();
        let d = normalize(&raw, DepthKind::Disparity, Path::new("d")).unwrap();
        assert!(!d.is_flat() && (d.map.data[1] - 0.5).abs() < 1e-3, "{:?}", d.map.data);
    }
}
