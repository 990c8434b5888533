//! How one source's footprint is drawn at full resolution: the exact taps of a small source
//! (a stencil table shared by every source of a layer), the hard disk of the same area for a
//! mid-sized one (with the soft step's edge as 3 nested disks where it shows), and the exact
//! footprint of a bright source at any radius in O(σ) writes ([`rim_disk`]).
//!
//! Radii are in pixels. A source's footprint is the model's soft step `S(σ, r)` times the
//! energy density `1/σ²` (see [`super::super::lens::energy`]), clipped to the lens window.

use super::super::RenderSettings;
use super::super::aperture::Tap;
use super::super::lens::{
    FACTORED_STEP_MAX, MAX_RADIUS, Profile, STEP_GAIN, STEP_LN_OFFSET, coc_radius, disk_coverage, disk_coverage_smooth, scatter_radius,
    soft_step, step_source_factor, step_tap_factor,
};
use super::super::splat::{Stripe, lattice_row_reach};
use std::f32::consts::{FRAC_PI_3, PI};

/// The soft step's edge as a mixture of hard disks: radius offsets and weights of a 3-point
/// quadrature of the logistic distribution (scale 1/3 px, standard deviation π/(3√3) px).
/// The nodes are ±√3 standard deviations = ±π/3 px (3-point Gauss–Hermite).
pub(super) const SOFT_EDGE: [(f32, f32); 3] = [(-FRAC_PI_3, 1.0 / 6.0), (0.0, 2.0 / 3.0), (FRAC_PI_3, 1.0 / 6.0)];
/// One hard disk at the equivalent radius (the soft edge's cost is 3× the spans).
pub(super) const HARD_EDGE: [(f32, f32); 1] = [(0.0, 1.0)];

/// Stencil taps reach `σ + STENCIL_TAIL` px: beyond, the soft step is below 5.5e-5 of its
/// plateau (a ring that holds < 0.1% of a source's energy).
pub(in crate::render) const STENCIL_TAIL: f32 = 2.5;

/// Inside this distance from the edge (`r ≤ σ - RIM`) the soft step is within `10·e^-12`
/// (6.2e-5) of 1.
pub(in crate::render) const RIM: f32 = 4.0;

/// Radius of the hard disk with the same area as the soft step's footprint
/// (`∫ 2πr·S(σ, r) dr = π·((σ - ln10/3)² + π²/27)`, a Fermi–Dirac integral: the step is
/// at 1/2 where `r = σ - ln10/3`; the neglected term is `O(e^{-3(σ - ln10/3)})` of the area).
#[inline]
pub(super) fn equivalent_radius(sigma: f32) -> f32 {
    let m = (sigma - STEP_LN_OFFSET / STEP_GAIN).max(0.0);
    (m * m + PI * PI / 27.0).sqrt()
}

/// The radius a source is drawn with: its scatter radius σ, capped at `p + RIM` for a
/// window of half-size `p`. Beyond `p + RIM` the soft step is within 6.2e-5 of 1 at every tap
/// of the window, so the footprint is the window itself whatever σ is; only the energy
/// density `1/σ²` still depends on σ. Without the cap a circle far larger than the image went
/// to a coarse grid whose cells are larger than the window, and its light was lost.
#[inline]
pub(super) fn drawn_radius(sigma: f32, p: usize) -> f32 {
    sigma.min(p as f32 + RIM)
}

/// Half-width of the physical disk's edge ramp ([`disk_coverage`]): a disk of radius `r` covers
/// its taps fully out to `r - EDGE` and not at all from `r + EDGE` on.
pub(super) const EDGE: f32 = 0.5;

/// A source's footprint radius at relative disparity `d` (blur `k`), pixels: the official
/// scatter radius `σ = K·|d| + 1`, or the physical CoC `r = K·|d|` (capped as the exact kernel
/// caps it).
#[inline]
pub(super) fn source_radius(profile: Profile, d: f32, k: f32) -> f32 {
    match profile {
        Profile::Official => scatter_radius(d, k),
        Profile::Physical => coc_radius(d, k).min(MAX_RADIUS),
    }
}

