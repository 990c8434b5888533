//! The physical profile, differentiable: the forward of [`exact`]'s physical kernel with its
//! two hard edges rounded (see [`super::Smoothing`]), and its per-layer backward.
//!
//! Forward, per target `x`: each source `y` adds `wt = α_y·cov(R_y, r)/N(R_y)` (smooth disk
//! edge [`lens::disk_coverage_smooth`], flux norm [`lens::disk_norm_smooth`], `R = K·|d|`; or
//! the aperture's shape and its norm, [`ShapedSources`], as the exact kernel draws them),
//! split over the depth groups `γ(d_y, d_x)` ([`lens::depth_groups`]; with the ray test, the
//! behind share times whether the ray from `x` to `y` passes the layer's surface, [`RayTest`]),
//! to the groups' `[P, a]`; the groups are filled front to back
//! ([`lens::over_groups_smooth`]). Backward:
//! the groups' cotangents come from [`lens::over_groups_smooth_vjp`], then one pass over the
//! taps scatters them to the sources' colour, alpha and radius and to both disparities.
//!
//! [`exact`]: crate::render::exact

use super::Smoothing;
use super::accum::{self, PixelGrad};
use crate::render::aperture::Tap;
use crate::render::aperture::sources::ShapedSources;
use crate::render::layer::{A, CHANNELS, D, Layer};
use crate::render::lens::{self, coc_radius, depth_groups_with_grad, disk_coverage_smooth, disk_coverage_smooth_grad, disk_norm_smooth};
use crate::render::{RawLayer, RenderSettings, Role, raw};
use rayon::prelude::*;

/// Per-pixel terms of a layer's sources: relative disparity, CoC radius, flux norm and its
/// derivative in the radius, and the footprint: the smooth disk, or a shape
/// ([`ShapedSources`], whose coverage is already continuous in the radius: the smoothing's
/// edge width does not apply to it).
struct Sources {
    d: Vec<f32>,
    radius: Vec<f32>,
    norm: Vec<(f32, f32)>,
    shape: Option<ShapedSources>,
    edge_width: f32,
}

impl Sources {
    fn new(layer: &Layer, s: &RenderSettings, sm: &Smoothing) -> Self {
        let d: Vec<f32> = layer.image().data.chunks_exact(CHANNELS).map(|px| px[D] - s.focus).collect();
        // The thin lens's CoC, capped far beyond any image so ratios stay finite.
        let radius: Vec<f32> = d.iter().map(|&d| coc_radius(d, s.blur).min(lens::MAX_RADIUS)).collect();
        let shape = ShapedSources::new(s.aperture, layer.width(), layer.height());
        let norm = (0..d.len())
            .into_par_iter()
            .map(|j| match &shape {
                None => disk_norm_smooth(radius[j], sm.edge_width),
                Some(g) => g.norm_grad(radius[j]),
            })
            .collect();
        Sources { d, radius, norm, shape, edge_width: sm.edge_width }
    }

    /// The coverage of tap `t` by source `j`.
    #[inline]
    fn coverage(&self, j: usize, t: &Tap) -> f32 {
        match &self.shape {
            None => disk_coverage_smooth(self.radius[j], t.r, self.edge_width),
            Some(g) => g.coverage(j, self.radius[j], self.d[j] > 0.0, t),
        }
    }

    /// What target `i` multiplies the weights reaching it by (a cat's eye's gain, see
    /// [`ShapedSources::target_gain`]; 1 otherwise).
    #[inline]
    fn target_gain(&self, i: usize) -> f32 {
        self.shape.as_ref().map_or(1.0, |g| g.target_gain(i))
    }

    /// Source `j`'s factor at a target of gain `target`.
    #[inline]
    fn gain(&self, j: usize, target: f32) -> f64 {
        ShapedSources::gain_of(self.radius[j], target) as f64
    }

    /// `(coverage, ∂coverage/∂R)` of tap `t` by source `j`.
    #[inline]
    fn coverage_grad(&self, j: usize, t: &Tap) -> (f32, f32) {
        let r = self.radius[j];
        match &self.shape {
            None => (disk_coverage_smooth(r, t.r, self.edge_width), disk_coverage_smooth_grad(r, t.r, self.edge_width)),
            Some(g) => g.coverage_grad(j, r, self.d[j] > 0.0, t),
        }
    }
}

/// What the tape keeps of a physical layer: the raw render (for compositing) and each
/// target's three depth groups `[P_r, P_g, P_b, a]` before the fill (96 bytes per pixel).
pub(super) struct Record {
    pub raw: RawLayer,
    pub groups: Vec<[[f64; 4]; 3]>,
}

