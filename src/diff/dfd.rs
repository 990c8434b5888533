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
//! R ≈ 1.5·K·max(focus, 1 − focus)).

use super::gauss_psf::{GaussTape, window_radius};
use super::loss::{self, HSSIM_WINDOWS};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::render::{Layer, Profile, RenderSettings, Smoothing, SpanTape, Tape, check_blur, check_focus, max_lens};

/// The window of the plain (single-scale) SSIM term, pixels: the usual 11×11 of Wang et al.
pub const SSIM_WINDOW: [usize; 1] = [11];

/// The loss weights of Eqn. 7.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LossWeights {
    /// λ₁, L1 between render and target.
    pub l1: f32,
    /// λ₂, gradient smoothness of the disparity.
    pub smoothness: f32,
    /// λ₃, the SSIM term: `1 - mean SSIM` over those of `windows` that fit the level.
    pub ssim: f32,
    /// The SSIM windows (odd sides, pixels): [`HSSIM_WINDOWS`] for the paper's hierarchical
    /// SSIM, [`SSIM_WINDOW`] for plain SSIM.
    pub windows: &'static [usize],
}

/// The objectives of the paper's loss ablation (Table 2), by their command-line names.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
// The shared prefix is the point: every variant adds a term to L1 + gradient smoothness.
#[allow(clippy::enum_variant_names)]
pub enum LossVariant {
    /// L1 + gradient smoothness.
    L1Grad,
    /// L1 + gradient smoothness + SSIM (one 11×11 window).
    L1GradSsim,
    /// L1 + gradient smoothness + hierarchical SSIM (windows 3, 5, 11, 21, 31): Eqn. 7.
    #[default]
    L1GradHssim,
}

impl LossVariant {
    /// The weights: λ₁ = 1, λ₂ = 0.01 and λ₃ = 1 (0 for [`LossVariant::L1Grad`]).
    pub fn weights(self) -> LossWeights {
        let base = LossWeights { l1: 1.0, smoothness: 0.01, ssim: 1.0, windows: &HSSIM_WINDOWS };
        match self {
            LossVariant::L1Grad => LossWeights { ssim: 0.0, windows: &[], ..base },
            LossVariant::L1GradSsim => LossWeights { windows: &SSIM_WINDOW, ..base },
            LossVariant::L1GradHssim => base,
        }
    }

    /// The command-line name (also the serialized one).
    pub fn name(self) -> &'static str {
        match self {
            LossVariant::L1Grad => "l1-grad",
            LossVariant::L1GradSsim => "l1-grad-ssim",
            LossVariant::L1GradHssim => "l1-grad-hssim",
        }
    }
}

/// The differentiable renderer that [`estimate`] inverts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DfdRenderer {
    /// Dr.Bokeh (exact kernel, [`crate::render::Tape`]) with the settings' profile and
    /// occlusion.
    #[default]
    DrBokeh,
    /// The Gaussian-PSF renderer ([`super::gauss_psf`]; the settings' profile, occlusion and
    /// lens are not used): the GaussPSF-style ablation.
    GaussPsf,
}

impl DfdRenderer {
    /// The name in reports ("drbokeh", "gauss-psf"; also the serialized one).
    pub fn name(self) -> &'static str {
        match self {
            DfdRenderer::DrBokeh => "drbokeh",
            DfdRenderer::GaussPsf => "gauss-psf",
        }
    }
}

/// Which differentiable Dr.Bokeh render [`estimate`] inverts (with [`DfdRenderer::DrBokeh`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum DfdKernel {
    /// [`DfdKernel::Ray`] where it applies (physical profile, occlusion on) and its estimated
    /// cost over all levels stays within [`AUTO_RAY_BUDGET`]; [`DfdKernel::Fast`] otherwise
    /// (see [`plan`]).
    #[default]
    Auto,
    /// [`SpanTape`]: spans instead of taps, the in-layer depth groups interpolated between
    /// depth bins (disparity gradients within 0.3% (physical) and 3.5% (official) of the exact
    /// tape's in relative L2 on the scenes of `tests/span_tape.rs`; README "Depth from
    /// defocus").
    Fast,
    /// [`Tape`]: the exact kernel, O(pixels·lens²) per step.
    Exact,
    /// [`Tape::record_with`] with the ray test: the exact kernel, where a source behind a
    /// target counts only as far as the ray between them passes the photo's surface (the
    /// physical profile only). The visibility of one opaque 2.5D surface, which the
    /// statistical fill of the other two only approximates. O(pixels·lens²) per step, about
    /// 1.7x the exact tape.
    Ray,
}