/// The radius a source of footprint radius `radius` is drawn with in a window of half-size
/// `p`: [`drawn_radius`] for the official footprint; for the physical disk, `r` capped at
/// `p + 2·EDGE`: every tap of the window (`ρ < p`) is fully covered from `r = p + EDGE` on, so
/// beyond the footprint is the window itself and only the norm still depends on `r`.
///
/// A non-disc aperture is capped where its own shape stops changing inside the window
/// ([`Aperture::drawn_cap`]).
///
/// [`Aperture::drawn_cap`]: super::super::aperture::Aperture::drawn_cap
#[inline]
pub(super) fn drawn(s: &RenderSettings, radius: f32, p: usize) -> f32 {
    match (s.profile, s.aperture.drawn_cap(p)) {
        (Profile::Official, _) => drawn_radius(radius, p),
        (Profile::Physical, None) => radius.min(p as f32 + 2.0 * EDGE),
        (Profile::Physical, Some(cap)) => radius.min(cap),
    }
}

/// Radius of the hard disk with the area of a drawn footprint: [`equivalent_radius`] for the
/// soft step; `√(r² + 1/12)` for the physical ramped disk (its area `π(r² + 1/12)`, see
/// [`super::super::lens::disk_norm`]). Used by the coarse grids.
#[inline]
pub(super) fn equivalent(profile: Profile, drawn: f32) -> f32 {
    match profile {
        Profile::Official => equivalent_radius(drawn),
        Profile::Physical => (drawn * drawn + 1.0 / 12.0).sqrt(),
    }
}

/// The lens window's taps out to the stencil reach, laid out for [`Stencil::weights`]:
/// built once per layer, O(reach²).
pub(super) struct Stencil {
    /// Distances of the taps, sorted by row offset.
    r: Vec<f32>,
    /// Their soft-step tap factors (`lens::step_tap_factor`; infinite beyond the factored
    /// form's range).
    factor: Vec<f32>,
    /// Where each row offset `-p..=p` starts in `r` and `factor` (`2p + 2` entries).
    rows: Vec<usize>,
    /// Largest row offset of a tap.
    pub(super) p: i64,
}

impl Stencil {
    /// The taps of the lens window `taps` (as [`super::super::aperture::disk_taps_within`]
    /// lists them: row offset outer).
    pub(super) fn new(taps: &[Tap]) -> Self {
        let p = taps.iter().map(|t| t.di.abs() as i64).max().unwrap_or(0);
        let rows = (-p..=p + 1).map(|di| taps.partition_point(|t| (t.di as i64) < di)).collect();
        Stencil { r: taps.iter().map(|t| t.r).collect(), factor: taps.iter().map(|t| step_tap_factor(t.r)).collect(), rows, p }
    }

    /// The exact taps `E(σ, r)` of a source with scatter radius `sigma` (energy density
    /// `dens`), per stencil row `-p..=p` as (first column offset `-jm`, weights of columns
    /// `-jm..=jm`), out to `σ + STENCIL_TAIL`. Reuses `out`'s buffers.
    pub(super) fn weights(&self, sigma: f32, dens: f32, out: &mut Vec<(i64, Vec<f32>)>) {
        let rows = (2 * self.p + 1) as usize;
        out.resize_with(rows, Default::default);
        let reach = sigma + STENCIL_TAIL;
        let fs = step_source_factor(sigma);
        for (k, (jm_out, e)) in out.iter_mut().enumerate() {
            e.clear();
            let Some((a, b, jm)) = self.row_span(k, reach) else { continue };
            if sigma <= FACTORED_STEP_MAX {
                e.extend(self.factor[a..b].iter().map(|&fr| dens / (1.0 + fs * fr)));
            } else {
                // Beyond the factored form's range (quality 8 draws every radius as a stencil):
                // the plain stable step, one exponential per tap.
                e.extend(self.r[a..b].iter().map(|&r| dens * soft_step(sigma, r)));
            }
            *jm_out = jm as i64;
        }
    }

    /// The taps of stencil row `k` (row offset `k - p`) closer than `reach`: their index range
    /// `a..b` in the row-sorted tap lists and the largest column offset `jm`; None when the row
    /// has none. Row `di` holds `dj = -m..=m`; kept are `|dj| < sqrt(reach² - di²)`.
    #[inline]
    fn row_span(&self, k: usize, reach: f32) -> Option<(usize, usize, usize)> {
        let di = k as i64 - self.p;
        let (start, end) = (self.rows[k], self.rows[k + 1]);
        let rem = reach * reach - (di * di) as f32;
        if rem <= 0.0 || end == start {
            return None;
        }
        let m = (end - start) / 2;
        // `⌈√rem⌉ - 1` without `ceil`, a libm call on the baseline x86-64 (2% of a 2 MP
        // preview at background focus): the truncation, one less where `√rem` is whole.
        let root = rem.sqrt();
        let t = root as usize;
        let jm = if (t as f32) < root { t } else { t.saturating_sub(1) }.min(m);
        Some((start + m - jm, start + m + jm + 1, jm))
    }

