//! The plan of a depth-from-defocus run ([`plan`]): which differentiable render, optimised at
//! which finest resolution level, over how many levels, and what that should cost.
//!
//! Cost model. A step (one render, its loss and its VJP) costs CPU time per pixel of its
//! level; the constants below were measured on this project's 2-core machine (release build,
//! `--levels 1`, the map frozen by a learning rate of 1e-9 at one CoC radius for every pixel,
//! CPU seconds per step as the difference of 12 and 2 steps). The exact tapes visit every tap
//! of the lens window actually drawn ([`level_blur_lens`]: what the disparity range needs,
//! capped by the level's frame) and do the real work only where a source's disk covers the
//! tap: so a pixel pays `window taps × TAPE_CPU_PER_WINDOW_TAP + covered taps × per covered
//! tap`. How many taps are covered depends on the disparities, which are not known before the
//! run; the plan takes the worst case, every source as blurred as the range allows (a far
//! background behind a near focus), so a run seldom takes longer than planned (on an
//! otherwise idle machine) and often takes a third to a half of it. The span render pays per pixel of CoC radius and per depth bin instead.
//! The old model (taps of the window, no coverage) put a blur larger than the frame 4x below
//! its real cost: `--blur 1e9 --iters 20 --levels 2` on 64×64 ran 305 s at full size.
//!
//! Estimated seconds are CPU seconds over the threads ([`DfdPlan::seconds`]).

use super::dfd_options::{DfdKernel, DfdOptions, DfdRenderer};
use super::gauss_psf::window_radius;
use crate::error::{Error, Result};
use crate::render::lens::coc_radius;
use crate::render::{Profile, RenderSettings, aperture, max_lens};

/// The most Adam steps per level: a run converges in hundreds (the default is 100); the bound
/// keeps a mistyped count (`--iters 4294967296`, centuries at any size) from starting.
pub const MAX_ITERS: usize = 100_000;

/// The smallest side, pixels, of a pyramid level below the finest: a coarser one holds too
/// little of the photo to say anything about its blur (and `--levels 1000000` allocated its
/// one-pixel levels for 54 s).
pub const MIN_LEVEL_SIDE: usize = 8;

/// The smallest largest CoC radius, pixels, of a pyramid level below the finest (K halves at
/// each level): below a pixel a level sees almost nothing, and at half a pixel its gradient is
/// exactly zero (its loss stayed constant). Two pixels (2026-11-26 to 11-28) cost the bench's
/// small frames their coarsest level (K 6.4 at 64 px: 1.6 px at the third level) and with it
/// accuracy: disparity MAE 0.1966 -> 0.2211 on the held-out Mitsuba scenes, 0.1956 -> 0.2349
/// on bench seed 1; one pixel gives back the earlier figures (`docs/dfd.md`). A start in the
/// dead band is moved out of it (`dfd_start::movable_start`).
pub const MIN_LEVEL_COC: f32 = 1.0;

/// The smallest side, pixels, of the finest level [`DfdKernel::Auto`] may optimise at instead
/// of the full size.
pub const AUTO_MIN_SIDE: usize = 16;

/// A run estimated to take longer than this (seconds on the threads it has) is announced.
pub const LONG_RUN_SECONDS: f64 = 60.0;