/// The most tap evaluations (Σ over levels of steps × pixels × window taps) that
/// [`DfdKernel::Auto`] spends on the ray test: about two minutes of optimisation on 2 cores
/// (a 128×128 step at K 15, 17.6 M taps, takes 0.47 s there). A 64×64 view at K 6.4 needs
/// 2e8, 128×128 at K 15 2.3e9, 256×256 at K 30 3.6e10 (that one is then optimised at 128×128).
pub const AUTO_RAY_BUDGET: f64 = 4e9;

/// The smallest side, pixels, of the finest level [`DfdKernel::Auto`] may optimise at instead of
/// the full size.
pub const AUTO_MIN_SIDE: usize = 16;

/// How [`estimate`] runs: the differentiable render, and the finest resolution level it
/// optimises at (0: full size; above 0 the map is optimised at that level's size, the
/// pyramid's `levels` levels ending there, and resized to the photo's size at the end).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct DfdPlan {
    /// The render ([`DfdKernel::Auto`] resolved).
    pub kernel: DfdKernel,
    /// The finest level (see [`level_size`]).
    pub finest_level: usize,
    /// Width of the map optimised at the finest level, pixels.
    pub width: usize,
    /// Its height.
    pub height: usize,
}

/// The plan of [`estimate`] for a `w × h` photo with settings `s` and `opts`. An explicit
/// kernel runs at full size. [`DfdKernel::Auto`] takes the ray test where it applies (physical
/// profile, occlusion on, the Dr.Bokeh renderer), at the finest level whose pyramid costs at
/// most `opts.ray_budget` (not below [`AUTO_MIN_SIDE`] pixels a side), and the span render at
/// full size where none does or the test does not apply (without occlusion the span render is
/// the exact tape's function, and cheaper). On the bench's scenes at 128 and 256 px the ray
/// test at a reduced size, resized, beat the span render at full size (README "The ray test").
pub fn plan(w: usize, h: usize, s: &RenderSettings, opts: &DfdOptions) -> DfdPlan {
    let at = |kernel, finest_level| {
        let (width, height) = level_size(w, h, finest_level);
        DfdPlan { kernel, finest_level, width, height }
    };
    if opts.kernel != DfdKernel::Auto {
        return at(opts.kernel, 0);
    }
    if opts.renderer != DfdRenderer::DrBokeh || s.profile != Profile::Physical || !s.occlusion {
        return at(DfdKernel::Fast, 0);
    }
    let cost = |finest: usize| -> f64 {
        (finest..finest + opts.levels.min(64))
            .map(|level| {
                let (lw, lh) = level_size(w, h, level);
                let (_, lens) = level_blur_lens(s, w, lw, lh);
                opts.iters as f64 * (lw * lh) as f64 * (lens * lens) as f64 * std::f64::consts::FRAC_PI_4
            })
            .sum()
    };
    (0..64usize)
        .take_while(|&l| {
            let (lw, lh) = level_size(w, h, l);
            l == 0 || lw.min(lh) >= AUTO_MIN_SIDE
        })
        .find(|&l| cost(l) <= opts.ray_budget)
        .map_or_else(|| at(DfdKernel::Fast, 0), |l| at(DfdKernel::Ray, l))
}

/// A level's K (scaled with its width) and lens window (what the disparity range [0, 1] needs
/// there, at most the level's largest window).
fn level_blur_lens(s: &RenderSettings, w: usize, lw: usize, lh: usize) -> (f32, usize) {
    // The ratio first: K near f32::MAX times the width would overflow to inf.
    let blur = s.blur * (lw as f32 / w as f32);
    // Saturating: a huge K (legal, finite) must give the widest window, not a wrapped one.
    let reach = ((blur * s.focus.max(1.0 - s.focus).max(0.0)).ceil() as usize).saturating_add(3);
    (blur, reach.saturating_mul(2).saturating_add(1).min(max_lens(lw, lh) | 1))
}

