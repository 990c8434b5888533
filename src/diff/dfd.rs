//! Depth from defocus by direct optimisation (paper Sec. 4, Fig. 9 row 1): the disparity map
//! that, rendered with an all-in-focus photo as one opaque layer, reproduces a photo of the
//! same view focused at `focus` with blur `K`. Adam on the disparity, coarse to fine, loss
//! `λ₁·L1 + λ₂·G + λ₃·HSSIM` (Eqn. 7; see [`super::loss`]), gradients through
//! [`crate::render::Tape`] with the ray test ([`DfdKernel::Ray`]: the exact kernel where a
//! source behind a target counts as far as the ray between them passes the photo's surface;
//! the default's choice, at the finest level its budget allows, see [`plan`]),
//! [`crate::render::SpanTape`] (the span render of one opaque layer, either profile:
//! [`DfdKernel::Fast`]) or the plain exact tape ([`DfdKernel::Exact`]), or through the
//! Gaussian-PSF renderer of the ablation ([`super::gauss_psf`], chosen by [`DfdRenderer`]).
//!
//! The optimisation behind `drbokeh dfd` (files in and out: [`super::dfd_job`]). Cost per
//! iteration: one render and its VJP at the level's size: O(pixels·(R + bins)) with the span
//! render (R the largest CoC, bins the depth bins a stripe of rows sees), O(pixels·lens²) with
//! the exact tape, with or without the ray test (the Gaussian PSF: O(pixels·(2R+1)²),
//! R ≈ 1.5·K·max(focus, 1 − focus)). The plan (render, levels, cost) is [`super::dfd_plan`];
//! the start, and what a defocused photo cannot tell (near or far, nothing below half a pixel
//! of blur), [`super::dfd_start`].

pub use super::dfd_light::aif_light;
pub use super::dfd_options::{AUTO_CPU_BUDGET, DfdKernel, DfdOptions, DfdRenderer, LossVariant, LossWeights, SSIM_WINDOW};
pub use super::dfd_plan::{AUTO_MIN_SIDE, DfdPlan, MAX_ITERS, check_iters, check_levels, level_size, plan};

use super::dfd_plan::{LONG_RUN_SECONDS, focus_room, level_blur_lens};
use super::dfd_start::{self, ambiguous_share, movable_start, undetermined};
use super::gauss_psf::{GaussTape, window_radius};
use super::loss;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::lens::coc_radius;
use crate::render::{Layer, Profile, RenderSettings, SpanTape, Tape, check_blur, check_focus};

/// One recorded forward render of a level's disparity, whichever renderer made it (the span
/// tape, the largest, boxed: one allocation per iteration beside its frame-sized buffers).
enum Recording<'a> {
    DrBokeh(Tape<'a>),
    Span(Box<SpanTape<'a>>),
    Gauss(GaussTape),
}

impl Recording<'_> {
    fn image(&self) -> &Image {
        match self {
            Recording::DrBokeh(t) => t.image(),
            Recording::Span(t) => t.image(),
            Recording::Gauss(t) => t.image(),
        }
    }

    /// `∂L/∂disparity` per pixel for `∂L/∂image` = `seed`.
    fn disparity_grad(&self, seed: &Image) -> Result<Vec<f32>> {
        use crate::render::layer::{CHANNELS, D};
        Ok(match self {
            Recording::DrBokeh(t) => t.vjp(seed)?.layers[0].data.iter().skip(D).step_by(CHANNELS).copied().collect(),
            Recording::Span(t) => t.disparity_vjp(seed)?.data,
            Recording::Gauss(t) => t.vjp(seed).data,
        })
    }
}

/// One logged step: level (0 = full size), iteration, and the loss terms.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Step {
    /// Resolution level ([`level_size`]), counting down to the plan's finest level (0: full size).
    pub level: usize,
    /// Iteration within the level: the losses of the map before update `iter` (`iters` for
    /// the map after the last update, [`Estimate::last`]).
    pub iter: usize,
    /// Total loss.
    pub loss: f64,
    /// L1 term (unweighted).
    pub l1: f64,
    /// Gradient-smoothness term (unweighted).
    pub smoothness: f64,
    /// SSIM term over the windows of [`LossWeights::windows`] (unweighted; 0 without windows).
    pub ssim: f64,
}

