//! The lens and occlusion terms of Dr.Bokeh, defined once.
//!
//! Every kernel (exact, fast) and the backward pass call these functions, so the model has a
//! single definition. Units: `d` is relative disparity (normalized disparity minus focus),
//! `k` the blur strength in pixels per unit of disparity, distances in pixels.
//!
//! Each function is written in a form that cannot overflow to NaN for any finite input
//! (see the numerical notes in DESIGN.md).

/// Steepness of the soft step (official `g`).
pub const STEP_GAIN: f32 = 3.0;
/// `ln(1/0.1)`: the soft step's offset, from the official `s = 0.1`.
pub const STEP_LN_OFFSET: f32 = std::f32::consts::LN_10;

/// Circle-of-confusion radius of a pixel at relative disparity `d`: `|d|·k` pixels, 0 on the
/// focal plane, uncapped (inf only if `k` or `d` is). The one definition of `|d - focus|·K`:
/// pass `d = disparity - focus`.
#[inline(always)]
pub fn coc_radius(d: f32, k: f32) -> f32 {
    d.abs() * k
}

/// Scatter radius of a pixel at relative disparity `d`: `|d|·k + 1` pixels (the `+1` is the
/// official model's; it keeps the `1/σ²` energy term bounded at the focal plane).
#[inline(always)]
pub fn scatter_radius(d: f32, k: f32) -> f32 {
    // Capped far beyond any image so that σ, and ratios of σ, stay finite.
    coc_radius(d, k).min(MAX_RADIUS) + 1.0
}

/// A circle of confusion below this radius (pixels) shows nothing of its source beyond its own
/// pixel ([`disk_coverage`]): the source is in focus.
pub const SHARP_COC_PX: f32 = 0.5;

/// Largest scatter radius the model represents (pixels).
pub const MAX_RADIUS: f32 = 1e30;

/// The weight unit of a layer whose smallest visible scatter radius is `sigma_min`.
///
/// Energies are `step/σ²` in the official model; for a layer that is far out of focus
/// everywhere (σ ≫ 64) they would sink towards the compositing epsilon or underflow. Only
/// ratios of weights matter, so such a layer measures weights in units of `(unit/σ)²`.
/// The unit is 1 whenever some visible pixel has σ ≤ 64: there the official numbers are
/// reproduced exactly.
pub fn weight_unit(sigma_min: f32) -> f32 {
    (sigma_min / 64.0).max(1.0)
}

/// Soft "a > b": `0.1 / (0.1 + exp(-3(a - b)))`, evaluated as the logistic function of
/// `3(a - b) - ln 10`, which never produces inf/inf. Returns 0.0909 at `a == b`.
#[inline(always)]
pub fn soft_step(a: f32, b: f32) -> f32 {
    let x = STEP_GAIN * (a - b) - STEP_LN_OFFSET;
    // 1/(1+e^-x) is already stable: e^-x → inf gives 0, never NaN.
    1.0 / (1.0 + (-x).exp())
}

/// The soft step split into a source factor and a tap factor, for kernels that evaluate many
/// taps of one source: `soft_step(σ, r) = 1 / (1 + step_source_factor(σ)·step_tap_factor(r))`.
/// Same function as [`soft_step`] (to f32 rounding) while both factors are finite and non-zero,
/// i.e. for `σ, r` up to [`FACTORED_STEP_MAX`]; callers use it only there (beyond, `e^{3r}`
/// overflows and `e^{ln10 - 3σ}` underflows, and their product is `0·inf = NaN`).
#[inline(always)]
pub fn step_source_factor(sigma: f32) -> f32 {
    (STEP_LN_OFFSET - STEP_GAIN * sigma).exp()
}

/// Largest `σ` and tap distance `r` (pixels) for which the factored soft step
/// ([`step_source_factor`] · [`step_tap_factor`]) is used: `e^{3·25}` and `e^{ln10 - 3·25}`
/// are both normal f32 numbers, with margin.
pub const FACTORED_STEP_MAX: f32 = 25.0;

/// See [`step_source_factor`].
#[inline(always)]
pub fn step_tap_factor(r: f32) -> f32 {
    (STEP_GAIN * r).exp()
}

/// Energy weight of a neighbour with scatter radius `sigma` at distance `r` from the target,
/// before the aperture mask and alpha: `step(σ, r) / σ²` (times `unit²`, see [`weight_unit`]).
#[inline(always)]
pub fn energy(sigma: f32, r: f32, unit: f32) -> f32 {
    soft_step(sigma, r) * density(sigma, unit)
}

/// The `1/σ²` energy density, in weight units of `unit` (see [`weight_unit`]).
#[inline(always)]
pub fn density(sigma: f32, unit: f32) -> f32 {
    let u = unit / sigma;
    u * u
}

/// The on-focal "defocus" factor of a target pixel: `q = 1 - exp(-3 (|d|·k)²)`.
/// 0 for an in-focus target (full on-focal occlusion), → 1 when it is defocused.
#[inline(always)]
pub fn focal_defocus(d_target: f32, k: f32) -> f32 {
    let c = coc_radius(d_target, k);
    if c == 0.0 {
        // Exactly in focus (common: a plane at the focal depth); -expm1(-0) is 0.
        return 0.0;
    }
    if c >= 2.5 {
        // exp(-3·6.25) < 2^-26: the f32 result is exactly 1; skip the transcendental.
        return 1.0;
    }
    // -expm1 keeps precision for tiny c (q ≈ 3c²).
    -(-3.0 * c * c).exp_m1()
}

/// Soft "neighbour is in front": `0.5 + 0.5·tanh(10·(d_y - d_x - 0.1))`.
#[inline(always)]
pub fn in_front(d_neighbour: f32, d_target: f32) -> f32 {
    0.5 + 0.5 * in_front_tanh(d_neighbour, d_target)
}

/// Gain of the soft "in front" test (per unit of relative disparity): `tanh(10·(..))`.
pub const IN_FRONT_GAIN: f32 = 10.0;
/// Margin of the soft "in front" test, relative disparity: a neighbour is half in front at
/// `d_y = d_x + 0.1`.
pub const IN_FRONT_MARGIN: f32 = 0.1;