impl DfdKernel {
    /// The command-line name ("fast", "exact"; also the serialized one).
    pub fn name(self) -> &'static str {
        match self {
            DfdKernel::Fast => "fast",
            DfdKernel::Auto => "auto",
            DfdKernel::Exact => "exact",
            DfdKernel::Ray => "ray",
        }
    }
}

/// One recorded forward render of a level's disparity, whichever renderer made it.
enum Recording<'a> {
    DrBokeh(Tape<'a>),
    Span(SpanTape<'a>),
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

/// Options of [`estimate`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DfdOptions {
    /// Adam steps per resolution level.
    pub iters: usize,
    /// Resolution levels, coarsest first (each half the size of the next), ending at the plan's
    /// finest level ([`plan`]: full size unless `auto` chose a smaller one); 1 = that level only.
    pub levels: usize,
    /// Adam's step size, in units of normalized disparity.
    pub learning_rate: f32,
    /// The loss weights.
    pub weights: LossWeights,
    /// The physical profile's smooth edges (see [`Smoothing`]).
    #[serde(skip)]
    pub smoothing: Smoothing,
    /// The disparity every pixel starts from.
    pub init: f32,
    /// The renderer inverted.
    pub renderer: DfdRenderer,
    /// The Dr.Bokeh render differentiated (see [`DfdKernel`]).
    pub kernel: DfdKernel,
    /// The most tap evaluations [`DfdKernel::Auto`] spends on the ray test ([`plan`];
    /// default [`AUTO_RAY_BUDGET`]).
    pub ray_budget: f64,
}

impl Default for DfdOptions {
    fn default() -> Self {
        DfdOptions {
            iters: 100,
            levels: 3,
            learning_rate: 0.02,
            weights: LossVariant::default().weights(),
            smoothing: Smoothing { edge_width: 1.0, fill_width: 0.1 },
            init: 0.5,
            renderer: DfdRenderer::DrBokeh,
            kernel: DfdKernel::Auto,
            ray_budget: AUTO_RAY_BUDGET,
        }
    }
}

/// One logged step: level (0 = full size), iteration, and the loss terms.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Step {
    /// Resolution level ([`level_size`]), counting down to the plan's finest level (0: full size).
    pub level: usize,
    /// Iteration within the level.
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

/// Estimates the disparity (one channel, the photos' size, in [0, 1], the units of `focus`
/// and `K`) from an all-in-focus photo `aif` and a photo `bokeh` of the same view rendered or
/// taken at `s.focus` with blur `s.blur` (both linear RGB). `s.lens` is ignored: each level
/// uses the window that the whole disparity range [0, 1] needs. `step` is called after every
/// iteration. Errors (usage, naming the parameter): photos of different sizes or channel
/// counts, a non-finite focus (`render.focus`), a blur that is not a finite number >= 0
/// (`render.blur`), no iterations (`dfd.iters`) or levels (`dfd.levels`), a learning rate
/// that is not a finite number > 0 (`dfd.learning_rate`), a start outside [0, 1] (`dfd.init`),
/// [`DfdKernel::Ray`] with the official profile (`dfd.kernel`). `opts.kernel`'s
/// [`DfdKernel::Auto`] is resolved once for all levels, with the finest level ([`plan`]).
pub fn estimate(aif: &Image, bokeh: &Image, s: &RenderSettings, opts: &DfdOptions, mut step: impl FnMut(Step)) -> Result<Image> {
    if (aif.width, aif.height) != (bokeh.width, bokeh.height) || aif.channels != 3 || bokeh.channels != 3 {
        return Err(Error::usage(format!(
            "the all-in-focus photo is {}x{} with {} channels and the defocused one {}x{} with {}: they must be the same size, RGB",
            aif.width, aif.height, aif.channels, bokeh.width, bokeh.height, bokeh.channels
        )));
    }
    check_focus("render.focus", s.focus)?;
    check_blur("render.blur", s.blur)?;
    if opts.iters == 0 {
        return Err(Error::usage("dfd.iters must be >= 1"));
    }
    if opts.levels == 0 {
        return Err(Error::usage("dfd.levels must be >= 1"));
    }
    if !opts.learning_rate.is_finite() || opts.learning_rate <= 0.0 {
        return Err(Error::usage(format!("dfd.learning_rate must be a finite number > 0, got {}", opts.learning_rate)));
    }
    if !(0.0..=1.0).contains(&opts.init) {
        return Err(Error::usage(format!("dfd.init must be a normalized disparity in [0, 1], got {}", opts.init)));
    }
    let (w, h) = (aif.width, aif.height);
    let plan = plan(w, h, s, opts);
    let opts = DfdOptions { kernel: plan.kernel, ..*opts };
    if opts.kernel == DfdKernel::Ray && s.profile != Profile::Physical {
        return Err(Error::usage(
            "dfd.kernel ray needs render.profile physical: the ray test is a term of the physical profile's depth groups",
        ));
    }
    let mut disparity: Option<Image> = None;
    for level in (plan.finest_level..plan.finest_level + opts.levels).rev() {
        let (lw, lh) = level_size(w, h, level);
        let (a, b) = (aif.resized(lw, lh), bokeh.resized(lw, lh));
        let d = match disparity.take() {
            Some(d) => d.resized(lw, lh),
            None => Image::filled(lw, lh, 1, opts.init),
        };
        let mut ls = *s;
        (ls.blur, ls.lens) = level_blur_lens(s, w, lw, lh);
        disparity = Some(optimise_level(&a, &b, d, &ls, &opts, level, &mut step)?);
    }
    let d = disparity.expect("at least one level");
    Ok(if (d.width, d.height) == (w, h) { d } else { d.resized(w, h) })
}

/// The size of resolution level `level` of a `w × h` photo: each side divided by `2^level`
/// (rounded down, at least 1 pixel). Level 0 is full size.
pub fn level_size(w: usize, h: usize, level: usize) -> (usize, usize) {
    let f = 1usize.checked_shl(level as u32).unwrap_or(usize::MAX);
    ((w / f).max(1), (h / f).max(1))
}

/// Adam on one level's disparity.
fn optimise_level(
    aif: &Image,
    target: &Image,
    mut d: Image,
    s: &RenderSettings,
    opts: &DfdOptions,
    level: usize,
    step: &mut impl FnMut(Step),
) -> Result<Image> {
    let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
    let n = d.data.len();
    let (mut m, mut v) = (vec![0f64; n], vec![0f64; n]);
    let alpha = Image::filled(aif.width, aif.height, 1, 1.0);
    let wts = opts.weights;
    let gauss_radius = window_radius(s.blur, s.focus);
    for it in 0..opts.iters {
        let layers;
        let tape = match opts.renderer {
            DfdRenderer::DrBokeh => {
                layers = [Layer::from_parts(aif, &alpha, &d, "dfd")?];
                match opts.kernel {
                    DfdKernel::Fast | DfdKernel::Auto => Recording::Span(SpanTape::record(&layers[0], s, opts.smoothing)?),
                    k => Recording::DrBokeh(Tape::record_with(&layers, s, opts.smoothing, k == DfdKernel::Ray)?),
                }
            }
            DfdRenderer::GaussPsf => Recording::Gauss(GaussTape::record(aif, &d, s.focus, s.blur, gauss_radius)?),
        };
        let l1 = loss::l1(tape.image(), target);
        let hs = loss::hssim(tape.image(), target, wts.windows);
        let sm = loss::gradient_smoothness(&d);
        let mut seed = l1.grad.clone();
        seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, hg)| *g = *g * wts.l1 + hg * wts.ssim);
        let g = tape.disparity_grad(&seed)?;
        let total = wts.l1 as f64 * l1.value + wts.ssim as f64 * hs.value + wts.smoothness as f64 * sm.value;
        step(Step { level, iter: it, loss: total, l1: l1.value, smoothness: sm.value, ssim: hs.value });
        let t = (it + 1) as i32;
        for (i, dv) in d.data.iter_mut().enumerate() {
            let gi = g[i] as f64 + wts.smoothness as f64 * sm.grad.data[i] as f64;
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
        let s = RenderSettings { blur: 4.0, focus: 1.0, lens: 0, occlusion: true, profile: Profile::Physical };
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

    /// `Auto` takes the ray test where it applies, at the finest level that fits the budget
    /// (full size where it can), the span render where the test does not apply; an explicit
    /// kernel runs at full size; the ray test with the official profile is a usage error naming
    /// the kernel. A reduced plan's map comes back at the photo's size.
    #[test]
    fn auto_plan_and_ray_checks() {
        let s = RenderSettings { blur: 6.4, focus: 1.0, lens: 0, occlusion: true, profile: Profile::Physical };
        let o = DfdOptions::default();
        let p = |w, h, s: &RenderSettings, o: &DfdOptions| {
            let p = plan(w, h, s, o);
            (p.kernel, p.finest_level, p.width, p.height)
        };
        assert_eq!(p(64, 64, &s, &o), (DfdKernel::Ray, 0, 64, 64));
        assert_eq!(p(128, 128, &RenderSettings { blur: 15.0, ..s }, &o), (DfdKernel::Ray, 0, 128, 128));
        assert_eq!(p(256, 256, &RenderSettings { blur: 30.0, ..s }, &o), (DfdKernel::Ray, 1, 128, 128));
        let big = plan(4000, 3000, &RenderSettings { blur: 400.0, ..s }, &o);
        assert_eq!(big.kernel, DfdKernel::Ray);
        assert!(big.width.min(big.height) >= AUTO_MIN_SIDE && big.width < 300, "{big:?}");
        assert_eq!(p(64, 64, &RenderSettings { occlusion: false, ..s }, &o), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(64, 64, &RenderSettings { profile: Profile::Official, ..s }, &o), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(64, 64, &s, &DfdOptions { renderer: DfdRenderer::GaussPsf, ..o }), (DfdKernel::Fast, 0, 64, 64));
        assert_eq!(p(4000, 3000, &s, &DfdOptions { kernel: DfdKernel::Exact, ..o }), (DfdKernel::Exact, 0, 4000, 3000));
        // Nothing fits: a window as wide as the image at every level down to 16 px.
        assert_eq!(p(40, 40, &RenderSettings { blur: 1e6, ..s }, &DfdOptions { iters: 10_000_000, ..o }), (DfdKernel::Fast, 0, 40, 40));
        // A reduced plan: optimised at 32×24, returned at 64×48.
        let aif = Image::from_vec(64, 48, 3, (0..64 * 48 * 3).map(|v| (v % 11) as f32 / 11.0).collect()).unwrap();
        // K 8: 2 steps of levels 0 + 1 cost 2·(3072·π/4·23² + 768·π/4·15²) = 2.8e6 taps, of
        // levels 1 + 2 3.1e5.
        let ro = DfdOptions { iters: 2, levels: 2, ray_budget: 1e6, ..o };
        let pl = plan(64, 48, &RenderSettings { blur: 8.0, ..s }, &ro);
        assert_eq!((pl.kernel, pl.finest_level, pl.width, pl.height), (DfdKernel::Ray, 1, 32, 24), "{pl:?}");
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
            let s = RenderSettings { blur, focus: 1.0, lens: 0, occlusion: true, profile: Profile::Physical };
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
        let s = RenderSettings { blur: 4.0, focus: 1.0, lens: 0, occlusion: true, profile: Profile::Physical };
        let bokeh = GaussTape::record(&aif, &truth, 1.0, 4.0, window_radius(4.0, 1.0)).unwrap().image().clone();
        let opts = DfdOptions { iters: 30, levels: 2, renderer: DfdRenderer::GaussPsf, ..DfdOptions::default() };
        let d = estimate(&aif, &bokeh, &s, &opts, |_| {}).unwrap();
        let err = |d: &Image| d.data.iter().zip(&truth.data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / (w * h) as f64;
        let start = err(&Image::filled(w, h, 1, opts.init));
        eprintln!("gauss-psf: disparity error {:.4} (start {start:.4})", err(&d));
        assert!(err(&d) < start / 3.0, "disparity error {} (start {start})", err(&d));
    }
}