/// CPU seconds per pixel of a step's fixed work (L1, hierarchical SSIM, smoothness, Adam):
/// 0.0050 s a step at 64×64 and 0.071 at 256×256 (span render, K 0.01).
const STEP_CPU_PER_PIXEL: f64 = 1.1e-6;
/// The exact tapes, per pixel and tap of the window (the coverage test): 6.5-7e-9 with every
/// source in focus at K 8, 16 and 30 (64×64, window 23 to 67).
const TAPE_CPU_PER_WINDOW_TAP: f64 = 7e-9;
/// The ray tape per covered tap (depth groups, ray test, forward and VJP): 1.43-1.46e-7 at
/// K 8, 16, 30 (64×64), K 16 (128×128) and K 1e9 (64×64, window 183: 16.3 s a step).
const RAY_CPU_PER_COVERED_TAP: f64 = 1.45e-7;
/// The exact tape per covered tap: 7.4e-8 (64×64, K 30).
const EXACT_CPU_PER_COVERED_TAP: f64 = 7.4e-8;
/// A shaped aperture's covered tap on top of the disc's (see [`shape_cost`]): 96×96, K 8, every
/// pixel at a CoC of 6 px, `--kernel exact`: 3.93 s per step with `blades:6,rotation=15`
/// against 0.17 s with the disc (2026-11-27), ~154 covered taps per pixel.
const SHAPE_CPU_PER_COVERED_TAP: f64 = 2.6e-6;
/// The span render per pixel and pixel of CoC radius (forward and VJP): 1.5-2.3e-7 at
/// K 8, 16, 30, 64 and 1e9 (the radius capped by the frame), 64×64 and 256×256.
const SPAN_CPU_PER_RADIUS: f64 = 1.8e-7;
/// The span render per pixel and depth bin a stripe uses (see [`crate::render::SpanTape`]):
/// counted with every bin in use, `--kernel fast` on 256×256 at K 16 (a far background,
/// focus 1, three levels) took 54 CPU seconds against 52 estimated.
const SPAN_CPU_PER_BIN: f64 = 2e-8;
/// The Gaussian PSF per pixel and tap of its `(2R+1)²` window clipped to the frame (forward
/// and VJP, one `exp` and a few multiply-adds each). Not measured (the command line does not
/// reach this renderer): twice the tapes' cost of a tap that is only tested.
const GAUSS_CPU_PER_TAP: f64 = 1.5e-8;
/// Disparity bins a span render's stripe uses at most: the range [0, 1] at
/// [`crate::render::BIN_STEP`] 0.01, plus the ends.
const SPAN_MAX_BINS: f64 = 102.0;

/// How [`super::dfd::estimate`] runs: the differentiable render, the finest resolution level
/// it optimises at (0: full size; above 0 the map is optimised at that level's size and
/// resized to the photo's at the end), how many levels the pyramid has, and the estimated
/// cost.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DfdPlan {
    /// The render ([`DfdKernel::Auto`] resolved).
    pub kernel: DfdKernel,
    /// The finest level (see [`level_size`]).
    pub finest_level: usize,
    /// Width of the map optimised at the finest level, pixels.
    pub width: usize,
    /// Its height.
    pub height: usize,
    /// Levels run, coarsest first, ending at the finest: the options' `levels`, capped by
    /// [`useful_levels`].
    pub levels: usize,
    /// Adam steps, all levels together.
    pub steps: usize,
    /// Estimated CPU seconds of the whole optimisation, the worst case of the cost model
    /// (module notes), on this project's 2-core machine.
    pub cpu_seconds: f64,
}

impl DfdPlan {
    /// Estimated wall seconds on `threads` threads (at most the machine's cores).
    pub fn seconds(&self, threads: usize) -> f64 {
        self.cpu_seconds / threads.clamp(1, crate::resources::cores()) as f64
    }
}

/// The size of resolution level `level` of a `w × h` photo: each side divided by `2^level`
/// (rounded down, at least 1 pixel). Level 0 is full size.
pub fn level_size(w: usize, h: usize, level: usize) -> (usize, usize) {
    let f = 1usize.checked_shl(level as u32).unwrap_or(usize::MAX);
    ((w / f).max(1), (h / f).max(1))
}

/// How far from the focal plane, in normalized disparity, the range [0, 1] reaches: the
/// larger of `focus` and `1 − focus` (focus clamped to [0, 1] first).
pub fn focus_room(focus: f32) -> f32 {
    let f = focus.clamp(0.0, 1.0);
    f.max(1.0 - f)
}

/// A level's K (scaled with its width) and lens window (what the disparity range [0, 1] needs
/// there, at most the level's largest window, [`max_lens`]): the window the tapes draw.
pub fn level_blur_lens(s: &RenderSettings, w: usize, lw: usize, lh: usize) -> (f32, usize) {
    // The ratio first: K near f32::MAX times the width would overflow to inf.
    let blur = s.blur * (lw as f32 / w as f32);
    // Saturating: a huge K (legal, finite) must give the widest window, not a wrapped one.
    let reach = (coc_radius(focus_room(s.focus), blur).ceil() as usize).saturating_add(3);
    (blur, reach.saturating_mul(2).saturating_add(1).min(max_lens(lw, lh) | 1))
}