/// What [`estimate_with`] tells as it goes.
#[derive(Clone, Copy, Debug)]
pub enum Event<'a> {
    /// The plan, before the first step.
    Plan(&'a DfdPlan),
    /// A warning, the moment it is known (a long run is announced before it starts); every
    /// one is also in [`Estimate::warnings`].
    Warning(&'a str),
    /// An Adam step was taken: the losses of the map it started from.
    Step(Step),
}

/// The result of [`estimate_with`].
#[derive(Clone, Debug)]
pub struct Estimate {
    /// The disparity: one channel, the photos' size, in [0, 1].
    pub disparity: Image,
    /// The map at the size it was optimised at (the plan's finest level), before the guided
    /// upsampling that gives `disparity` ([`super::dfd_upsample`]); `disparity` itself at full
    /// size.
    pub optimised: Image,
    /// How the run went ([`plan`]).
    pub plan: DfdPlan,
    /// The losses of the first step at the finest level (of the map that level started from).
    pub first: Step,
    /// The losses of the map returned, at the finest level's size (evaluated once more after
    /// the last update; `iter` = `iters`).
    pub last: Step,
    /// What the user should know, naming the parameters (`render.focus`, `dfd.levels`, ...):
    /// a clamped focus, capped levels, a long run, a start that could not move, a photo that
    /// cannot tell the map or its near/far side.
    pub warnings: Vec<String>,
}

/// One defocused photo of a focal stack: the photo (linear RGB, the all-in-focus photo's size),
/// the normalized disparity it is focused at, and where it clipped.
#[derive(Clone, Copy, Debug)]
pub struct Shot<'a> {
    /// The photo.
    pub photo: &'a Image,
    /// Its focal plane (normalized disparity; clamped to [0, 1] with a warning).
    pub focus: f32,
    /// The linear level at or above which a sample may stand for more light than it holds (an
    /// integer photo's white, less JPEG's ringing: [`clip_level`]); None for a linear photo.
    /// Where the photo is clipped, a render brighter than it is no error ([`loss::censor`]):
    /// without this, an 8-bit pair's lights pull the map towards less blur.
    pub clip: Option<f32>,
}

impl<'a> Shot<'a> {
    /// A linear photo (nothing clipped) focused at `focus`.
    pub fn linear(photo: &'a Image, focus: f32) -> Self {
        Shot { photo, focus, clip: None }
    }
}

/// The clip level of [`Shot::clip`] for a photo stored with `encoding`: the linear value of the
/// highlights stage's default threshold (sRGB 0.98, code 250 of 255) for integer samples, None
/// for linear ones.
pub fn clip_level(encoding: crate::color::PhotoEncoding) -> Option<f32> {
    use crate::color::PhotoEncoding;
    match encoding {
        PhotoEncoding::Linear => None,
        PhotoEncoding::Integer { transfer, .. } => {
            Some(transfer.decode(crate::stages::light_recovery::HighlightsOptions::default().threshold))
        }
    }
}

/// One defocused photo at one level: the photo resized, the share of each sample's footprint
/// that was clipped (None when nothing was), and the level's render settings at its focus.
struct Target {
    photo: Image,
    clipped: Option<Image>,
    settings: RenderSettings,
}

impl Target {
    /// `shot` at `lw` x `lh` with the level's settings `s` (its own focus).
    fn of(shot: &Shot, focus: f32, s: RenderSettings, lw: usize, lh: usize) -> Self {
        let clipped = shot.clip.and_then(|c| {
            let p = shot.photo;
            let mask: Vec<f32> = p.data.iter().map(|&v| if v >= c { 1.0 } else { 0.0 }).collect();
            mask.contains(&1.0).then(|| Image::from_vec(p.width, p.height, p.channels, mask).expect("the photo's shape").resized(lw, lh))
        });
        Target { photo: shot.photo.resized(lw, lh), clipped, settings: RenderSettings { focus, ..s } }
    }
}

/// Estimates the disparity (one channel, the photos' size, in [0, 1], the units of `focus`
/// and `K`) from an all-in-focus photo `aif` and a photo `bokeh` of the same view rendered or
/// taken at `s.focus` with blur `s.blur` (both linear RGB): [`estimate_with`]'s map, `step`
/// called after every iteration.
pub fn estimate(aif: &Image, bokeh: &Image, s: &RenderSettings, opts: &DfdOptions, mut step: impl FnMut(Step)) -> Result<Image> {
    estimate_with(aif, bokeh, s, opts, |e| {
        if let Event::Step(st) = e {
            step(st)
        }
    })
    .map(|e| e.disparity)
}

/// [`estimate`] with its plan, its final losses and its warnings, `on` told of each as it
/// comes ([`Event`]). `s.lens` is ignored: each level uses the window that the whole disparity
/// range [0, 1] needs. A focus outside [0, 1] is clamped to it, with a warning (as `render`
/// does). Errors (usage, naming the parameter): photos of different sizes or channel counts,
/// a non-finite focus (`render.focus`), a blur that is not a finite number >= 0
/// (`render.blur`), iterations outside 1..=[`MAX_ITERS`] (`dfd.iters`), no levels
/// (`dfd.levels`), a learning rate that is not a finite number > 0 (`dfd.learning_rate`), a
/// start outside [0, 1] (`dfd.init`), [`DfdKernel::Ray`] with the official profile
/// (`dfd.kernel`). `opts.kernel`'s [`DfdKernel::Auto`] is resolved once for all levels, with
/// the finest level ([`plan`]).
pub fn estimate_with(aif: &Image, bokeh: &Image, s: &RenderSettings, opts: &DfdOptions, on: impl FnMut(Event)) -> Result<Estimate> {
    estimate_stack(aif, &[Shot::linear(bokeh, s.focus)], s, opts, on)
}