/// The tanh inside [`in_front`]: `tanh(10·(d_y - d_x - 0.1))`.
#[inline(always)]
pub fn in_front_tanh(d_neighbour: f32, d_target: f32) -> f32 {
    (IN_FRONT_GAIN * (d_neighbour - d_target - IN_FRONT_MARGIN)).tanh()
}

/// Both tanh of [`depth_groups`] split into a neighbour factor and a target factor, for kernels
/// that evaluate many (neighbour depth, target) pairs: with `p = in_front_neighbour_factor(d_y,
/// c)·in_front_target_factor(d_x, c)` (any centre `c`), `tanh(a) = (p - 1)/(p + 1)` for
/// `a = 10(d_y - d_x - 0.1)`, and the reverse test's `tanh(10(d_x - d_y - 0.1)) = (e - p)/(e + p)`
/// with `e = exp(-4·10·0.1)` ([`in_front_tanh_pair`]). f64, finite while `|d - c|` stays
/// within [`IN_FRONT_FACTORED_MAX`] for both depths.
#[inline(always)]
pub fn in_front_neighbour_factor(d_neighbour: f32, centre: f32) -> f64 {
    (2.0 * IN_FRONT_GAIN as f64 * (d_neighbour as f64 - centre as f64)).exp()
}

/// See [`in_front_neighbour_factor`]: `exp(-2·10·(d_x - c + 0.1))`.
#[inline(always)]
pub fn in_front_target_factor(d_target: f32, centre: f32) -> f64 {
    (-2.0 * IN_FRONT_GAIN as f64 * (d_target as f64 - centre as f64 + IN_FRONT_MARGIN as f64)).exp()
}

/// `(in_front_tanh(d_y, d_x), in_front_tanh(d_x, d_y))` from the product `p` of the factors
/// ([`in_front_neighbour_factor`]). Two divisions instead of two tanh.
#[inline(always)]
pub fn in_front_tanh_pair(p: f64) -> (f32, f32) {
    let e = (-4.0 * IN_FRONT_GAIN as f64 * IN_FRONT_MARGIN as f64).exp();
    (((p - 1.0) / (p + 1.0)) as f32, ((e - p) / (e + p)) as f32)
}

/// Largest `|d - centre|` (relative disparity) for the factored tanh: the product's exponent
/// `2·10·(2·17 + 0.1)` = 682 stays below f64's 709.
pub const IN_FRONT_FACTORED_MAX: f32 = 17.0;

/// On-focal occlusion of neighbour `y` seen from target `x` (not the centre tap, whose
/// occlusion is 1): `q(x) + (1 - q(x))·in_front(d_y, d_x)`, with `q = focal_defocus(d_x)`.
#[inline(always)]
pub fn occlusion(q_target: f32, d_neighbour: f32, d_target: f32) -> f32 {
    (1.0 - q_target) * in_front(d_neighbour, d_target) + q_target
}

/// Half-size of the visibility box (eq. 4) of a pixel with scatter radius `sigma`, capped by
/// the window half-size `p`: `min(trunc(σ/2), p)`.
#[inline(always)]
pub fn visibility_half_size(sigma: f32, p: usize) -> usize {
    let h = (sigma / 2.0).trunc();
    if h.is_finite() && h < p as f32 { h as usize } else { p }
}

/// Which calibration of the lens terms a render uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    /// Every term calibrated to the thin lens: CoC radius exactly `K·|d|`, uniform disks with
    /// a one-pixel antialiased edge, normalized to unit flux; visibility is the layer's own
    /// coverage; inside a layer, sources in front of / at / behind the target's depth are
    /// composited front to back. A source whose CoC is below half a pixel stays in place.
    /// The default.
    #[default]
    Physical,
    /// The official Dr.Bokeh formula, exactly (golden vectors): `σ = K·|d| + 1`, the soft
    /// step, on-focal occlusion `O`, visibility as the mean alpha of a box of half-size σ/2.
    Official,
}

impl Profile {
    /// The profile's name as the CLI and config spell it.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Physical => "physical",
            Profile::Official => "official",
        }
    }
}

// ---------------------------------------------------------------------------------------------
// The physical profile's terms.
// ---------------------------------------------------------------------------------------------

/// Coverage of the target pixel at distance `rho` (pixel centres) by a uniform disk of radius
/// `r`: a linear ramp one pixel wide across the disk's edge, `clamp(r + ½ - ρ, 0, 1)` (the
/// pixel-area coverage of a straight edge crossing the pixel square head-on). Below
/// `r = ½` only the centre pixel is covered: a source in focus stays where it is.
#[inline(always)]
pub fn disk_coverage(r: f32, rho: f32) -> f32 {
    (r + 0.5 - rho).clamp(0.0, 1.0)
}