/// How many levels, at most `requested`, a pyramid ending at level `finest` of a `w × h`
/// photo has that can see the blur: every level below the finest at least [`MIN_LEVEL_SIDE`]
/// pixels a side with a largest CoC radius (its K times [`focus_room`]) of at least
/// [`MIN_LEVEL_COC`]. At least 1 (the finest always runs). O(log(size)).
///
/// [`size_levels`] is the same count by size alone, from full size: what a request is
/// measured against before the plan and the blur drop more.
pub fn useful_levels(w: usize, h: usize, s: &RenderSettings, finest: usize, requested: usize) -> usize {
    let mut n = 1;
    while n < requested {
        let (lw, lh) = level_size(w, h, finest + n);
        let (blur, _) = level_blur_lens(s, w, lw, lh);
        if lw.min(lh) < MIN_LEVEL_SIDE || coc_radius(focus_room(s.focus), blur) < MIN_LEVEL_COC {
            break;
        }
        n += 1;
    }
    n
}

/// How many levels a `w × h` photo has from full size, each at least [`MIN_LEVEL_SIDE`]
/// pixels a side below the first: the most `--levels` can ask for. O(log(size)).
pub fn size_levels(w: usize, h: usize) -> usize {
    let fits = |l: &usize| {
        let (lw, lh) = level_size(w, h, *l);
        lw.min(lh) >= MIN_LEVEL_SIDE
    };
    1 + (1..64).take_while(fits).count()
}

/// Estimated CPU seconds of one step of `kernel` (or of `renderer` when that is not Dr.Bokeh)
/// at level `level` of a `w × h` photo (see the module notes; the worst case of coverage).
fn step_cpu(kernel: DfdKernel, renderer: DfdRenderer, s: &RenderSettings, (w, h): (usize, usize), level: usize) -> f64 {
    let (lw, lh) = level_size(w, h, level);
    let (blur, lens) = level_blur_lens(s, w, lw, lh);
    let pixels = (lw * lh) as f64;
    // The largest CoC a source can have here, at most what the window holds.
    let radius = (coc_radius(focus_room(s.focus), blur) as f64).min((lens / 2) as f64);
    let window = aperture::disk_tap_count(lens) as f64;
    let covered = (std::f64::consts::PI * (radius + 1.0).powi(2)).min(window);
    let render = match (renderer, kernel) {
        (DfdRenderer::GaussPsf, _) => {
            // Its window is clipped to the frame.
            let side = |n: usize| window_radius(blur, s.focus).saturating_mul(2).saturating_add(1).min(n) as f64;
            side(lw) * side(lh) * GAUSS_CPU_PER_TAP
        }
        (_, DfdKernel::Ray) => tape_passes(s) * (window * TAPE_CPU_PER_WINDOW_TAP + covered * (RAY_CPU_PER_COVERED_TAP + shape_cost(s))),
        (_, DfdKernel::Exact) => {
            tape_passes(s) * (window * TAPE_CPU_PER_WINDOW_TAP + covered * (EXACT_CPU_PER_COVERED_TAP + shape_cost(s)))
        }
        (_, DfdKernel::Fast | DfdKernel::Auto) => {
            // The worst case: disparities spread over the whole range, every bin in use.
            let bins = if s.occlusion { SPAN_MAX_BINS } else { 1.0 };
            radius * SPAN_CPU_PER_RADIUS + bins * SPAN_CPU_PER_BIN
        }
    };
    pixels * (STEP_CPU_PER_PIXEL + render)
}

/// Whether the span render draws `s`'s aperture: the plain disc, achromatic (see
/// [`crate::render::SpanTape`]); any other aperture takes the exact tape.
pub fn spans_draw(s: &RenderSettings) -> bool {
    s.aperture.is_disc() && s.aperture.channel_scales().is_none()
}

/// The exact tape's passes per step: three with chromatic aberration (one per channel).
fn tape_passes(s: &RenderSettings) -> f64 {
    if s.aperture.channel_scales().is_some() { 3.0 } else { 1.0 }
}

/// What a covered tap of a shaped aperture costs on top of the disc's: its coverage is an
/// area (up to 16 clips of the outline), evaluated once in the render and three times in the
/// VJP (the value and its slope in the CoC).
fn shape_cost(s: &RenderSettings) -> f64 {
    if s.aperture.is_disc() { 0.0 } else { SHAPE_CPU_PER_COVERED_TAP }
}