    /// The physical taps `disk_coverage(r, ρ) / norm` of a source with CoC `r` and flux norm
    /// `norm` ([`super::super::lens::disk_norm`] of its true radius), laid out as
    /// [`Stencil::weights`] lays them out, out to `r + EDGE`. The division (not a product with
    /// `1/norm`) keeps an in-focus source's weight exactly 1, as in the exact kernel.
    pub(super) fn coverage_weights(&self, r: f32, norm: f32, out: &mut Vec<(i64, Vec<f32>)>) {
        let rows = (2 * self.p + 1) as usize;
        out.resize_with(rows, Default::default);
        let reach = r + EDGE;
        for (k, (jm_out, e)) in out.iter_mut().enumerate() {
            e.clear();
            let Some((a, b, jm)) = self.row_span(k, reach) else { continue };
            // Into a sized slice: the loop vectorizes (with `extend` it did not, and these
            // weights, made afresh for every source of a depth ramp, were a fifth of a 2 MP
            // preview's scan at background focus).
            e.resize(b - a, 0.0);
            for (w, &rho) in e.iter_mut().zip(&self.r[a..b]) {
                *w = disk_coverage(r, rho) / norm;
            }
            *jm_out = jm as i64;
        }
    }
}

/// The exact footprint `E(σ, r)` of one source at integer position (sx, sy), clipped to the
/// lens window `|offset| < p` and to the stripe, in O(σ) writes: per row, one span of the
/// plateau (`r ≤ σ - RIM`, soft step taken as 1) and explicit taps on the rim out to
/// `σ + STENCIL_TAIL`. `e` is scratch (one rim row). Returns the number of writes.
pub(super) fn rim_disk(st: &mut Stripe, centre: (i64, i64), sigma: f32, dens: f32, p: i64, v: [f32; 4], e: &mut Vec<f32>) -> u64 {
    soft_step_disk([st], centre, sigma, dens, p, [v], e)
}

/// [`rim_disk`] into `N` stripes at once (the same footprint of values `vs[k]` into `sts[k]`,
/// its rim's taps computed once): the official footprint of the differentiable span render
/// (`render::backward::span`), which draws a source into two depth bins.
pub(in crate::render) fn soft_step_disk<const N: usize>(
    sts: [&mut Stripe; N],
    centre: (i64, i64),
    sigma: f32,
    dens: f32,
    p: i64,
    vs: [[f32; 4]; N],
    e: &mut Vec<f32>,
) -> u64 {
    let rim = Rim { reach: sigma + STENCIL_TAIL, inner: sigma - RIM, plateau: vs.map(|v| v.map(|c| c * dens)) };
    rim_footprint(sts, centre, &rim, p, |r| dens * soft_step(sigma, r), vs, e)
}

/// The physical footprint `disk_coverage(r, ρ) / norm` of one source of drawn CoC `r` at
/// (sx, sy), exact, in O(r) writes like [`rim_disk`]: the plateau (`ρ ≤ r - EDGE`, coverage
/// exactly 1) as one span per row, the one-pixel ramp as explicit taps. (The span disk of
/// [`Stripe::disk`] is no substitute: its edge ramps along the row, not along the radius, and
/// it leaves out the rows beyond `r`; see the test `span_disk_edge_is_not_the_physical_ramp`.)
pub(super) fn coverage_disk(st: &mut Stripe, (sx, sy): (i64, i64), r: f32, norm: f32, p: i64, v: [f32; 4], e: &mut Vec<f32>) -> u64 {
    let rim = Rim { reach: r + EDGE, inner: r - EDGE, plateau: [v.map(|c| c / norm)] };
    rim_footprint([st], (sx, sy), &rim, p, |rho| disk_coverage(r, rho) / norm, [v], e)
}