/// The smooth physical forward of one layer, tap by tap (as [`crate::render::exact`]'s
/// physical kernel, with the smooth coverage, norm and fill). Rows in parallel; allocates the
/// raw output, the groups and three planes of per-pixel terms.
pub(super) fn record(layer: &Layer, s: &RenderSettings, sm: &Smoothing, taps: &[Tap], role: Role, ray: bool) -> Record {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let src = Sources::new(layer, s, sm);
    let reach = ray_reach(s);
    let mut out = vec![0f32; w * h * raw::CHANNELS];
    let mut groups = vec![[[0f64; 4]; 3]; w * h];
    out.par_chunks_mut(w * raw::CHANNELS).zip(groups.par_chunks_mut(w)).enumerate().for_each(|(y, (row, grow))| {
        for x in 0..w {
            let dx = src.d[y * w + x];
            let gain = src.target_gain(y * w + x);
            let g = &mut grow[x];
            for t in taps {
                let j = clamped(x, y, t, w, h);
                let px = &img.data[j * CHANNELS..(j + 1) * CHANNELS];
                let cov = src.coverage(j, t);
                if px[A] == 0.0 || cov == 0.0 {
                    continue;
                }
                let wt = (px[A] * (cov / src.norm[j].0)) as f64 * src.gain(j, gain);
                let mut split = if (t.di == 0 && t.dj == 0) || !s.occlusion { [0.0, 1.0, 0.0] } else { lens::depth_groups(src.d[j], dx) };
                if ray && split[2] > 0.0 {
                    split[2] *= RayTest::new(&src.d, w, h, (x, y), j, t, reach).map_or(1.0, |r| r.clear);
                }
                lens::add_to_groups(g, wt, split, px);
            }
            let p = lens::over_groups_smooth(g, sm.fill_width as f64);
            let a = p[3] as f32;
            let vis = match role {
                Role::Front => a,
                Role::Backdrop => a.max(img.data[(y * w + x) * CHANNELS + A]),
            };
            row[x * raw::CHANNELS..(x + 1) * raw::CHANNELS].copy_from_slice(&[p[0] as f32, p[1] as f32, p[2] as f32, a, vis]);
        }
    });
    Record { raw: RawLayer::new(w, h, out, layer), groups }
}

/// Row-major index of the source a tap reads from target `(x, y)`, replicate-padded.
#[inline(always)]
fn clamped(x: usize, y: usize, t: &Tap, w: usize, h: usize) -> usize {
    let yy = (y as i64 + t.di as i64).clamp(0, h as i64 - 1) as usize;
    let xx = (x as i64 + t.dj as i64).clamp(0, w as i64 - 1) as usize;
    yy * w + xx
}

/// Gradients of one layer given, per pixel, the cotangents `[g_P_r, g_P_g, g_P_b, g_A, _]` of
/// its filled `[P, A]` (see [`super::RawCot`]). Per target: the groups' cotangents
/// (O(1)), then one pass over the taps. Rows in parallel bands; allocates the bands and three
/// planes of per-pixel terms.
pub(super) fn backward(
    layer: &Layer,
    s: &RenderSettings,
    sm: &Smoothing,
    taps: &[Tap],
    rec: &Record,
    cot: &[super::RawCot],
    ray: bool,
) -> Vec<PixelGrad> {
    let img = layer.image();
    let (w, h) = (img.width, img.height);
    let src = Sources::new(layer, s, sm);
    let reach = ray_reach(s);
    accum::scatter_rows(w, h, s.lens / 2, |y, band| {
        for x in 0..w {
            let i = y * w + x;
            let c = &cot[i];
            if c[..4].iter().all(|&v| v == 0.0) {
                continue;
            }
            let gg = lens::over_groups_smooth_vjp(&rec.groups[i], sm.fill_width as f64, &[c[0], c[1], c[2], c[3]]);
            let dx = src.d[i];
            let gain = src.target_gain(i);
            let mut g_dx = 0f64;
            for t in taps {
                let j = clamped(x, y, t, w, h);
                let (cov, dcov) = src.coverage_grad(j, t);
                if cov == 0.0 && dcov == 0.0 {
                    continue;
                }
                let px = &img.data[j * CHANNELS..(j + 1) * CHANNELS];
                // The centre tap and a render without occlusion use one group.
                let grouped = s.occlusion && !(t.di == 0 && t.dj == 0);
                let (mut split, dsplit) = if grouped { depth_groups_with_grad(src.d[j], dx) } else { ([0.0, 1.0, 0.0], [0.0; 3]) };
                // The behind group's unblocked share, and the ray test that scales it.
                let behind = split[2];
                let test = if ray && grouped && behind > 0.0 { RayTest::new(&src.d, w, h, (x, y), j, t, reach) } else { None };
                if let Some(r) = &test {
                    split[2] *= r.clear;
                }
                // h_g: the cotangent of a unit of weight in group g carrying this source's colour.
                let hg: [f64; 3] =
                    std::array::from_fn(|k| gg[k][0] * px[0] as f64 + gg[k][1] * px[1] as f64 + gg[k][2] * px[2] as f64 + gg[k][3]);
                let g_wt: f64 = (0..3).map(|k| split[k] as f64 * hg[k]).sum();
                // The gain divides the norm: u = cov·gain / N.
                let gj = src.gain(j, gain);
                let (norm, dnorm) = (src.norm[j].0 as f64 / gj, src.norm[j].1 as f64 / gj);
                let u = cov as f64 / norm;
                let sg = band.at(j);
                sg.alpha += g_wt * u;
                let a = px[A] as f64;
                if a == 0.0 {
                    continue;
                }
                let wt = a * u;
                for (ch, g) in sg.colour.iter_mut().enumerate() {
                    *g += wt * (0..3).map(|k| split[k] as f64 * gg[k][ch]).sum::<f64>();
                }
                // ∂u/∂R = cov'/N - (cov/N)·N'/N, finite also where N overflowed to inf.
                sg.radius += g_wt * a * (dcov as f64 / norm - u * (dnorm / norm));
                if grouped {
                    // The groups' own tests read d_source - d_target; the ray test scales the
                    // behind share and reads both disparities and the surface at the crossing.
                    let clear = test.as_ref().map_or(1.0, |r| r.clear as f64);
                    let g_d = wt * (dsplit[0] as f64 * hg[0] + dsplit[1] as f64 * hg[1] + dsplit[2] as f64 * clear * hg[2]);
                    sg.disparity += g_d;
                    g_dx -= g_d;
                    if let Some(r) = &test {
                        let hb = wt * hg[2] * behind as f64;
                        band.at(j).disparity += hb * r.d_source;
                        g_dx += hb * r.d_target;
                        for &(k, dk) in &r.corners {
                            band.at(k).disparity += hb * dk;
                        }
                    }
                }
            }
            band.at(i).disparity += g_dx;
        }
    })
}