/// [`disk_coverage`] with an edge `width` pixels wide whose ramp is smooth (a C¹ smoothstep
/// instead of a clamped line), for gradients through the edge; `width = 1` has the same
/// half-way point as the hard ramp and, being symmetric about it, the same area of a
/// continuous disk.
#[inline]
pub fn disk_coverage_smooth(r: f32, rho: f32, width: f32) -> f32 {
    // Times the reciprocal: hoisted out of a disk's loop over taps (a division per tap was 6%
    // of a dfd step); exact for the default width 1.
    let t = ((r - rho) * (1.0 / width.max(f32::MIN_POSITIVE)) + 0.5).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// `Σ` of [`disk_coverage`] over the whole pixel lattice around a source: the flux of an
/// unnormalized disk of radius `r`, so `disk_coverage / disk_norm` spreads a unit of light.
/// Exactly `r + ½` below half a pixel (the centre alone); up to [`NORM_TABLE_MAX`] the exact
/// lattice sum from a table of the lattice's distances (O(log n), see [`LatticeRings`]);
/// beyond, the area `π·(r² + 1/12)` of the ramped disk (relative error < 1e-4 there).
// Inline: called per source of a depth ramp by the fast kernel's stencils (another module).
#[inline]
pub fn disk_norm(r: f32) -> f32 {
    if r < 0.5 {
        return r + 0.5;
    }
    if r >= NORM_TABLE_MAX {
        return std::f32::consts::PI * (r * r + 1.0 / 12.0);
    }
    LatticeRings::get().norm(r as f64) as f32
}

/// Radius up to which [`disk_norm`] is the exact lattice sum.
pub const NORM_TABLE_MAX: f32 = 64.0;

/// The pixel lattice's points by distance from the origin, out to `NORM_TABLE_MAX + 1`: each
/// distinct distance with the number of points within it and the sum of their distances.
/// With them `Σ clamp(r + ½ - |p|, 0, 1) = C(r - ½) + (r + ½)·(C(r + ½) - C(r - ½)) -
/// (S(r + ½) - S(r - ½))`, where `C(t)`, `S(t)` count and sum the points with `|p| ≤ t`.
/// Built once (~13 000 points, well under a millisecond).
pub struct LatticeRings {
    dist: Vec<f64>,
    count: Vec<f64>,
    sum: Vec<f64>,
    /// For each squared distance `n` (integer), how many distinct distances are at most
    /// `√n`: `within` in O(1) (the coarse grids ask it for every source; a binary search was
    /// 5% of a 3 MP render's instructions).
    by_sq: Vec<u32>,
}

impl LatticeRings {
    fn get() -> &'static LatticeRings {
        static RINGS: std::sync::OnceLock<LatticeRings> = std::sync::OnceLock::new();
        RINGS.get_or_init(|| {
            let reach = (NORM_TABLE_MAX + 1.0).ceil() as i64;
            let mut sq: Vec<i64> = Vec::new();
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    sq.push(dx * dx + dy * dy);
                }
            }
            sq.sort_unstable();
            let (mut dist, mut count, mut sum) = (Vec::new(), Vec::new(), Vec::new());
            let (mut c, mut s) = (0f64, 0f64);
            let mut distinct_sq = Vec::new();
            for (k, &q) in sq.iter().enumerate() {
                let d = (q as f64).sqrt();
                c += 1.0;
                s += d;
                if sq.get(k + 1) != Some(&q) {
                    dist.push(d);
                    count.push(c);
                    sum.push(s);
                    distinct_sq.push(q);
                }
            }
            // The table stops where the square of points is still complete (|p| ≤ reach).
            let mut by_sq = vec![0u32; (reach * reach) as usize + 1];
            let mut k = 0;
            for (n, slot) in by_sq.iter_mut().enumerate() {
                while k < distinct_sq.len() && distinct_sq[k] <= n as i64 {
                    k += 1;
                }
                *slot = k as u32;
            }
            LatticeRings { dist, count, sum, by_sq }
        })
    }

    /// `(C(t), S(t))`: points with `|p| ≤ t` and the sum of their distances (every point for
    /// `t` beyond the table). A point exactly at distance `t` may count or not by rounding:
    /// the coverage sums built from these are continuous in `t`, so either gives the same sum.
    fn within(&self, t: f64) -> (f64, f64) {
        if t < 0.0 {
            return (0.0, 0.0);
        }
        let n = ((t * t) as usize).min(self.by_sq.len() - 1);
        match self.by_sq[n] {
            0 => (0.0, 0.0),
            k => (self.count[k as usize - 1], self.sum[k as usize - 1]),
        }
    }

    fn norm(&self, r: f64) -> f64 {
        let (c_in, s_in) = self.within(r - 0.5);
        let (c_out, s_out) = self.within(r + 0.5);
        c_in + (r + 0.5) * (c_out - c_in) - (s_out - s_in)
    }
}

/// The lattice sum of [`disk_coverage`], in f64, tap by tap: O(r²).
pub fn lattice_norm(r: f32) -> f64 {
    let reach = (r + 0.5).ceil() as i64;
    let mut sum = 0f64;
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            sum += disk_coverage(r, ((dx * dx + dy * dy) as f32).sqrt()) as f64;
        }
    }
    sum
}

/// How a source at relative disparity `d_source` relates to a target at `d_target` in the
/// physical profile's in-layer occlusion: weights of (in front, same surface, behind) that sum
/// to 1, from the official soft "in front" test (a margin of 0.1 in disparity, so a smoothly
/// slanted surface is one surface).
#[inline(always)]
pub fn depth_groups(d_source: f32, d_target: f32) -> [f32; 3] {
    let front = in_front(d_source, d_target);
    let behind = in_front(d_target, d_source);
    [front, (1.0 - front - behind).max(0.0), behind]
}

/// Adds one source to a target's depth groups: weight `wt` (alpha times normalized coverage)
/// split by `split` (from [`depth_groups`]), colour `rgb` (straight). The groups hold
/// premultiplied colour and coverage, front first, as [`over_groups`] takes them.
#[inline(always)]
pub fn add_to_groups(groups: &mut [[f64; 4]; 3], wt: f64, split: [f32; 3], rgb: &[f32]) {
    for (acc, &gk) in groups.iter_mut().zip(&split) {
        if gk > 0.0 {
            let k = wt * gk as f64;
            acc[0] += k * rgb[0] as f64;
            acc[1] += k * rgb[1] as f64;
            acc[2] += k * rgb[2] as f64;
            acc[3] += k;
        }
    }
}

