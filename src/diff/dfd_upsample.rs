//! A disparity map estimated at a reduced level, brought to the photo's size along the
//! all-in-focus photo's edges (joint bilateral upsampling, Kopf et al. 2007).
//!
//! `auto` optimises a large photo at a reduced level ([`super::dfd_plan`]); a plain resize then
//! smears each depth edge over the level's pixel (several photo pixels), so a subject's outline
//! comes back soft and offset. Each full-size pixel here averages the low-resolution map around
//! it, weighted by distance (in low-resolution pixels) and by how alike its colour is to each
//! low-resolution pixel's (the photo reduced the same way): across an edge of the photo the
//! other side's disparity hardly counts.
//!
//! Units: the map's (normalized disparity); colours compared sRGB-encoded (perceptual steps).

use crate::color::linear_to_srgb;
use crate::image::Image;
use rayon::prelude::*;

/// Spatial σ, in low-resolution pixels: a full-size pixel draws on about one low-resolution
/// pixel each side. With [`SIGMA_COLOUR`], chosen on bench seed 1 (6 generated scenes at
/// 256x192, K 19.2, optimised at 64x48; `examples/dfd_upsample_check.rs`) among σ 0.6-1 and
/// colour σ 0.02-0.2 (and no colour term): disparity MAE 0.3077 (bilinear) → 0.2924, the
/// far-focus re-render +0.03 dB; held out, seeds 2 and 3: 0.3155 → 0.3029 (+0.19 dB) and
/// 0.2214 → 0.2106 (+0.16 dB), a lower MAE in 12 of 12 scenes.
const SIGMA_SPACE: f32 = 0.8;
/// Low-resolution pixels each side of the nearest one that are read (the 5x5 window holds
/// the spatial Gaussian to 2σ).
const RADIUS: i64 = 2;
/// Range σ: colour distance (sRGB-encoded, 0..1 per channel, Euclidean) at which a neighbour's
/// weight falls to e^-1/2 (5 of 255 levels: sharply edge-preserving; 0.1 and more gained
/// nothing over a bilinear resize, see [`SIGMA_SPACE`]).
const SIGMA_COLOUR: f32 = 0.02;

/// `low` (one channel) brought to `aif`'s size (linear RGB) along the photo's edges. The
/// output stays within the range of `low`'s values around each pixel (a weighted mean). A
/// map already at the photo's size is returned as it is. Allocates the output and the
/// photo reduced to `low`'s size; O(pixels · 25).
pub fn upsample_guided(low: &Image, aif: &Image) -> Image {
    let (w, h, lw, lh) = (aif.width, aif.height, low.width, low.height);
    if (lw, lh) == (w, h) {
        return low.clone();
    }
    let encode = |img: &Image| -> Vec<[f32; 3]> {
        img.data.par_chunks(img.channels).map(|p| [linear_to_srgb(p[0]), linear_to_srgb(p[1]), linear_to_srgb(p[2])]).collect()
    };
    let guide_low = encode(&aif.resized(lw, lh));
    let guide = encode(aif);
    let (sx, sy) = (lw as f32 / w as f32, lh as f32 / h as f32);
    let (ks, kc) = (-0.5 / (SIGMA_SPACE * SIGMA_SPACE), -0.5 / (SIGMA_COLOUR * SIGMA_COLOUR));
    let data = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = (i % w, i / w);
            // The pixel's centre in low-resolution pixel coordinates (centres at integers).
            let (u, v) = ((x as f32 + 0.5) * sx - 0.5, (y as f32 + 0.5) * sy - 0.5);
            let (cu, cv) = (u.round() as i64, v.round() as i64);
            let c = guide[i];
            let (mut num, mut den) = (0.0f32, 0.0f32);
            for qy in (cv - RADIUS).max(0)..=(cv + RADIUS).min(lh as i64 - 1) {
                for qx in (cu - RADIUS).max(0)..=(cu + RADIUS).min(lw as i64 - 1) {
                    let q = qy as usize * lw + qx as usize;
                    let g = guide_low[q];
                    let dc = (c[0] - g[0]).powi(2) + (c[1] - g[1]).powi(2) + (c[2] - g[2]).powi(2);
                    let ds = (qx as f32 - u).powi(2) + (qy as f32 - v).powi(2);
                    let wgt = (ks * ds + kc * dc).exp();
                    num += wgt * low.data[q];
                    den += wgt;
                }
            }
            // Every weight underflows only when no neighbour's colour is anywhere near: the
            // nearest low-resolution value then.
            if den > 1e-20 { num / den } else { low.data[cv.clamp(0, lh as i64 - 1) as usize * lw + cu.clamp(0, lw as i64 - 1) as usize] }
        })
        .collect();
    Image::from_vec(w, h, 1, data).expect("one value per pixel")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A vertical colour edge at x = 37 of a 96-px photo and a map at a quarter size whose step
    /// falls inside one low-resolution pixel: upsampled, the step lands on the photo's edge
    /// (every pixel within 0.05 of its side's value more than a pixel from it), where a
    /// bilinear resize smears it over several pixels; a flat map stays flat; the output stays
    /// within the low map's range.
    #[test]
    fn the_step_follows_the_photos_edge() {
        let (w, h) = (96usize, 48usize);
        let edge = 37usize;
        let aif =
            Image::from_vec(w, h, 3, (0..w * h).flat_map(|i| if i % w < edge { [0.6, 0.5, 0.4] } else { [0.05, 0.1, 0.2] }).collect())
                .unwrap();
        let truth = |x: usize| if x < edge { 0.9 } else { 0.2 };
        let full = Image::from_vec(w, h, 1, (0..w * h).map(|i| truth(i % w)).collect()).unwrap();
        let low = full.resized(w / 4, h / 4);
        let up = upsample_guided(&low, &aif);
        let plain = low.resized(w, h);
        let off = |img: &Image| (0..w).filter(|&x| (img.data[h / 2 * w + x] - truth(x)).abs() > 0.05).count();
        assert!(
            (0..w).filter(|&x| x + 1 < edge || x > edge).all(|x| (up.data[h / 2 * w + x] - truth(x)).abs() <= 0.05),
            "{:?}",
            &up.data[h / 2 * w..h / 2 * w + w]
        );
        assert!(off(&plain) >= 4, "the plain resize should smear the step: {} pixels off", off(&plain));
        assert!(up.data.iter().all(|&v| (0.2 - 1e-6..=0.9 + 1e-6).contains(&v)));
        let flat = upsample_guided(&Image::filled(24, 12, 1, 0.4), &aif);
        assert!(flat.data.iter().all(|&v| (v - 0.4).abs() < 1e-6));
    }
}