/// [`estimate_with`] for a focal stack: every photo of `shots` is a view of `aif` focused at
/// its own `focus` with the same blur `s.blur` (`s.focus` is ignored). The loss is the mean of
/// the photos' data terms plus the smoothness term; each step renders the map once per photo.
/// Two photos focused at different depths tell near from far (the mirror image of a depth
/// about one focal plane is not its mirror about the other) and constrain a pixel that one
/// photo shows in focus. The plan gives each photo an equal share of the time budget. Errors:
/// those of [`estimate_with`], for each photo; no photo.
pub fn estimate_stack(aif: &Image, shots: &[Shot], s: &RenderSettings, opts: &DfdOptions, mut on: impl FnMut(Event)) -> Result<Estimate> {
    if shots.is_empty() {
        return Err(Error::usage("dfd needs at least one defocused photo"));
    }
    for shot in shots {
        check_options(aif, shot.photo, &RenderSettings { focus: shot.focus, ..*s }, opts)?;
    }
    let mut warnings = Vec::new();
    let mut warn = |m: String, on: &mut dyn FnMut(Event)| {
        on(Event::Warning(&m));
        warnings.push(m);
    };
    let mut foci = Vec::with_capacity(shots.len());
    for shot in shots {
        let (focus, clamped) = crate::render::focus_in_range("render.focus", shot.focus);
        if let Some(m) = clamped {
            warn(m, &mut on);
        }
        foci.push(focus);
    }
    let s = RenderSettings { focus: foci[0], ..*s };
    let (w, h) = (aif.width, aif.height);
    let plan = stack_plan(w, h, &s, &foci, opts);
    let opts = DfdOptions { kernel: plan.kernel, ..*opts };
    if opts.kernel == DfdKernel::Ray && s.profile != Profile::Physical {
        return Err(Error::usage(
            "dfd.kernel ray needs render.profile physical: the ray test is a term of the physical profile's depth groups",
        ));
    }
    on(Event::Plan(&plan));
    for m in plan_warnings(w, h, &s, &foci, &opts, &plan) {
        warn(m, &mut on);
    }
    let (start, why) = start_map(w, h, &s, &foci, &opts, &plan);
    if let Some(m) = why {
        warn(m, &mut on);
    }
    // Coarsest level first; each level starts from the previous one's map, resized.
    let mut d = start;
    let mut first = None;
    let mut last = None;
    for level in (plan.finest_level..plan.finest_level + plan.levels).rev() {
        let (lw, lh) = level_size(w, h, level);
        let a = aif.resized(lw, lh);
        let mut ls = s;
        (ls.blur, ls.lens) = level_blur_lens(&s, w, lw, lh);
        let targets: Vec<Target> = shots.iter().zip(&foci).map(|(shot, &focus)| Target::of(shot, focus, ls, lw, lh)).collect();
        let mut step = |st: Step| {
            if level == plan.finest_level && first.is_none() {
                first = Some(st);
            }
            on(Event::Step(st));
        };
        d = optimise_level(&a, &targets, d.resized(lw, lh), &opts, level, &mut step)?;
        if level == plan.finest_level {
            let terms = evaluate(&a, &targets, &d, &opts, false)?.0;
            last = Some(terms.at(level, opts.iters));
            if let Some(m) = near_far_warning(&d, &ls, &foci) {
                warn(m, &mut on);
            }
        }
    }
    // A reduced plan's map follows the photo's edges to full size (a plain resize smears
    // each depth edge over a level pixel).
    let disparity = super::dfd_upsample::upsample_guided(&d, aif);
    let optimised = d;
    let (first, last) = first.zip(last).ok_or_else(|| Error::Internal("dfd: no step was run at the finest level".into()))?;
    Ok(Estimate { disparity, optimised, plan, first, last, warnings })
}

/// The checks of [`estimate_with`] (see there).
fn check_options(aif: &Image, bokeh: &Image, s: &RenderSettings, opts: &DfdOptions) -> Result<()> {
    if (aif.width, aif.height) != (bokeh.width, bokeh.height) || aif.channels != 3 || bokeh.channels != 3 {
        return Err(Error::usage(format!(
            "the all-in-focus photo is {}x{} with {} channels and the defocused one {}x{} with {}: they must be the same size, RGB",
            aif.width, aif.height, aif.channels, bokeh.width, bokeh.height, bokeh.channels
        )));
    }
    check_focus("render.focus", s.focus)?;
    check_blur("render.blur", s.blur)?;
    check_iters("dfd.iters", i64::try_from(opts.iters).unwrap_or(i64::MAX))?;
    check_levels("dfd.levels", i64::try_from(opts.levels).unwrap_or(i64::MAX))?;
    if !opts.learning_rate.is_finite() || opts.learning_rate <= 0.0 {
        return Err(Error::usage(format!("dfd.learning_rate must be a finite number > 0, got {}", opts.learning_rate)));
    }
    if !(0.0..=1.0).contains(&opts.init) {
        return Err(Error::usage(format!("dfd.init must be a normalized disparity in [0, 1], got {}", opts.init)));
    }
    // The exact tape draws every aperture; the span render and the Gaussian PSF the plain disc.
    if !super::dfd_plan::spans_draw(s) {
        let a = s.aperture.label();
        if opts.renderer != DfdRenderer::DrBokeh {
            return Err(Error::usage(format!(
                "dfd.renderer {}: the Gaussian-PSF ablation has no aperture shape or chromatic aberration (aperture.shape {a}); use the disc",
                opts.renderer.name()
            )));
        }
        if opts.kernel == DfdKernel::Fast {
            return Err(Error::usage(format!(
                "dfd.kernel fast draws the plain disc only; aperture.shape {a} needs dfd.kernel exact or ray (auto picks them)"
            )));
        }
    }
    Ok(())
}

