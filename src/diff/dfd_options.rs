//! What a depth-from-defocus run is asked to do ([`DfdOptions`]): the loss and its weights,
//! the renderer inverted and the kernel differentiated, the time budget `auto` plans for. The
//! planner ([`super::dfd_plan`]) and the optimisation ([`super::dfd`]) read them.

use super::loss::HSSIM_WINDOWS;
use crate::render::Smoothing;

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

/// The objectives of the paper's loss ablation (Table 2), by their command-line names (also
/// their serialized ones, both ways: the Python binding parses them).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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

/// The differentiable renderer that [`super::dfd::estimate`] inverts.
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

/// Which differentiable Dr.Bokeh render [`super::dfd::estimate`] inverts (with [`DfdRenderer::DrBokeh`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum DfdKernel {
    /// [`DfdKernel::Ray`] where it applies (physical profile, occlusion on) and its estimated
    /// cost over all levels stays within [`DfdOptions::cpu_budget`] at some level;
    /// [`DfdKernel::Fast`] otherwise (see [`super::dfd_plan::plan`]).
    #[default]
    Auto,
    /// [`crate::render::SpanTape`]: spans instead of taps, the in-layer depth groups interpolated between
    /// depth bins (disparity gradients within 0.3% (physical) and 3.5% (official) of the exact
    /// tape's in relative L2 on the scenes of `tests/span_tape.rs`; README "Depth from
    /// defocus").
    Fast,
    /// [`crate::render::Tape`]: the exact kernel, O(pixels·lens²) per step.
    Exact,
    /// [`crate::render::Tape::record_with`] with the ray test: the exact kernel, where a source behind a
    /// target counts only as far as the ray between them passes the photo's surface (the
    /// physical profile only). The visibility of one opaque 2.5D surface, which the
    /// statistical fill of the other two only approximates. O(pixels·lens²) per step, about
    /// 1.7x the exact tape.
    Ray,
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

/// Options of [`super::dfd::estimate`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DfdOptions {
    /// Adam steps per resolution level, 1..=[`super::dfd_plan::MAX_ITERS`] ([`super::dfd_plan::check_iters`]).
    pub iters: usize,
    /// Resolution levels, coarsest first (each half the size of the next), ending at the plan's
    /// finest level ([`super::dfd_plan::plan`]: full size unless `auto` chose a smaller one); 1 = that level only.
    /// More than the photo and the blur allow are capped ([`super::dfd_plan::useful_levels`]),
    /// with a warning.
    pub levels: usize,
    /// Adam's step size, in units of normalized disparity.
    pub learning_rate: f32,
    /// The loss weights.
    pub weights: LossWeights,
    /// The physical profile's smooth edges (see [`Smoothing`]).
    #[serde(skip)]
    pub smoothing: Smoothing,
    /// The disparity every pixel starts from, in [0, 1]; one in the dead band of the first
    /// level (within half a pixel of blur of the focal plane, where the map cannot move) is
    /// replaced, with a warning ([`super::dfd_start::movable_start`]).
    pub init: f32,
    /// The renderer inverted.
    pub renderer: DfdRenderer,
    /// The Dr.Bokeh render differentiated (see [`DfdKernel`]).
    pub kernel: DfdKernel,
    /// The estimated CPU seconds [`DfdKernel::Auto`] plans a run for ([`super::dfd_plan::plan`]; default
    /// [`AUTO_CPU_BUDGET`]).
    pub cpu_budget: f64,
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
            cpu_budget: AUTO_CPU_BUDGET,
        }
    }
}

/// The CPU seconds (this project's 2-core machine, see the module notes) that
/// [`DfdKernel::Auto`] plans for: in the worst case of the cost model about 30 s of wall time
/// on 2 idle cores, and under a minute with one of them busy elsewhere, so that no default run
/// on a photo up to 256×256 passes a minute there. Scenes near the worst case (a far
/// background at disparity 0, focus 1, K 8 and 16 at 128 and 256 px) planned at 73 CPU
/// seconds (a budget of 80) took 62: 61-65 s of wall time while another build shared the
/// machine. A level coarser costs about 16 times less (a quarter of the pixels, a quarter of
/// the window's taps) and loses detail: 256×256 at K 16 (two planes) has a mean disparity
/// error of 0.015 optimised at 128×128 (28 CPU seconds), 0.036 at 64×64 (2.7), the plan under
/// this budget.
pub const AUTO_CPU_BUDGET: f64 = 60.0;