/// The smooth-edged physical disk of the differentiable renders
/// ([`lens::disk_coverage_smooth`] with an edge `width` pixels wide, over the flux `norm`),
/// drawn as [`coverage_disk`] draws the hard one: the plateau as one span per row, the edge as
/// taps; the same disk of values `vs[k]` into each stripe `sts[k]` (the edge's coverage is
/// computed once for all). Same clipping (window `|offset| < p`, the stripes' rows, which must
/// be the same). Returns the writes.
///
/// [`lens::disk_coverage_smooth`]: super::super::lens::disk_coverage_smooth
#[allow(clippy::too_many_arguments)]
pub(in crate::render) fn smooth_coverage_disk<const N: usize>(
    sts: [&mut Stripe; N],
    centre: (i64, i64),
    r: f32,
    width: f32,
    norm: f32,
    p: i64,
    vs: [[f32; 4]; N],
    e: &mut Vec<f32>,
) -> u64 {
    let rim = Rim { reach: r + 0.5 * width, inner: r - 0.5 * width, plateau: vs.map(|v| v.map(|c| c / norm)) };
    rim_footprint(sts, centre, &rim, p, |rho| disk_coverage_smooth(r, rho, width) / norm, vs, e)
}

/// The pixels of row offset `dy` that a rim footprint (value constant within `inner` of the
/// centre, tapered out to `reach`) covers in a window of half-size `p` (strict disk, as the
/// official mask): `(xi, xo)`, the plateau is `|dx| ≤ xi` (none when `xi < 0`) and the taper
/// `xi < |dx| ≤ xo`; None where the row holds nothing. Shared by the scatter
/// ([`rim_footprint`]) and the gathers of the differentiable span render
/// (`render::backward::span`), so both walk the same pixels.
// Always inlined: the per-row step of every exact disk.
#[inline(always)]
pub(in crate::render) fn rim_row(reach: f32, inner: f32, p: i64, dy: i64) -> Option<(i64, i64)> {
    // Largest |dx| inside the window (strict disk, as the official mask). A footprint that
    // reaches at most p - 1 lies inside it (xo² ≤ reach² - dy² < p² - dy²): no clip to compute.
    let m = if reach <= (p - 1) as f32 { i64::MAX } else { lattice_row_reach(p, dy)? };
    let dyf = (dy * dy) as f32;
    let xo = if reach * reach > dyf { ((reach * reach - dyf).sqrt() as i64).min(m) } else { return None };
    let xi = if inner > 0.0 && inner * inner >= dyf { ((inner * inner - dyf).sqrt() as i64).min(xo) } else { -1 };
    Some((xi, xo))
}

/// [`rim_row`] with the taper's taps `tap(ρ)` of columns `dx = xi + 1 ..= xo` in `e` (the left
/// taper mirrors them). Shared by [`rim_footprint`] and the radius bins' templates
/// ([`super::binned`]), so both draw the same pixels with the same weights.
#[inline(always)]
pub(super) fn rim_row_taps(reach: f32, inner: f32, p: i64, dy: i64, tap: impl Fn(f32) -> f32, e: &mut Vec<f32>) -> Option<(i64, i64)> {
    let (xi, xo) = rim_row(reach, inner, p, dy)?;
    let dyf = (dy * dy) as f32;
    e.clear();
    e.extend((xi + 1..=xo).map(|dx| tap(((dx * dx) as f32 + dyf).sqrt())));
    Some((xi, xo))
}

/// A footprint's rings: its value is `plateau` within `inner` of the centre and `tap(ρ)·v`
/// out to `reach` (exclusive); `N` copies of it (see [`rim_footprint`]).
struct Rim<const N: usize> {
    reach: f32,
    inner: f32,
    plateau: [[f32; 4]; N],
}

/// Draws a [`Rim`] footprint at (sx, sy), clipped to the window `|offset| < p` and the stripe:
/// copy `k` (plateau `rim.plateau[k]`, rim `tap(ρ)·vs[k]`) into `sts[k]` (stripes of the same
/// rows), the geometry and the rim's taps computed once.
// Always inlined: each caller's tap is then a direct call (rim_disk's arithmetic unchanged);
// `N` is a constant, so the copies' loops unroll (the kernels' callers draw one).
#[inline(always)]
fn rim_footprint<const N: usize>(
    mut sts: [&mut Stripe; N],
    (sx, sy): (i64, i64),
    rim: &Rim<N>,
    p: i64,
    tap: impl Fn(f32) -> f32,
    vs: [[f32; 4]; N],
    e: &mut Vec<f32>,
) -> u64 {
    let (y0, y1) = sts[0].rows();
    let (reach, inner) = (rim.reach, rim.inner);
    let rr = (reach.min(1e9).ceil() as i64).min(p);
    let mut ops = 0;
    for row in (sy - rr).max(y0)..=(sy + rr).min(y1 - 1) {
        let Some((xi, xo)) = rim_row_taps(reach, inner, p, row - sy, &tap, e) else { continue };
        if xi >= 0 {
            for (st, plateau) in sts.iter_mut().zip(&rim.plateau) {
                st.pixels(row, sx - xi, sx + xi, *plateau);
            }
            ops += 4 * N as u64;
        }
        if xo > xi {
            for (st, v) in sts.iter_mut().zip(&vs) {
                st.tap_row(sx + xi + 1, row, e, *v);
            }
            if xi >= 0 || xo > 0 {
                // The left rim mirrors the right one (without the centre column when xi < 0).
                let skip = usize::from(xi < 0);
                e.reverse();
                let left = &e[..e.len() - skip];
                for (st, v) in sts.iter_mut().zip(&vs) {
                    st.tap_row(sx - xo, row, left, *v);
                }
            }
            ops += 2 * (N * e.len()) as u64;
        }
    }
    ops
}

