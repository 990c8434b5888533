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
    0.5 + 0.5 * (10.0 * (d_neighbour - d_target - 0.1)).tanh()
}

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