/// Composites the three depth groups of one target (each a premultiplied colour and a
/// coverage, front first, see [`depth_groups`]) by filling coverage front to back: each group
/// takes what is left of the pixel, up to its own coverage, with its mean colour. Groups that
/// tile the pixel side by side (the parts of one slanted surface) add up exactly; a group
/// stacked in front of another hides it as the thin lens does (a half-covering blurred edge
/// shows half of what is behind); a covered in-focus target leaves nothing to the groups
/// behind it (no colour bleeding). Returns the premultiplied colour and the coverage (≤ 1).
#[inline]
pub fn over_groups(groups: &[[f64; 4]; 3]) -> [f64; 4] {
    let mut out = [0f64; 4];
    for g in groups {
        let a = g[3];
        if a <= 0.0 {
            continue;
        }
        let take = (out[3] + a).min(1.0) - out[3];
        if take <= 0.0 {
            break;
        }
        let f = take / a;
        for c in 0..3 {
            out[c] += g[c] * f;
        }
        out[3] += take;
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Derivatives of the terms above, for the backward pass (`render::backward`), and the smooth
// variants of the physical profile's hard edges. Each derivative sits under the name of the
// term it differentiates and is finite for every finite input.
// ---------------------------------------------------------------------------------------------

/// `∂ soft_step(a, b) / ∂a` (`= -∂/∂b`): `3·s·(1 - s)` with `s` the soft step. The official
/// CUDA form `g·s·e / ((e + s)² + ε)`, `e = exp(3(b - a))`, overflows to inf/inf = NaN once
/// `b - a` passes ~30 px; this one is at most 0.75 and never NaN.
#[inline(always)]
pub fn soft_step_grad(a: f32, b: f32) -> f32 {
    soft_step_with_grad(a, b).1
}

/// `(soft_step(a, b), soft_step_grad(a, b))` from one exponential.
#[inline(always)]
pub fn soft_step_with_grad(a: f32, b: f32) -> (f32, f32) {
    let s = soft_step(a, b);
    (s, STEP_GAIN * s * (1.0 - s))
}

/// [`energy`] and its derivative in `σ` at fixed `r` and `unit`, from one soft step:
/// `(s·u², (3·s(1 - s) - 2s/σ)·u²)` with `u = unit/σ`. Finite for every finite input.
#[inline(always)]
pub fn energy_with_grad(sigma: f32, r: f32, unit: f32) -> (f32, f32) {
    let s = soft_step(sigma, r);
    let rho = density(sigma, unit);
    (s * rho, (STEP_GAIN * s * (1.0 - s) - 2.0 * s / sigma) * rho)
}

/// `(∂σ/∂d, ∂σ/∂k)` of [`scatter_radius`] (and of [`coc_radius`], whose derivatives are the
/// same): `(sign(d)·k, |d|)`; 0 at `d = 0` (the subgradient the backward uses at the kink) and
/// once the radius is capped at [`MAX_RADIUS`].
#[inline(always)]
pub fn coc_radius_grad(d: f32, k: f32) -> (f32, f32) {
    if coc_radius(d, k) >= MAX_RADIUS || d == 0.0 { (0.0, 0.0) } else { (d.signum() * k, d.abs()) }
}

/// `(∂q/∂d, ∂q/∂k)` of [`focal_defocus`] `q = 1 - exp(-3 (d·k)²)`: `(6k²d, 6kd²)·exp(-3(dk)²)`,
/// smooth through `d = 0`. Zero where [`focal_defocus`] returns exactly 1 (`|d|·k ≥ 2.5`; the
/// true derivative there is below 1e-7·k), so forward and backward describe one function.
#[inline(always)]
pub fn focal_defocus_grad(d_target: f32, k: f32) -> (f32, f32) {
    let c = coc_radius(d_target, k);
    if c == 0.0 || c >= 2.5 {
        return (0.0, 0.0);
    }
    let e = 6.0 * (-3.0 * c * c).exp();
    (e * k * k * d_target, e * k * d_target * d_target)
}

/// [`in_front`] and its derivative in `d_y` (`= -∂/∂d_x`) from one tanh:
/// `(0.5 + 0.5·t, 5·(1 - t²))` with `t = tanh(10(d_y - d_x - 0.1))`; the slope is in [0, 5].
#[inline(always)]
pub fn in_front_with_grad(d_neighbour: f32, d_target: f32) -> (f32, f32) {
    in_front_from_tanh(in_front_tanh(d_neighbour, d_target))
}

/// [`in_front`] and its derivative in `d_y` from its tanh `t` ([`in_front_tanh`]):
/// `(0.5 + 0.5·t, 5·(1 - t²))`.
#[inline(always)]
pub fn in_front_from_tanh(t: f32) -> (f32, f32) {
    (0.5 + 0.5 * t, 0.5 * IN_FRONT_GAIN * (1.0 - t) * (1.0 + t))
}

/// `∂ disk_coverage_smooth(r, ρ, width) / ∂r` (`= -∂/∂ρ`): the smoothstep's slope `6t(1 - t)`
/// over `width`; 0 outside the edge.
#[inline]
pub fn disk_coverage_smooth_grad(r: f32, rho: f32, width: f32) -> f32 {
    let inv = 1.0 / width.max(f32::MIN_POSITIVE);
    let t = (r - rho) * inv + 0.5;
    if t <= 0.0 || t >= 1.0 { 0.0 } else { 6.0 * t * (1.0 - t) * inv }
}

/// `(Σ, ∂Σ/∂r)`: the lattice sum of [`disk_coverage_smooth`] around a source (its flux before
/// normalisation, so `disk_coverage_smooth / norm` spreads a unit of light, as
/// [`disk_norm`] does for the hard ramp) and its derivative in `r`. Exact (pixels fully inside
/// counted from [`LatticeRings`], the edge ring point by point, O(r·width)) while the edge
/// stays within the table (`r + width/2 ≤ NORM_TABLE_MAX + 1`); beyond, the area
/// `π(r² + width²/20)` of the smoothly ramped disk (the hard ramp's `1/12` becomes `1/20` for
/// the smoothstep) and `2πr` (relative error below 1e-3 at the switch for widths ≥ ½). With `width = 1` an in-focus source (`r < ½`) keeps weight 1 on
/// its own pixel, as in the hard profile.
pub fn disk_norm_smooth(r: f32, width: f32) -> (f32, f32) {
    let width = width.max(f32::MIN_POSITIVE);
    let half = 0.5 * width;
    if r + half > NORM_TABLE_MAX + 1.0 {
        let pi = std::f32::consts::PI;
        return (pi * (r * r + width * width / 20.0), 2.0 * pi * r);
    }
    let rings = LatticeRings::get();
    let (inside, _) = rings.within((r - half) as f64);
    let (mut sum, mut grad) = (inside, 0f64);
    for (rho, n) in rings.ring((r - half) as f64, (r + half) as f64) {
        sum += n * disk_coverage_smooth(r, rho as f32, width) as f64;
        grad += n * disk_coverage_smooth_grad(r, rho as f32, width) as f64;
    }
    (sum as f32, grad as f32)
}

impl LatticeRings {
    /// The lattice's distinct distances in `(lo, hi)` with how many points lie at each.
    fn ring(&self, lo: f64, hi: f64) -> impl Iterator<Item = (f64, f64)> + '_ {
        let start = self.dist.partition_point(|&d| d <= lo);
        let end = self.dist.partition_point(|&d| d < hi);
        (start..end).map(move |k| (self.dist[k], self.count[k] - if k == 0 { 0.0 } else { self.count[k - 1] }))
    }
}

/// [`depth_groups`] and `(∂front, ∂same, ∂behind) / ∂d_source` (the derivatives in
/// `d_target` are their negatives), from the same two tanh. The `max(·, 0)` guarding the
/// middle weight against rounding is differentiated as the identity (`1 - front - behind` is
/// positive for every input).
#[inline(always)]
pub fn depth_groups_with_grad(d_source: f32, d_target: f32) -> ([f32; 3], [f32; 3]) {
    depth_groups_from_tanh(in_front_tanh(d_source, d_target), in_front_tanh(d_target, d_source))
}

/// [`depth_groups_with_grad`] from its two tanh, `t_front = in_front_tanh(d_source, d_target)`
/// and `t_behind = in_front_tanh(d_target, d_source)` (see [`in_front_tanh`]).
#[inline(always)]
pub fn depth_groups_from_tanh(t_front: f32, t_behind: f32) -> ([f32; 3], [f32; 3]) {
    let (front, d_front) = in_front_from_tanh(t_front);
    let (behind, d_behind) = in_front_from_tanh(t_behind);
    ([front, (1.0 - front - behind).max(0.0), behind], [d_front, d_behind - d_front, -d_behind])
}

/// The fill rule of [`over_groups`], `min(x, 1)`, with its corner rounded over `width` of
/// coverage for gradients: `x` below `1 - width`, 1 above `1 + width`, a parabola between
/// (C¹; at `x = 1` it gives `1 - width/4`, i.e. a fully covered pixel lets `width/4` through).
/// `width = 0` is the hard `min(x, 1)`. Returns `(m(x), m'(x))`; at the hard corner the slope
/// is taken from below `x < 1` (1) and 0 from `x = 1` on.
#[inline]
pub fn fill_min(x: f64, width: f64) -> (f64, f64) {
    if x <= 1.0 - width {
        if x < 1.0 { (x, 1.0) } else { (1.0, 0.0) }
    } else if x >= 1.0 + width {
        (1.0, 0.0)
    } else {
        let u = x - 1.0 + width;
        (x - u * u / (4.0 * width), 1.0 - u / (2.0 * width))
    }
}

/// [`over_groups`] with the fill rule rounded by [`fill_min`] (`width = 0`: the same result
/// as [`over_groups`] up to rounding). Written as `P = Σ_g P_g·f_g`, `A = m(S_3)` with `S_g`
/// the coverage of the groups before `g` and `f_g = (m(S_{g+1}) - m(S_g)) / a_g` (its limit
/// `m'(S_g)` when `a_g = 0`).
pub fn over_groups_smooth(groups: &[[f64; 4]; 3], width: f64) -> [f64; 4] {
    let mut out = [0f64; 4];
    let mut s = 0f64;
    let mut m_s = 0f64;
    for g in groups {
        let a = g[3];
        if a <= 0.0 {
            continue;
        }
        let (m_next, _) = fill_min(s + a, width);
        let f = (m_next - m_s) / a;
        for c in 0..3 {
            out[c] += g[c] * f;
        }
        s += a;
        m_s = m_next;
    }
    out[3] = m_s;
    out
}

/// The vector-Jacobian product of [`over_groups_smooth`]: given the cotangent `g` of its
/// `[P_r, P_g, P_b, A]`, the cotangents of the three groups' `[P_r, P_g, P_b, a]`. With
/// `c̄_g = P_g / a_g` (0 for an empty group), `∂P/∂P_g = f_g` and `∂P/∂a_g = c̄_g·(m'(S_{g+1}) -
/// f_g) + Σ_{h>g} c̄_h·(m'(S_{h+1}) - m'(S_h))`, `∂A/∂a_g = m'(S_3)`. O(1), f64.
pub fn over_groups_smooth_vjp(groups: &[[f64; 4]; 3], width: f64, g: &[f64; 4]) -> [[f64; 4]; 3] {
    // Forward quantities: cumulative coverage S_g, m(S_g), m'(S_g) for g = 0..=3.
    let mut s = [0f64; 4];
    let mut m = [0f64; 4];
    let mut dm = [0f64; 4];
    // m(0) = 0 and m'(0) = 1 for every width the renderer accepts (<= 1/2).
    dm[0] = fill_min(0.0, width).1;
    for k in 0..3 {
        s[k + 1] = s[k] + groups[k][3].max(0.0);
        (m[k + 1], dm[k + 1]) = fill_min(s[k + 1], width);
    }
    let mut out = [[0f64; 4]; 3];
    // g·c̄_h·(m'(S_{h+1}) - m'(S_h)), summed over h > g from the back.
    let mut tail = 0f64;
    for k in (0..3).rev() {
        let a = groups[k][3];
        let (f, gc) = if a > 0.0 {
            let f = (m[k + 1] - m[k]) / a;
            (f, (0..3).map(|c| g[c] * groups[k][c]).sum::<f64>() / a)
        } else {
            (dm[k], 0.0)
        };
        for c in 0..3 {
            out[k][c] = g[c] * f;
        }
        out[k][3] = gc * (dm[k + 1] - f) + tail + g[3] * dm[3];
        tail += gc * (dm[k + 1] - dm[k]);
    }
    out
}

// ---------------------------------------------------------------------------------------------
// Geometric visibility on one opaque surface: the ray test (depth from defocus).
// ---------------------------------------------------------------------------------------------

/// Width, in relative disparity, of the ray test's smooth edge ([`ray_clear`]).
pub const RAY_EDGE: f32 = 0.05;

/// Where the ray that reaches target `p` from a source `s` behind it crosses the target's
/// depth, as a fraction `t` of the offset `s - p` (pixels: the crossing is at
/// `p + t·(s - p)`), with `(∂t/∂e_p, ∂t/∂e_s)`. Thin lens: a ray through pixel `p` is offset
/// at relative disparity `e` in proportion to the circle of confusion there, so the ray that
/// meets `s` (offset `s - p` at `e_s`) is at `t = e_p / e_s` of that offset at `e_p`. `None`
/// where `t` is not a finite number of moderate size (`|t| > 1e6`: a source on the focal
/// plane, whose ray no lateral window holds).
#[inline]
pub fn ray_crossing(e_target: f32, e_source: f32) -> Option<(f64, f64, f64)> {
    let (ep, es) = (e_target as f64, e_source as f64);
    let t = ep / es;
    (t.is_finite() && t.abs() <= 1e6).then(|| (t, 1.0 / es, -t / es))
}

/// Whether the ray crossing the target's depth `d_target` at a point where the surface has
/// disparity `d_at_crossing` passes (1) or is stopped (0): clear where the surface there lies
/// behind the target by more than [`IN_FRONT_MARGIN`] (the margin of one slanted surface, as
/// in [`depth_groups`]), a smoothstep [`RAY_EDGE`] wide around it. Returns the value and its
/// derivative in `d_target` (`= -∂/∂d_at_crossing`). Any pair of relative or absolute
/// disparities (only their difference counts).
#[inline]
pub fn ray_clear(d_at_crossing: f32, d_target: f32) -> (f32, f32) {
    let x = ((d_target - IN_FRONT_MARGIN - d_at_crossing) / RAY_EDGE + 0.5).clamp(0.0, 1.0);
    (x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x) / RAY_EDGE)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn soft_step_f64(a: f64, b: f64) -> f64 {
        // High-precision reference of the literal official formula.
        0.1 / (0.1 + (-3.0 * (a - b)).exp())
    }

    #[test]
    fn soft_step_matches_official_values_and_f64() {
        assert!((soft_step(0.0, 0.0) - 0.090_909).abs() < 1e-6);
        assert!((soft_step(1.0, 0.0) - 0.6676).abs() < 1e-4);
        for i in -2000..=2000 {
            let a = i as f32 * 0.37;
            let got = soft_step(a, 0.0) as f64;
            let want = soft_step_f64(a as f64, 0.0);
            assert!(got.is_finite());
            assert!((got - want).abs() <= 1e-6 * want.max(1e-30) + 1e-7, "a={a} got={got} want={want}");
        }
        // Where the naive f32 form overflows (exp(3·40) = inf), the stable form is 0.
        assert_eq!(soft_step(0.0, 40.0), 0.0);
        assert_eq!(soft_step(f32::MAX, 0.0), 1.0);
        assert_eq!(soft_step(0.0, f32::MAX), 0.0);
    }

    #[test]
    fn factored_soft_step_is_the_soft_step() {
        for si in 0..=200 {
            let sigma = 1.0 + si as f32 * 0.1;
            for ri in 0..=150 {
                let r = ri as f32 * 0.1;
                let f = 1.0 / (1.0 + step_source_factor(sigma) * step_tap_factor(r));
                assert!((f - soft_step(sigma, r)).abs() < 2e-6, "σ={sigma} r={r}");
            }
        }
        // Both factors stay normal numbers up to the documented limit.
        let (fs, fr) = (step_source_factor(FACTORED_STEP_MAX), step_tap_factor(FACTORED_STEP_MAX + 2.5));
        assert!(fs.is_normal() && fr.is_normal(), "{fs} {fr}");
    }

    #[test]
    fn physical_footprint_has_unit_flux_and_stays_in_focus() {
        // In focus: the centre alone, weight exactly 1.
        for r in [0.0f32, 0.1, 0.49] {
            assert_eq!(disk_coverage(r, 0.0) / disk_norm(r), 1.0);
            assert_eq!(disk_coverage(r, 1.0), 0.0);
        }
        // The ring table against the lattice sums, tap by tap.
        for i in 0..2000 {
            let r = 0.5 + i as f32 * 0.0317;
            let want = lattice_norm(r);
            let rel = (disk_norm(r) as f64 - want).abs() / want;
            assert!(rel < 1e-5, "r={r}: {} vs {want} ({rel:e})", disk_norm(r));
        }
        for r in [64.0f32, 70.3, 100.0] {
            let rel = (disk_norm(r) as f64 - lattice_norm(r)).abs() / lattice_norm(r);
            assert!(rel < 1e-4, "r={r}: {rel:e}");
        }
        // The smooth edge has the hard edge's half-way point and, on the lattice, its area
        // to 1% once the disk spans a few pixels (both ramps are symmetric about the edge).
        for r in [5.5f32, 12.0, 20.0] {
            let reach = (r + 2.0).ceil() as i64;
            let (mut hard, mut smooth) = (0f64, 0f64);
            for dy in -reach..=reach {
                for dx in -reach..=reach {
                    let rho = ((dx * dx + dy * dy) as f32).sqrt();
                    hard += disk_coverage(r, rho) as f64;
                    smooth += disk_coverage_smooth(r, rho, 1.0) as f64;
                }
            }
            assert!((smooth / hard - 1.0).abs() < 0.01, "r={r}: {smooth} vs {hard}");
            assert!((disk_coverage_smooth(r, r, 1.0) - 0.5).abs() < 1e-6);
        }
    }

    #[test]
    fn depth_groups_and_over() {
        for (ds, dt) in [(0.5f32, 0.0f32), (0.0, 0.5), (0.2, 0.2), (0.05, 0.0), (-3.0, 2.0)] {
            let g = depth_groups(ds, dt);
            assert!(g.iter().all(|&v| (0.0..=1.0).contains(&v)), "{g:?}");
            assert!((g.iter().sum::<f32>() - 1.0).abs() < 1e-6, "{g:?}");
        }
        assert!(depth_groups(0.5, 0.0)[0] > 0.999 && depth_groups(0.0, 0.5)[2] > 0.999 && depth_groups(0.3, 0.3)[1] > 0.75);
        // An opaque front group hides the rest; a half-covering one shows half of it.
        let opaque = over_groups(&[[0.2, 0.2, 0.2, 1.0], [0.9, 0.9, 0.9, 1.0], [0.0; 4]]);
        assert_eq!(opaque, [0.2, 0.2, 0.2, 1.0]);
        let half = over_groups(&[[0.1, 0.1, 0.1, 0.5], [0.8, 0.8, 0.8, 1.0], [0.0; 4]]);
        assert!((half[0] - 0.5).abs() < 1e-12 && (half[3] - 1.0).abs() < 1e-12);
        // Overlapping coverage of one surface is normalized.
        let over = over_groups(&[[0.0; 4], [1.2, 0.6, 0.0, 2.0], [0.0; 4]]);
        assert!((over[0] - 0.6).abs() < 1e-12 && (over[3] - 1.0).abs() < 1e-12);
        // Groups that tile the pixel (one surface split by the soft depth test) simply add.
        let g = depth_groups(0.3, 0.3).map(|v| v as f64);
        let tiled = over_groups(&[[0.5 * g[0], 0.0, 0.0, g[0]], [0.5 * g[1], 0.0, 0.0, g[1]], [0.5 * g[2], 0.0, 0.0, g[2]]]);
        assert!((tiled[0] - 0.5).abs() < 1e-7 && (tiled[3] - 1.0).abs() < 1e-7, "{tiled:?}");
    }

    #[test]
    fn a_source_adds_its_weight_split_by_group() {
        // Group k gains `wt·split[k]` of coverage and that times the colour, per channel; a
        // second source adds to what is there.
        let mut groups = [[0.5, 0.25, 0.125, 1.0], [0.0; 4], [1.0, 2.0, 3.0, 0.5]];
        let rgb = [0.2f32, 0.4, 0.8];
        add_to_groups(&mut groups, 0.5, [0.25, 0.75, 0.0], &rgb);
        let want = [[0.525, 0.3, 0.225, 1.125], [0.075, 0.15, 0.3, 0.375], [1.0, 2.0, 3.0, 0.5]];
        for (g, w) in groups.iter().zip(&want) {
            for (a, b) in g.iter().zip(w) {
                assert!((a - b).abs() < 1e-7, "{groups:?} vs {want:?}");
            }
        }
        // A group the split leaves out is not touched.
        let before = groups;
        add_to_groups(&mut groups, 1.0, [0.0, 1.0, 0.0], &[4.0, 0.0, 0.0]);
        assert_eq!((groups[0], groups[2]), (before[0], before[2]));
        assert_eq!(groups[1], [before[1][0] + 4.0, before[1][1], before[1][2], before[1][3] + 1.0]);
    }

    #[test]
    fn occlusion_terms() {
        // Same-depth neighbour of an in-focus target: 0.5 - 0.5 tanh(1).
        assert!((occlusion(0.0, 0.3, 0.3) - 0.119_203).abs() < 1e-6);
        assert_eq!(focal_defocus(0.0, 30.0), 0.0);
        assert_eq!(focal_defocus(1.0, 1e6), 1.0);
        // The shortcut at c >= 2.5 is exact in f32.
        assert_eq!(-(-3.0f32 * 2.5 * 2.5).exp_m1(), 1.0);
        assert!(in_front(1e30, -1e30) == 1.0 && in_front(-1e30, 1e30) == 0.0);
        assert_eq!(visibility_half_size(7.9, 10), 3);
        assert_eq!(visibility_half_size(f32::INFINITY, 10), 10);
    }
}