/// The plan of a stack focused at `foci`: each photo's plan with an equal share of the time
/// budget, the one at the coarsest finest level (the first of equals), its cost counted once
/// per photo. One photo: [`plan`] itself.
fn stack_plan(w: usize, h: usize, s: &RenderSettings, foci: &[f32], opts: &DfdOptions) -> DfdPlan {
    let share = DfdOptions { cpu_budget: opts.cpu_budget / foci.len() as f64, ..*opts };
    let plans = foci.iter().map(|&focus| plan(w, h, &RenderSettings { focus, ..*s }, &share));
    let mut chosen = plans.reduce(|a, b| if b.finest_level > a.finest_level { b } else { a }).expect("at least one photo");
    chosen.cpu_seconds *= foci.len() as f64;
    chosen
}

/// What the plan's user should know before it runs: levels capped, a long run, photos whose
/// blur cannot tell any disparity (every photo of a stack).
fn plan_warnings(w: usize, h: usize, s: &RenderSettings, foci: &[f32], opts: &DfdOptions, plan: &DfdPlan) -> Vec<String> {
    let mut out = Vec::new();
    // A request beyond what the photo's size allows is the user's to hear about; levels the
    // plan or the blur drop below that are its own business (the report has `plan.levels`).
    let most = super::dfd_plan::size_levels(w, h);
    if opts.levels > most {
        out.push(format!(
            "dfd.levels {}: a {w}x{h} photo has {most} level(s) of at least {} px a side; running {} (levels that blur no pixel by {} px are left out too)",
            opts.levels,
            super::dfd_plan::MIN_LEVEL_SIDE,
            plan.levels,
            super::dfd_plan::MIN_LEVEL_COC
        ));
    }
    let threads = rayon::current_num_threads();
    let secs = plan.seconds(threads);
    if secs > LONG_RUN_SECONDS {
        let when = if secs < 5400.0 { format!("{:.0} minutes", secs / 60.0) } else { format!("{:.1} hours", secs / 3600.0) };
        out.push(format!(
            "dfd.iters {} x {} level(s) with the {} render up to {}x{} will take up to about {when} here ({threads} threads); fewer steps (dfd.iters) or levels (dfd.levels) take less",
            opts.iters,
            plan.levels,
            plan.kernel.name(),
            plan.width,
            plan.height
        ));
    }
    if foci.iter().all(|&f| undetermined(s.blur, f)) {
        out.push(format!(
            "render.blur {} at render.focus {}: no disparity in [0, 1] blurs a pixel by {} px (the largest CoC radius is {:.3} px), so the photo does not determine the map; it is returned as it started",
            s.blur,
            s.focus,
            dfd_start::DEAD_COC_PX,
            coc_radius(focus_room(s.focus), s.blur)
        ));
    }
    out
}

/// The map the first (coarsest) level starts from: `init` everywhere, or the replacement of
/// a start in that level's dead band ([`movable_start`]; for a stack, in every photo's, the
/// first photo's replacement) with the warning that says so. Where the photos cannot tell
/// anything ([`undetermined`]) `init` is kept (and returned).
fn start_map(w: usize, h: usize, s: &RenderSettings, foci: &[f32], opts: &DfdOptions, plan: &DfdPlan) -> (Image, Option<String>) {
    let coarsest = plan.finest_level + plan.levels - 1;
    let (cw, ch) = level_size(w, h, coarsest);
    let (blur, _) = level_blur_lens(s, w, cw, ch);
    let stuck = foci.iter().all(|&f| movable_start(opts.init, blur, f).is_some());
    match movable_start(opts.init, blur, s.focus).filter(|_| stuck) {
        Some(d) if !foci.iter().all(|&f| undetermined(s.blur, f)) => (
            Image::filled(cw, ch, 1, d),
            Some(format!(
                "dfd.init {} is within {} px of blur of render.focus {} at the first level ({cw}x{ch}, K {blur}), where the render does not change with the disparity and the map could not move; started from {d} instead (half-way out on the side of the focal plane with more room)",
                opts.init,
                dfd_start::DEAD_COC_PX,
                s.focus
            )),
        ),
        _ => (Image::filled(cw, ch, 1, opts.init), None),
    }
}

/// The near/far warning for the finest level's map `d` (settings `s` of that level): how
/// much of it is blurred where the other side of the focal plane is in range too. None for a
/// stack with two focal planes or more: a depth and its mirror image about one focal plane are
/// blurred differently by the other.
fn near_far_warning(d: &Image, s: &RenderSettings, foci: &[f32]) -> Option<String> {
    if foci.iter().any(|&f| f != foci[0]) {
        return None;
    }
    let (behind, front) = ambiguous_share(d, s.blur, s.focus);
    (behind + front > 0.0).then(|| {
        format!(
            "render.focus {} lies inside the disparity range [0, 1]: defocus shows how far a pixel is from the focal plane, not on which side, and {:.0}% of the map is blurred where both sides are in range; the map keeps the side it started on (behind the focal plane: {:.0}%, in front: {:.0}%), and the other side fits the photo as well",
            s.focus,
            100.0 * (behind + front),
            100.0 * behind,
            100.0 * front
        )
    })
}