/// Estimated CPU seconds of a run of `kernel` whose finest level is `finest`: every level's
/// steps and the final evaluation (one more step).
fn run_cpu(w: usize, h: usize, s: &RenderSettings, opts: &DfdOptions, kernel: DfdKernel, finest: usize) -> f64 {
    let levels = useful_levels(w, h, s, finest, opts.levels);
    let steps: f64 = (finest..finest + levels).map(|l| opts.iters as f64 * step_cpu(kernel, opts.renderer, s, (w, h), l)).sum();
    steps + step_cpu(kernel, opts.renderer, s, (w, h), finest)
}

/// The plan of [`super::dfd::estimate`] for a `w × h` photo with settings `s` and `opts`. An
/// explicit kernel runs at full size. [`DfdKernel::Auto`] takes the ray test where it applies
/// (physical profile, occlusion on, the Dr.Bokeh renderer) at the finest level whose run is
/// estimated within `opts.cpu_budget` (not below [`AUTO_MIN_SIDE`] pixels a side); where it
/// does not apply or fits nowhere, the span render at the finest level that fits (without
/// occlusion the span render is the exact tape's function, and cheaper); where nothing fits,
/// the span render at the coarsest level allowed. On the bench's scenes at 128 and 256 px the
/// ray test at a reduced size, resized, beat the span render at full size (README "The ray
/// test"). The Gaussian PSF runs at full size. O(levels²).
pub fn plan(w: usize, h: usize, s: &RenderSettings, opts: &DfdOptions) -> DfdPlan {
    let at = |kernel, finest_level| {
        let (width, height) = level_size(w, h, finest_level);
        let levels = useful_levels(w, h, s, finest_level, opts.levels);
        let cpu_seconds = run_cpu(w, h, s, opts, kernel, finest_level);
        DfdPlan { kernel, finest_level, width, height, levels, steps: opts.iters.saturating_mul(levels), cpu_seconds }
    };
    if opts.kernel != DfdKernel::Auto {
        return at(opts.kernel, 0);
    }
    if opts.renderer != DfdRenderer::DrBokeh {
        return at(DfdKernel::Fast, 0);
    }
    let finest: Vec<usize> = (0..64usize)
        .take_while(|&l| {
            let (lw, lh) = level_size(w, h, l);
            l == 0 || lw.min(lh) >= AUTO_MIN_SIDE
        })
        .collect();
    let fits = |kernel, l: &usize| run_cpu(w, h, s, opts, kernel, *l) <= opts.cpu_budget;
    let ray = s.profile == Profile::Physical && s.occlusion;
    if let Some(&l) = finest.iter().find(|l| ray && fits(DfdKernel::Ray, l)) {
        return at(DfdKernel::Ray, l);
    }
    // The span render draws the plain disc only: another aperture takes the exact tape.
    let kernel = if spans_draw(s) { DfdKernel::Fast } else { DfdKernel::Exact };
    let l = finest.iter().find(|l| fits(kernel, l)).or(finest.last()).copied().unwrap_or(0);
    at(kernel, l)
}

/// The one rule for `dfd.iters`: a whole number of Adam steps per level in 1..=[`MAX_ITERS`].
/// Takes the signed count a command line parsed (a negative one is the user's, refused here
/// with the rule). The usage error names `key`.
pub fn check_iters(key: &str, n: i64) -> Result<usize> {
    match usize::try_from(n) {
        Ok(n) if (1..=MAX_ITERS).contains(&n) => Ok(n),
        _ => Err(Error::usage(format!("{key} must be a whole number of steps from 1 to {MAX_ITERS}, got {n}"))),
    }
}