#[cfg(test)]
mod grad_tests {
    //! Each derivative against central differences of its term (f32 terms, steps of 1e-3:
    //! agreement to ~1e-3 relative), values of the combined forms against the plain terms.
    use super::*;

    fn fd(f: impl Fn(f32) -> f32, x: f32) -> f32 {
        let h = 1e-3;
        ((f(x + h) as f64 - f(x - h) as f64) / (2.0 * h as f64)) as f32
    }

    fn close(a: f32, b: f32, what: &str) {
        assert!((a - b).abs() <= 2e-3 * a.abs().max(b.abs()) + 2e-4, "{what}: analytic {a} vs fd {b}");
    }

    #[test]
    fn step_energy_defocus_and_in_front() {
        for i in -40..=40 {
            let x = i as f32 * 0.25;
            close(soft_step_grad(x, 0.5), fd(|a| soft_step(a, 0.5), x), "soft_step");
            let (d, k) = (x * 0.05, 7.0);
            if coc_radius(d, k) < 2.4 && d != 0.0 {
                let (dd, dk) = focal_defocus_grad(d, k);
                close(dd, fd(|d| focal_defocus(d, k), d), "focal_defocus d");
                close(dk, fd(|k| focal_defocus(d, k), k), "focal_defocus k");
            }
            let (f, df) = in_front_with_grad(x * 0.02, 0.05);
            assert_eq!(f, in_front(x * 0.02, 0.05));
            close(df, fd(|y| in_front(y, 0.05), x * 0.02), "in_front");
            let ([a, b, c], [da, db, dc]) = depth_groups_with_grad(x * 0.02, 0.05);
            assert_eq!([a, b, c], depth_groups(x * 0.02, 0.05));
            for (k, dv) in [da, db, dc].into_iter().enumerate() {
                close(dv, fd(|y| depth_groups(y, 0.05)[k], x * 0.02), "depth_groups");
            }
        }
        for sigma in [1.0f32, 1.7, 4.0, 12.5, 30.0] {
            for r in [0.0f32, 1.0, 3.5, 11.0, 20.0] {
                let (e, de) = energy_with_grad(sigma, r, 1.0);
                assert_eq!(e, energy(sigma, r, 1.0));
                close(de, fd(|s| energy(s, r, 1.0), sigma), "energy");
            }
        }
        // Where the official CUDA form is inf/inf, these are finite (and 0).
        for (a, b) in [(1.0f32, 40.0f32), (1.0, 1e30), (1e30, 0.0), (-1e30, 1e30)] {
            assert!(soft_step_grad(a, b).is_finite() && energy_with_grad(a.abs().max(1.0), b.abs(), 1.0).1.is_finite());
        }
        assert_eq!(focal_defocus_grad(0.0, 30.0), (0.0, 0.0));
        assert_eq!(coc_radius_grad(0.0, 30.0), (0.0, 0.0));
        assert_eq!(coc_radius_grad(-0.5, 30.0), (-30.0, 0.5));
    }