/// The loss terms of one render of a level's map.
#[derive(Clone, Copy, Debug)]
struct Terms {
    loss: f64,
    l1: f64,
    smoothness: f64,
    ssim: f64,
}

impl Terms {
    fn at(self, level: usize, iter: usize) -> Step {
        Step { level, iter, loss: self.loss, l1: self.l1, smoothness: self.smoothness, ssim: self.ssim }
    }
}

/// Renders map `d` of one level (`aif`, and each target photo with the settings of that level
/// and its focus) with the options' renderer and kernel: the loss terms (data terms averaged
/// over the targets), and with `grad` the loss's gradient with respect to every pixel's
/// disparity (the renders' VJPs plus the smoothness term's). One render (and one VJP) per
/// target at the level's size.
fn evaluate(aif: &Image, targets: &[Target], d: &Image, opts: &DfdOptions, grad: bool) -> Result<(Terms, Vec<f64>)> {
    let alpha = Image::filled(aif.width, aif.height, 1, 1.0);
    let layers = match opts.renderer {
        DfdRenderer::DrBokeh => Some([Layer::from_parts(aif, &alpha, d, "dfd")?]),
        DfdRenderer::GaussPsf => None,
    };
    let wts = opts.weights;
    let share = 1.0 / targets.len() as f64;
    let sm = loss::gradient_smoothness(d);
    let (mut l1_sum, mut ssim_sum) = (0.0f64, 0.0f64);
    let mut g_sum = if grad { vec![0f64; d.data.len()] } else { Vec::new() };
    for Target { photo: target, clipped, settings: s } in targets {
        let tape = match &layers {
            Some(layers) => match opts.kernel {
                DfdKernel::Fast | DfdKernel::Auto => Recording::Span(Box::new(SpanTape::record(&layers[0], s, opts.smoothing)?)),
                k => Recording::DrBokeh(Tape::record_with(layers, s, opts.smoothing, k == DfdKernel::Ray)?),
            },
            None => Recording::Gauss(GaussTape::record(aif, d, s.focus, s.blur, window_radius(s.blur, s.focus))?),
        };
        let censored = clipped.as_ref().map(|c| loss::censor(tape.image(), target, c));
        let seen = censored.as_ref().map_or(tape.image(), |c| &c.0);
        let l1 = loss::l1(seen, target);
        let hs = loss::hssim(seen, target, wts.windows);
        (l1_sum, ssim_sum) = (l1_sum + share * l1.value, ssim_sum + share * hs.value);
        if grad {
            let mut seed = l1.grad;
            seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, hg)| *g = *g * wts.l1 + hg * wts.ssim);
            if let Some((_, passed)) = &censored {
                seed.data.iter_mut().zip(passed).filter(|(_, p)| !**p).for_each(|(g, _)| *g = 0.0);
            }
            for (acc, g) in g_sum.iter_mut().zip(tape.disparity_grad(&seed)?) {
                *acc += share * g as f64;
            }
        }
    }
    let loss = wts.l1 as f64 * l1_sum + wts.ssim as f64 * ssim_sum + wts.smoothness as f64 * sm.value;
    let terms = Terms { loss, l1: l1_sum, smoothness: sm.value, ssim: ssim_sum };
    for (acc, &sg) in g_sum.iter_mut().zip(&sm.grad.data) {
        *acc += wts.smoothness as f64 * sg as f64;
    }
    Ok((terms, g_sum))
}