#[cfg(test)]
mod tests {
    use super::super::super::aperture::{disk_taps, disk_taps_within};
    use super::super::super::lens::energy;
    use super::*;

    /// The soft step in f64, the literal official formula.
    fn step_f64(sigma: f64, r: f64) -> f64 {
        0.1 / (0.1 + (-3.0 * (sigma - r)).exp())
    }

    #[test]
    fn equivalent_radius_has_the_soft_footprint_area() {
        // Radii the kernel draws as disks (σ ≥ stencil_max ≥ 3) and beyond.
        for sigma in [3.0f32, 3.7, 5.0, 8.0, 13.5, 30.0, 64.0, 150.0] {
            // ∫ 2πr·S(σ, r) dr by the midpoint rule (the integrand is smooth; 1e-3 px steps).
            let (dr, end) = (1e-3f64, sigma as f64 + 20.0);
            let area: f64 = (0..(end / dr) as usize)
                .map(|i| (i as f64 + 0.5) * dr)
                .map(|r| 2.0 * std::f64::consts::PI * r * step_f64(sigma as f64, r) * dr)
                .sum();
            let rho = equivalent_radius(sigma) as f64;
            let disk = std::f64::consts::PI * rho * rho;
            assert!((disk - area).abs() <= 1e-4 * area, "σ={sigma}: disk {disk} vs footprint {area}");
        }
    }

    #[test]
    fn drawn_radius_caps_where_the_window_is_flat() {
        for p in [1usize, 2, 7, 30, 200, 1500] {
            let cap = p as f32 + RIM;
            assert_eq!(drawn_radius(0.5 * p as f32 + 1.0, p), 0.5 * p as f32 + 1.0);
            assert_eq!(drawn_radius(cap + 1.0, p), cap);
            assert_eq!(drawn_radius(1e30, p), cap);
            // At the cap (and so beyond: the step grows with σ) every tap of the window is
            // within 6.2e-5 of the plateau.
            let rmax = disk_taps(2 * p + 1).iter().map(|t| t.r).fold(0.0, f32::max);
            let low = step_f64(cap as f64, rmax as f64);
            assert!(1.0 - low <= 6.2e-5, "p={p}: 1 - S = {}", 1.0 - low);
            assert!((1.0 - soft_step(cap, rmax)) <= 6.2e-5);
        }
    }

    #[test]
    fn stencil_weights_are_the_exact_taps() {
        for (lens, sigma) in [(15usize, 1.0f32), (31, 3.3), (61, 7.9), (61, 24.0), (301, 40.0)] {
            let taps = disk_taps_within(lens, sigma + STENCIL_TAIL);
            let stencil = Stencil::new(&taps);
            let dens = 1.0 / (sigma * sigma);
            let mut w = Vec::new();
            stencil.weights(sigma, dens, &mut w);
            let mut seen = 0;
            for (k, (jm, e)) in w.iter().enumerate() {
                let di = k as i64 - stencil.p;
                for (c, &got) in e.iter().enumerate() {
                    let dj = c as i64 - jm;
                    let r = ((di * di + dj * dj) as f32).sqrt();
                    let want = energy(sigma, r, 1.0);
                    assert!((got - want).abs() <= 2e-6 * dens, "lens {lens} σ={sigma} ({di},{dj}): {got} vs {want}");
                    seen += 1;
                }
            }
            // Every dropped tap is beyond the tail, where the step is negligible.
            assert!(seen <= taps.len());
            let kept: f32 = w.iter().flat_map(|(_, e)| e.iter()).sum();
            let all: f32 = disk_taps(lens).iter().map(|t| energy(sigma, t.r, 1.0)).sum();
            assert!((all - kept).abs() <= 1e-3 * all, "lens {lens} σ={sigma}: kept {kept} of {all}");
        }
    }