/// How far (pixels, per axis) from its target the ray test may sample the surface: one less
/// than the window's half-size, so the crossing's bilinear corners stay in the rows a target's
/// backward may write (see [`accum::scatter_rows`]). A ray through a pixel is offset at most
/// by the CoC at the target's depth, which the window holds; only the disk's soft edge reaches
/// beyond.
fn ray_reach(s: &RenderSettings) -> i64 {
    (s.lens / 2) as i64 - 1
}

/// The ray test of one (target, tap) pair: whether the ray from the target to the tap's
/// source, behind it, passes the surface where it crosses the target's depth
/// ([`lens::ray_crossing`], [`lens::ray_clear`]), the layer's disparity there read
/// bilinearly (replicate-padded, the crossing kept within `reach` of the target per axis),
/// and the derivatives of the result in the target's, the source's and the four corners'
/// relative disparities.
struct RayTest {
    clear: f32,
    d_target: f64,
    d_source: f64,
    corners: [(usize, f64); 4],
}

impl RayTest {
    /// `j` is the tap's source, `clamped(x, y, t, w, h)`, which the caller has already.
    fn new(d: &[f32], w: usize, h: usize, (x, y): (usize, usize), j: usize, t: &Tap, reach: i64) -> Option<RayTest> {
        let (ep, es) = (d[y * w + x], d[j]);
        let (frac, dt_dp, dt_ds) = lens::ray_crossing(ep, es)?;
        // One axis: the crossing's coordinate and its derivative in `frac` (0 where clamped).
        let axis = |p: usize, off: i32, n: usize| {
            let raw = p as f64 + frac * off as f64;
            let lo = (p as i64 - reach).max(0) as f64;
            let hi = ((p as i64 + reach).min(n as i64 - 1) as f64).max(lo);
            let q = raw.clamp(lo, hi);
            let i0 = (q.floor() as usize).min(n.saturating_sub(2));
            let f = if n > 1 { q - i0 as f64 } else { 0.0 };
            (i0, (i0 + 1).min(n - 1), f, if q == raw { off as f64 } else { 0.0 })
        };
        let (x0, x1, fx, dqx) = axis(x, t.dj, w);
        let (y0, y1, fy, dqy) = axis(y, t.di, h);
        let corners = [
            (y0 * w + x0, (1.0 - fx) * (1.0 - fy)),
            (y0 * w + x1, fx * (1.0 - fy)),
            (y1 * w + x0, (1.0 - fx) * fy),
            (y1 * w + x1, fx * fy),
        ];
        let v = |k: usize| d[corners[k].0] as f64;
        let dq: f64 = corners.iter().map(|&(i, wt)| d[i] as f64 * wt).sum();
        // ∂d_q/∂frac through the crossing's position.
        let slope = ((1.0 - fy) * (v(1) - v(0)) + fy * (v(3) - v(2))) * dqx + ((1.0 - fx) * (v(2) - v(0)) + fx * (v(3) - v(1))) * dqy;
        let (clear, g) = lens::ray_clear(dq as f32, ep);
        let g = g as f64;
        Some(RayTest {
            clear,
            d_target: g * (1.0 - slope * dt_dp),
            d_source: -g * slope * dt_ds,
            corners: corners.map(|(i, wt)| (i, -g * wt)),
        })
    }
}