/// Adam on one level's disparity, `step` told of each step's losses.
fn optimise_level(
    aif: &Image,
    targets: &[Target],
    mut d: Image,
    opts: &DfdOptions,
    level: usize,
    step: &mut impl FnMut(Step),
) -> Result<Image> {
    let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
    let n = d.data.len();
    let (mut m, mut v) = (vec![0f64; n], vec![0f64; n]);
    for it in 0..opts.iters {
        let (terms, g) = evaluate(aif, targets, &d, opts, true)?;
        step(terms.at(level, it));
        let t = (it + 1) as i32;
        for (i, dv) in d.data.iter_mut().enumerate() {
            let gi = g[i];
            m[i] = b1 * m[i] + (1.0 - b1) * gi;
            v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
            let (mh, vh) = (m[i] / (1.0 - b1.powi(t)), v[i] / (1.0 - b2.powi(t)));
            *dv = (*dv as f64 - opts.learning_rate as f64 * mh / (vh.sqrt() + eps)).clamp(0.0, 1.0) as f32;
        }
    }
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{Kernel, Profile, render};

    /// A textured 32×32 view, near half at disparity 1 (the focal plane), far half at 0.4,
    /// K = 4, start 0.5 everywhere: 2 levels × 40 steps bring the full-size L1 from 0.0123
    /// to 0.0013 and the mean disparity error from 0.30 to 0.022 (asserted: ×0.25, ×0.15),
    /// with the span render (the default) and with the exact tape.
    #[test]
    fn recovers_a_two_plane_scene() {
        let (w, h) = (32usize, 32usize);
        let mut seed = 9u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let aif = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd()).collect()).unwrap();
        let truth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w < w / 2 { 1.0 } else { 0.4 }).collect()).unwrap();
        let s = RenderSettings {
            blur: 4.0,
            focus: 1.0,
            lens: 0,
            occlusion: true,
            profile: Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        };
        let opts = DfdOptions { iters: 40, levels: 2, ..DfdOptions::default() };
        let mut rs = s;
        rs.lens = 2 * ((s.blur * 1.0).ceil() as usize + 3) + 1;
        let layer = Layer::from_parts(&aif, &Image::filled(w, h, 1, 1.0), &truth, "truth").unwrap();
        let bokeh = render(&[layer], &rs, Kernel::Exact).unwrap();
        for kernel in [DfdKernel::Fast, DfdKernel::Exact, DfdKernel::Ray] {
            let opts = DfdOptions { kernel, ..opts };
            let mut log = Vec::new();
            let d = estimate(&aif, &bokeh, &s, &opts, |st| log.push(st)).unwrap();
            let full: Vec<&Step> = log.iter().filter(|st| st.level == 0).collect();
            assert!(full.last().unwrap().l1 < 0.25 * full[0].l1, "{kernel:?}: L1 {} → {}", full[0].l1, full.last().unwrap().l1);
            let err = |d: &Image| d.data.iter().zip(&truth.data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / (w * h) as f64;
            let start = Image::filled(w, h, 1, opts.init);
            eprintln!(
                "{kernel:?}: L1 {:.4} → {:.4}; disparity error {:.4} (start {:.4})",
                full[0].l1,
                full.last().unwrap().l1,
                err(&d),
                err(&start)
            );
            assert!(err(&d) < 0.15 * err(&start), "{kernel:?}: disparity error {} (start {})", err(&d), err(&start));
        }
        // Mismatched photos are a usage error naming both sizes.
        let e = estimate(&aif, &Image::new(8, 8, 3), &s, &opts, |_| {}).unwrap_err().to_string();
        assert!(e.contains("32x32") && e.contains("8x8"), "{e}");
    }

    /// An 8-bit pair of a view with small lights (radiance 12, 2.5 px across) on a textured far
    /// plane (disparity 0.3) beside a near plane in focus (1.0), K 8: clipped, the photo
    /// focused on the near plane spreads far more light around each light than a render of the
    /// clipped all-in-focus photo can, and the map is pulled towards less blur there. With the
    /// lights recovered and the clipped samples taken as lower bounds, the map near the lights
    /// is closer to the truth (asserted: error ×0.8). An unclipped pair gives the very same
    /// map with or without the clip level.
    #[test]
    fn clipped_lights_do_not_pull_the_map_in_focus() {
        use crate::bench::inputs::{Input, photo};
        let (w, h) = (48usize, 48usize);
        let mut seed = 21u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut linear = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| 0.1 + 0.4 * rnd()).collect()).unwrap();
        let lights = [(30.3, 9.6), (38.7, 24.2), (27.5, 38.4), (40.2, 41.1)];
        crate::diff::dfd_light::tests::paint_lights(&mut linear, &lights, 1.25, 12.0);
        let truth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w < 16 { 1.0 } else { 0.3 }).collect()).unwrap();
        let s = RenderSettings {
            blur: 8.0,
            focus: 1.0,
            lens: 2 * (8 + 3) + 1,
            occlusion: true,
            profile: Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        };
        let layer = Layer::from_parts(&linear, &Image::filled(w, h, 1, 1.0), &truth, "truth").unwrap();
        let target = render(&[layer], &s, Kernel::Exact).unwrap();
        let (aif8, target8) = (photo(&linear, Input::Srgb8).0.into_owned(), photo(&target, Input::Srgb8).0.into_owned());
        let encoding = Input::Srgb8.encoding();
        // The span render: the clip model is the loss's, whichever render is inverted.
        let opts = DfdOptions { iters: 60, levels: 2, kernel: DfdKernel::Fast, ..DfdOptions::default() };
        // Error within 6 px of a light.
        let near: Vec<usize> = (0..w * h)
            .filter(|i| lights.iter().any(|&(cx, cy)| ((i % w) as f32 + 0.5 - cx).hypot((i / w) as f32 + 0.5 - cy) < 6.0))
            .collect();
        let err = |d: &Image| near.iter().map(|&i| (d.data[i] - truth.data[i]).abs() as f64).sum::<f64>() / near.len() as f64;
        let plain = estimate_stack(&aif8, &[Shot::linear(&target8, 1.0)], &s, &opts, |_| {}).unwrap().disparity;
        let clip = clip_level(encoding);
        let shot = Shot { photo: &target8, focus: 1.0, clip };
        let light = aif_light(&aif8, encoding, &[shot], s.blur).unwrap();
        assert!(matches!(light, std::borrow::Cow::Owned(_)), "the lights were recovered");
        let aware = estimate_stack(&light, &[shot], &s, &opts, |_| {}).unwrap().disparity;
        eprintln!("near the lights: disparity error {:.4} plain, {:.4} with the clip model", err(&plain), err(&aware));
        assert!(err(&aware) < 0.8 * err(&plain), "{} vs {}", err(&aware), err(&plain));
        assert!(aware.data.iter().all(|v| (0.0..=1.0).contains(v)));
        // Nothing clipped: no mask, the same map bit for bit.
        let dim = |img: &Image| Image::from_vec(w, h, 3, img.data.iter().map(|v| v.min(0.9)).collect()).unwrap();
        let (a, t) = (dim(&aif8), dim(&target8));
        let shot = Shot { photo: &t, focus: 1.0, clip };
        assert!(matches!(aif_light(&a, encoding, &[shot], s.blur).unwrap(), std::borrow::Cow::Borrowed(_)));
        let with = estimate_stack(&a, &[shot], &s, &opts, |_| {}).unwrap().disparity;
        let without = estimate_stack(&a, &[Shot::linear(&t, 1.0)], &s, &opts, |_| {}).unwrap().disparity;
        assert_eq!(with.data, without.data);
    }

    /// A photo focused between two planes (disparity 0.2 and 0.8, focus 0.5) blurs both alike:
    /// alone it cannot tell which half is near, and the map keeps the side it starts on. A
    /// second photo focused on the near end (1.0) tells them apart: 92% of the stack's map is
    /// within 0.1 of the truth (mean error 0.049) where half of the single photo's is (0.30),
    /// and the single run's near/far warning is not given for the stack.
    #[test]
    fn a_focal_stack_resolves_what_one_photo_cannot() {
        let (w, h) = (32usize, 32usize);
        let mut seed = 5u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let aif = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd()).collect()).unwrap();
        let truth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w < w / 2 { 0.2 } else { 0.8 }).collect()).unwrap();
        let s = RenderSettings {
            blur: 8.0,
            focus: 0.5,
            lens: 2 * (8 + 3) + 1,
            occlusion: true,
            profile: Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        };
        let layer = Layer::from_parts(&aif, &Image::filled(w, h, 1, 1.0), &truth, "truth").unwrap();
        let shot = |focus: f32| render(std::slice::from_ref(&layer), &RenderSettings { focus, ..s }, Kernel::Exact).unwrap();
        let (middle, near) = (shot(0.5), shot(1.0));
        let err = |d: &Image| d.data.iter().zip(&truth.data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / (w * h) as f64;
        let opts = DfdOptions { iters: 100, levels: 2, ..DfdOptions::default() };
        let one = estimate_with(&aif, &middle, &s, &opts, |_| {}).unwrap();
        let stack = [Shot::linear(&middle, 0.5), Shot::linear(&near, 1.0)];
        let both = estimate_stack(&aif, &stack, &s, &opts, |_| {}).unwrap();
        // Share of the pixels within 0.1 of the truth (on the right side of the focal plane).
        let close = |d: &Image| d.data.iter().zip(&truth.data).filter(|(a, b)| (*a - *b).abs() < 0.1).count() as f64 / (w * h) as f64;
        let (e1, e2, c1, c2) = (err(&one.disparity), err(&both.disparity), close(&one.disparity), close(&both.disparity));
        eprintln!("one photo: disparity error {e1:.4}, {c1:.3} within 0.1; stack: {e2:.4}, {c2:.3}");
        assert!(e1 > 0.2 && c1 < 0.6, "one photo should be ambiguous here: error {e1}, {c1} within 0.1");
        assert!(one.warnings.iter().any(|m| m.contains("not on which side")), "{:?}", one.warnings);
        assert!(e2 < 0.1 && c2 > 0.85, "stack: disparity error {e2}, {c2} within 0.1");
        assert!(!both.warnings.iter().any(|m| m.contains("not on which side")), "{:?}", both.warnings);
        assert!(both.disparity.data.iter().all(|v| (0.0..=1.0).contains(v)));
        // A stack photo of another size is refused; so is an empty stack.
        let small = Image::new(8, 8, 3);
        let e = estimate_stack(&aif, &[stack[0], Shot::linear(&small, 1.0)], &s, &opts, |_| {}).unwrap_err().to_string();
        assert!(e.contains("8x8"), "{e}");
        assert!(estimate_stack(&aif, &[], &s, &opts, |_| {}).is_err());
    }

    /// `Auto` takes the ray test where it applies, at the finest level whose estimated run fits
    /// the budget (full size where it can), the span render where the test does not apply; an
    /// explicit kernel runs at full size; the ray test with the official profile is a usage
    /// error naming the kernel. A reduced plan's map comes back at the photo's size.
    #[test]
    fn auto_plan_and_ray_checks() {
        let s = RenderSettings {
            blur: 6.4,
            focus: 1.0,
            lens: 0,
            occlusion: true,
            profile: Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        };
        let o = DfdOptions::default();
        let p = |w, h, s: &RenderSettings, o: &DfdOptions| {
            let p = plan(w, h, s, o);
            assert!(p.cpu_seconds <= o.cpu_budget || o.kernel != DfdKernel::Auto || p.finest_level > 0, "{p:?}");
            (p.kernel, p.finest_level, p.width, p.height)
        };
        assert_eq!(p(64, 64, &s, &o), (DfdKernel::Ray, 0, 64, 64));
        // The worst case of the cost model (every source as blurred as the range allows) puts
        // these a level lower than the old tap count did.
        assert_eq!(p(128, 128, &RenderSettings { blur: 15.0, ..s }, &o), (DfdKernel::Ray, 1, 64, 64));
        assert_eq!(p(256, 256, &RenderSettings { blur: 30.0, ..s }, &o), (DfdKernel::Ray, 2, 64, 64));
        let big = plan(4000, 3000, &RenderSettings { blur: 400.0, ..s }, &o);
        assert_eq!(big.kernel, DfdKernel::Ray);
        assert!(big.width.min(big.height) >= AUTO_MIN_SIDE && big.width < 300 && big.cpu_seconds <= o.cpu_budget, "{big:?}");
        assert_eq!(p(64, 64, &RenderSettings { occlusion: false, ..s }, &o), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(64, 64, &RenderSettings { profile: Profile::Official, ..s }, &o), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(64, 64, &s, &DfdOptions { renderer: DfdRenderer::GaussPsf, ..o }), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(4000, 3000, &s, &DfdOptions { kernel: DfdKernel::Exact, ..o }), (DfdKernel::Exact, 0, 4000, 3000));
        // Nothing fits: the span render at the coarsest level allowed (20 px; 10 would be under
        // AUTO_MIN_SIDE).
        let none = DfdOptions { iters: MAX_ITERS, ..o };
        assert_eq!(p(40, 40, &RenderSettings { blur: 1e6, ..s }, &none), (DfdKernel::Fast, 1, 20, 20));
        // A reduced plan: optimised at 32×24, returned at 64×48 (K 8, 2 steps of 2 levels: about
        // 0.3 CPU seconds ending at full size, 0.04 ending at level 1).
        let aif = Image::from_vec(64, 48, 3, (0..64 * 48 * 3).map(|v| (v % 11) as f32 / 11.0).collect()).unwrap();
        let ro = DfdOptions { iters: 2, levels: 2, cpu_budget: 0.1, ..o };
        let pl = plan(64, 48, &RenderSettings { blur: 8.0, ..s }, &ro);
        assert_eq!((pl.kernel, pl.finest_level, pl.width, pl.height, pl.levels, pl.steps), (DfdKernel::Ray, 1, 32, 24, 2, 4), "{pl:?}");
        let mut sizes = Vec::new();
        let d = estimate(&aif, &aif, &RenderSettings { blur: 8.0, ..s }, &ro, |st| sizes.push(st.level)).unwrap();
        assert_eq!((d.width, d.height), (64, 48));
        assert_eq!(sizes, [2, 2, 1, 1]);
        let aif = Image::filled(8, 8, 3, 0.5);
        let official = RenderSettings { profile: Profile::Official, ..s };
        let e = estimate(&aif, &aif, &official, &DfdOptions { kernel: DfdKernel::Ray, iters: 1, ..o }, |_| {}).unwrap_err();
        assert!(e.to_string().contains("dfd.kernel") && e.to_string().contains("physical"), "{e}");
    }

    /// A K near f32::MAX is legal (finite): every level's window and blur stay finite and the
    /// estimate is a disparity in [0, 1] (the coarse levels' K once overflowed to inf, a usage
    /// error that named a --blur the user never gave).
    #[test]
    fn huge_blur_is_accepted_at_every_level() {
        let aif = Image::from_vec(8, 6, 3, (0..8 * 6 * 3).map(|v| (v % 7) as f32 / 7.0).collect()).unwrap();
        for blur in [3e38f32, 1e30, 1e-30] {
            let s = RenderSettings {
                blur,
                focus: 1.0,
                lens: 0,
                occlusion: true,
                profile: Profile::Physical,
                aperture: crate::render::Aperture::DISC,
            };
            let opts = DfdOptions { iters: 2, levels: 2, ..DfdOptions::default() };
            let d = estimate(&aif, &aif, &s, &opts, |_| {}).unwrap_or_else(|e| panic!("K {blur}: {e}"));
            assert!(d.data.iter().all(|v| (0.0..=1.0).contains(v)), "K {blur}");
        }
    }

    /// The Gaussian-PSF renderer plugged into the same optimiser inverts its own renders: a
    /// 24×24 noise texture, halves at 1.0 (in focus) and 0.3, K = 4, 2 levels × 30 steps bring
    /// the mean disparity error from 0.35 to under a third of that.
    #[test]
    fn gauss_psf_renderer_inverts_its_own_render() {
        let (w, h) = (24usize, 24usize);
        let mut seed = 4u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let aif = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| rnd()).collect()).unwrap();
        let truth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if i % w < w / 2 { 1.0 } else { 0.3 }).collect()).unwrap();
        let s = RenderSettings {
            blur: 4.0,
            focus: 1.0,
            lens: 0,
            occlusion: true,
            profile: Profile::Physical,
            aperture: crate::render::Aperture::DISC,
        };
        let bokeh = GaussTape::record(&aif, &truth, 1.0, 4.0, window_radius(4.0, 1.0)).unwrap().image().clone();
        let opts = DfdOptions { iters: 30, levels: 2, renderer: DfdRenderer::GaussPsf, ..DfdOptions::default() };
        let d = estimate(&aif, &bokeh, &s, &opts, |_| {}).unwrap();
        let err = |d: &Image| d.data.iter().zip(&truth.data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / (w * h) as f64;
        let start = err(&Image::filled(w, h, 1, opts.init));
        eprintln!("gauss-psf: disparity error {:.4} (start {start:.4})", err(&d));
        assert!(err(&d) < start / 3.0, "disparity error {} (start {start})", err(&d));
    }
}