    #[test]
    fn rim_disk_is_the_exact_footprint() {
        let (w, h) = (120usize, 96usize);
        for (sigma, p, (sx, sy)) in [(6.0f32, 40i64, (50i64, 40i64)), (19.3, 60, (60, 50)), (35.0, 30, (10, 90)), (80.0, 200, (-5, 20))] {
            let dens = 1.0 / (sigma * sigma);
            let v = [2.0, 0.5, 7.0, 1.0];
            let mut st = Stripe::new(w);
            st.reset(0, h);
            let mut scratch = Vec::new();
            rim_disk(&mut st, (sx, sy), sigma, dens, p, v, &mut scratch);
            let mut row = vec![0f32; w * 4];
            for y in 0..h {
                row.fill(0.0);
                st.add_row_to(y, &mut row);
                for x in 0..w {
                    let (dx, dy) = (x as i64 - sx, y as i64 - sy);
                    let inside = dx * dx + dy * dy < p * p;
                    let want = if inside { energy(sigma, ((dx * dx + dy * dy) as f32).sqrt(), 1.0) } else { 0.0 };
                    for c in 0..4 {
                        let got = row[x * 4 + c];
                        assert!(
                            (got - v[c] * want).abs() <= 6.2e-5 * v[c] * dens + 1e-7,
                            "σ={sigma} ({x},{y})[{c}]: {got} vs {}",
                            v[c] * want
                        );
                    }
                }
            }
        }
    }

    /// The physical disk drawn by [`coverage_disk`] is the plain formula tap by tap (window and
    /// stripe clipping included); the splat's span disk of the same radius is not (measured
    /// here: its edge ramps along the row and it stops at the rows within `r`).
    #[test]
    fn coverage_disk_is_the_physical_footprint_and_the_span_disk_is_not() {
        use super::super::super::lens::{disk_coverage, disk_norm};
        use super::super::super::splat::Window;
        let (w, h) = (120usize, 96usize);
        let mut span_err = 0f32;
        for (r, p, (sx, sy)) in
            [(0.3f32, 40i64, (50i64, 40i64)), (4.0, 40, (50, 40)), (9.7, 60, (60, 50)), (35.0, 30, (10, 90)), (80.0, 200, (-5, 20))]
        {
            let norm = disk_norm(r);
            let v = [2.0, 0.5, 7.0, 1.0];
            let (mut st, mut disk) = (Stripe::new(w), Stripe::new(w));
            st.reset(0, h);
            disk.reset(0, h);
            coverage_disk(&mut st, (sx, sy), r, norm, p, v, &mut Vec::new());
            disk.disk(sx as f32, sy as f32, r, Window::Lattice(p), v.map(|c| c / norm));
            let (mut row, mut drow) = (vec![0f32; w * 4], vec![0f32; w * 4]);
            for y in 0..h {
                row.fill(0.0);
                drow.fill(0.0);
                st.add_row_to(y, &mut row);
                disk.add_row_to(y, &mut drow);
                for x in 0..w {
                    let (dx, dy) = (x as i64 - sx, y as i64 - sy);
                    let inside = dx * dx + dy * dy < p * p;
                    let want = if inside { disk_coverage(r, ((dx * dx + dy * dy) as f32).sqrt()) / norm } else { 0.0 };
                    let got = row[x * 4 + 3];
                    assert!((got - want).abs() <= 1e-6 * (1.0 + want), "r={r} ({x},{y}): {got} vs {want}");
                    assert!((row[x * 4 + 2] - 7.0 * want).abs() <= 1e-5 * (1.0 + want));
                    if r >= 4.0 {
                        span_err = span_err.max((drow[x * 4 + 3] - want).abs() * norm);
                    }
                }
            }
        }
        // Measured: the span disk's coverage differs from disk_coverage by up to ~0.5 of a
        // pixel's full weight near the top and bottom of the disk.
        println!("span disk vs disk_coverage: max difference {span_err:.3} of a full pixel");
        assert!(span_err > 0.25, "span disk edge error {span_err}");
    }
}