    #[test]
    fn smooth_disk_and_its_norm() {
        for width in [0.5f32, 1.0, 2.0] {
            for i in 0..400 {
                let r = i as f32 * 0.173;
                close(disk_coverage_smooth_grad(r, 5.0, width), fd(|r| disk_coverage_smooth(r, 5.0, width), r), "coverage");
                // The norm is the lattice sum, point by point.
                let reach = (r + width).ceil() as i64;
                let mut want = 0f64;
                for dy in -reach..=reach {
                    for dx in -reach..=reach {
                        want += disk_coverage_smooth(r, ((dx * dx + dy * dy) as f32).sqrt(), width) as f64;
                    }
                }
                let (n, dn) = disk_norm_smooth(r, width);
                let tol = if r + width / 2.0 > NORM_TABLE_MAX + 1.0 { 1e-3 } else { 1e-5 };
                assert!((n as f64 - want).abs() <= tol * want, "r={r} w={width}: {n} vs {want}");
                if r + width / 2.0 + 1e-3 < NORM_TABLE_MAX + 1.0 {
                    close(dn, fd(|r| disk_norm_smooth(r, width).0, r), "norm");
                } else {
                    assert_eq!(dn, 2.0 * std::f32::consts::PI * r);
                }
            }
        }
        // In focus, a source keeps its own pixel at weight exactly 1.
        for r in [0.0f32, 0.2, 0.49] {
            assert_eq!(disk_coverage_smooth(r, 0.0, 1.0) / disk_norm_smooth(r, 1.0).0, 1.0);
        }
        // Beyond the table: the area, within 1e-4 of the lattice sum at the switch.
        let (table, area) = (disk_norm_smooth(64.4, 1.0).0, disk_norm_smooth(64.6, 1.0).0);
        assert!((area / table - 1.0).abs() < 1e-2, "{table} {area}");
        assert!(disk_norm_smooth(1e30, 1.0).0.is_infinite() || disk_norm_smooth(1e30, 1.0).0 > 0.0);
    }