/// The one rule for `dfd.levels`: a whole number >= 1 (more than the photo allows are capped
/// by [`useful_levels`], with a warning). The usage error names `key`.
pub fn check_levels(key: &str, n: i64) -> Result<usize> {
    match usize::try_from(n) {
        Ok(n) if n >= 1 => Ok(n),
        _ => Err(Error::usage(format!("{key} must be a whole number of levels >= 1, got {n}"))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::diff::dfd_options::AUTO_CPU_BUDGET;
    use crate::render::Profile;

    fn settings(blur: f32, focus: f32) -> RenderSettings {
        RenderSettings { blur, focus, lens: 0, occlusion: true, profile: Profile::Physical, aperture: crate::render::Aperture::DISC }
    }

    /// Levels stop where the photo is under 8 px a side or the blur under a pixel; a request
    /// of a million levels costs nothing.
    #[test]
    fn levels_are_capped_by_size_and_blur() {
        let s = settings(30.0, 1.0);
        assert_eq!(useful_levels(64, 64, &s, 0, 3), 3);
        // 64, 32, 16, 8 px: the next would be 4 px.
        assert_eq!(useful_levels(64, 64, &s, 0, 1_000_000), 4);
        assert_eq!(useful_levels(64, 64, &s, 0, usize::MAX), 4);
        assert_eq!(useful_levels(64, 16, &s, 0, 10), 2);
        assert_eq!(useful_levels(5, 5, &s, 0, 10), 1);
        assert_eq!((size_levels(64, 64), size_levels(64, 16), size_levels(15, 15), size_levels(1, 1)), (4, 2, 1, 1));
        // K 2 at focus 0.5: 1 px of CoC at most, 0.5 at level 1; K 4: 2, 1 and 0.5 px.
        assert_eq!(useful_levels(256, 256, &settings(2.0, 0.5), 0, 10), 1);
        assert_eq!(useful_levels(256, 256, &settings(4.0, 0.5), 0, 10), 2);
        assert_eq!(useful_levels(256, 256, &settings(8.0, 0.5), 0, 10), 3);
        assert_eq!(useful_levels(256, 256, &settings(0.0, 0.5), 0, 10), 1);
    }

    /// The window the cost model counts is the one the tapes draw: capped by the frame.
    #[test]
    fn cost_uses_the_window_drawn() {
        let o = DfdOptions { iters: 20, levels: 2, ..DfdOptions::default() };
        let huge = plan(64, 64, &settings(1e9, 1.0), &DfdOptions { kernel: DfdKernel::Ray, ..o });
        // Window 183 (the frame's), every tap covered: 64²·(26k taps·1.5e-7)·20 steps ≈ 300 s
        // (measured: 305 s).
        assert!((250.0..700.0).contains(&huge.cpu_seconds), "{huge:?}");
        assert_eq!(level_blur_lens(&settings(1e9, 1.0), 64, 64, 64).1, 183);
    }

    /// Item 9 of issue 34: every default plan for a photo up to 256×256 fits the budget (the
    /// old one ran 64×64 at K 30 for 48 s and 256×256 at K 16 for 53 s on 2 threads).
    #[test]
    fn default_plans_of_small_photos_fit_the_budget() {
        let o = DfdOptions::default();
        for (w, h) in [(16, 16), (40, 24), (64, 64), (100, 75), (256, 64), (256, 256)] {
            for k in [0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 60.0, 120.0, 1e3, 1e9, 3e38] {
                for f in [0.0, 0.3, 0.5, 1.0] {
                    let p = plan(w, h, &settings(k, f), &o);
                    assert!(p.cpu_seconds <= AUTO_CPU_BUDGET, "{w}x{h} K {k} focus {f}: {p:?}");
                }
            }
        }
        // The two: now optimised at 32×32 and 64×64.
        let p = plan(64, 64, &settings(30.0, 1.0), &o);
        assert_eq!((p.kernel, p.width), (DfdKernel::Ray, 32), "{p:?}");
        let p = plan(256, 256, &settings(16.0, 1.0), &o);
        assert_eq!((p.kernel, p.width), (DfdKernel::Ray, 64), "{p:?}");
    }

    #[test]
    fn counts_follow_their_rules() {
        assert_eq!(check_iters("dfd.iters", 1).unwrap(), 1);
        assert_eq!(check_iters("dfd.iters", MAX_ITERS as i64).unwrap(), MAX_ITERS);
        for bad in [0, -1, MAX_ITERS as i64 + 1, 4_294_967_296] {
            let e = check_iters("dfd.iters", bad).unwrap_err().to_string();
            assert!(e.contains("dfd.iters") && e.contains(&bad.to_string()), "{e}");
        }
        assert_eq!(check_levels("dfd.levels", 1_000_000).unwrap(), 1_000_000);
        assert!(check_levels("dfd.levels", -1).unwrap_err().to_string().contains("dfd.levels"));
        assert!(check_levels("dfd.levels", 0).is_err());
    }
}