    #[test]
    fn smooth_fill_and_its_vjp() {
        assert_eq!(fill_min(0.3, 0.0), (0.3, 1.0));
        assert_eq!(fill_min(1.0, 0.0), (1.0, 0.0));
        assert_eq!(fill_min(1.7, 0.0), (1.0, 0.0));
        // C¹ at both ends of the rounded corner.
        let w = 0.2;
        for x in [1.0 - w, 1.0 + w] {
            let (a, da) = fill_min(x - 1e-9, w);
            let (b, db) = fill_min(x + 1e-9, w);
            assert!((a - b).abs() < 1e-8 && (da - db).abs() < 1e-6, "x={x}");
        }
        let mut seed = 7u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for case in 0..200 {
            let groups: [[f64; 4]; 3] = std::array::from_fn(|_| {
                let a = if rnd() < 0.2 { 0.0 } else { rnd() * 0.8 };
                [a * rnd(), a * rnd() * 2.0, a * rnd(), a]
            });
            // Width 0 is the renderer's fill.
            let (hard, smooth) = (over_groups(&groups), over_groups_smooth(&groups, 0.0));
            assert!(hard.iter().zip(&smooth).all(|(a, b)| (a - b).abs() < 1e-12), "{hard:?} {smooth:?}");
            let width = [0.0, 0.1, 0.5][case % 3];
            let g: [f64; 4] = std::array::from_fn(|_| rnd() * 2.0 - 1.0);
            let vjp = over_groups_smooth_vjp(&groups, width, &g);
            let loss = |gr: &[[f64; 4]; 3]| over_groups_smooth(gr, width).iter().zip(&g).map(|(a, b)| a * b).sum::<f64>();
            for k in 0..3 {
                for c in 0..4 {
                    let h = 1e-7;
                    let mut up = groups;
                    up[k][c] += h;
                    let mut down = groups;
                    down[k][c] -= h;
                    // An empty group's colour cannot move alone (its P and a are one weight
                    // times [c, 1]); at a = 0 the group starts to count: one-sided.
                    if c < 3 && groups[k][3] == 0.0 {
                        continue;
                    }
                    let want =
                        if c == 3 && groups[k][3] == 0.0 { (loss(&up) - loss(&groups)) / h } else { (loss(&up) - loss(&down)) / (2.0 * h) };
                    let got = vjp[k][c];
                    // The hard corner (width 0) is a kink: skip where a step crosses it.
                    let s: f64 = groups.iter().map(|g| g[3]).sum();
                    if width == 0.0 && (s - 1.0).abs() < 1e-6 {
                        continue;
                    }
                    assert!((got - want).abs() <= 1e-5 * want.abs().max(1.0), "case {case} group {k} ch {c}: {got} vs {want} ({groups:?})");
                }
            }
        }
    }
}
