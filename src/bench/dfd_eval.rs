//! `drbokeh bench --dfd`: depth from defocus evaluated with the structure of the paper's
//! Table 2 (report: [`super::dfd_report`]).
//!
//! Each case is one all-in-focus photo with its true disparity, a **target** (the thin-lens
//! truth focused on the nearest plane, so every relative disparity has one sign) and a second
//! thin-lens truth at the **other** focus (the farthest plane) for the re-render check.
//! Generated cases come from [`super::scenes::generate`] (radiance clipped to [0, 1]) traced
//! by [`super::trace`] at a blur K of our choosing; ground-truth cases are the shared Mitsuba scenes, box-downsampled (see
//! [`DfdBenchOptions::groundtruth`]).
//!
//! Every method ([`DfdMethod`]) estimates the disparity with [`dfd::estimate_stack`] from the photo
//! and the target, and is scored on
//! - the disparity's mean absolute error (normalized disparity) over the frame less a border
//!   of `ceil(K)` px (the lens sees off-frame content there that the photo lacks), and over
//!   the textured pixels only ([`textured`]);
//! - the re-render at the other focus, vs the traced truth there: [`rerender`] (what
//!   `drbokeh render --layer` does with the photo as one opaque layer and the estimate),
//!   scored by [`super::run::score`] with the same border;
//! - its wall time.
//!
//! Two reference rows: the true disparity (the best a one-layer re-render can do) and the
//! optimiser's start (a constant map at [`DfdOptions::init`]).
//!
//! Each case runs once per input ([`DfdBenchOptions::inputs`], `bench --dfd --inputs`): the
//! linear views as they are, or both photos (all-in-focus and target) as an 8-bit camera
//! stores them ([`inputs::photo`]: clipped at white, quantized, a PSF first for
//! `srgb8-psf`). The estimate and every re-render (the references' too) start from the photo
//! of that input, against the same linear truths: what a user with those files gets. As
//! `drbokeh dfd` does with integer photos, the 8-bit inputs' estimates start from the
//! all-in-focus photo with its clipped lights recovered and checked against the target's light
//! ([`dfd::aif_light`]) and take the
//! target's clipped samples as lower bounds ([`dfd::clip_level`]); the re-renders use the
//! photo as stored (the same for every row, so the rows compare the maps alone).

use super::depth_metrics::{DepthErrors, depth_errors};
use super::groundtruth::GtScene;
use super::inputs::{self, Input};
use super::metrics::luminance;
use super::metrics::srgb;
use super::run::{Scores, score};
use super::scenes::generate;
use super::trace::{TraceSettings, trace};
use crate::config::Config;
use crate::diff::dfd::{self, DfdKernel, DfdOptions, DfdRenderer, LossVariant};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::pipeline::{Focus, Pipeline};
use crate::render::{Layer, Profile, RenderSettings};
use crate::timing::ms_since;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A depth-from-defocus method of the evaluation: a renderer, profile, occlusion and loss.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum DfdMethod {
    /// Dr.Bokeh, physical profile, L1 + gradient + HSSIM (the tool's defaults, Eqn. 7; the
    /// automatic kernel: the ray test at the bench's sizes).
    Physical,
    /// The same with the span render (`--kernel fast`): the layered model without the ray test.
    PhysicalSpan,
    /// Dr.Bokeh, official profile, L1 + gradient + HSSIM.
    Official,
    /// Dr.Bokeh without occlusion (physical profile, HSSIM loss): the paper's ablation.
    NoOcclusion,
    /// The Gaussian-PSF renderer ([`crate::diff::gauss_psf`]), HSSIM loss.
    GaussPsf,
    /// Dr.Bokeh, physical profile, L1 + gradient only.
    L1Grad,
    /// Dr.Bokeh, physical profile, L1 + gradient + SSIM (one 11×11 window).
    L1GradSsim,
}

impl DfdMethod {
    /// Every method, in report order.
    pub const ALL: [DfdMethod; 7] = [
        DfdMethod::Physical,
        DfdMethod::PhysicalSpan,
        DfdMethod::Official,
        DfdMethod::NoOcclusion,
        DfdMethod::GaussPsf,
        DfdMethod::L1Grad,
        DfdMethod::L1GradSsim,
    ];

    /// The name in report.csv and report.md.
    pub fn name(self) -> &'static str {
        match self {
            DfdMethod::Physical => "drbokeh-physical",
            DfdMethod::PhysicalSpan => "drbokeh-physical-span",
            DfdMethod::Official => "drbokeh-official",
            DfdMethod::NoOcclusion => "drbokeh-no-occlusion",
            DfdMethod::GaussPsf => "gauss-psf",
            DfdMethod::L1Grad => "drbokeh-l1-grad",
            DfdMethod::L1GradSsim => "drbokeh-l1-grad-ssim",
        }
    }

    /// The method named `name` in report.csv ([`DfdMethod::name`]); None for another name.
    pub fn parse(name: &str) -> Option<DfdMethod> {
        DfdMethod::ALL.into_iter().find(|m| m.name() == name)
    }

    /// What the method is, for the report.
    pub fn label(self) -> &'static str {
        match self {
            DfdMethod::Physical => "Dr.Bokeh, physical profile, L1 + grad + HSSIM (default: ray test)",
            DfdMethod::PhysicalSpan => "Dr.Bokeh, physical profile, span render without the ray test",
            DfdMethod::Official => "Dr.Bokeh, official profile, L1 + grad + HSSIM",
            DfdMethod::NoOcclusion => "Dr.Bokeh without occlusion (physical), L1 + grad + HSSIM",
            DfdMethod::GaussPsf => "Gaussian PSF (GaussPSF-style), L1 + grad + HSSIM",
            DfdMethod::L1Grad => "Dr.Bokeh, physical, loss L1 + grad",
            DfdMethod::L1GradSsim => "Dr.Bokeh, physical, loss L1 + grad + SSIM",
        }
    }

    /// The short label of figure panels (at most 16 characters).
    pub fn short(self) -> &'static str {
        match self {
            DfdMethod::Physical => "Dr.Bokeh",
            DfdMethod::PhysicalSpan => "no ray test",
            DfdMethod::Official => "official",
            DfdMethod::NoOcclusion => "no occlusion",
            DfdMethod::GaussPsf => "Gaussian PSF",
            DfdMethod::L1Grad => "L1+grad",
            DfdMethod::L1GradSsim => "L1+grad+SSIM",
        }
    }

    /// The differentiable render the method asks for: the span render for
    /// [`DfdMethod::PhysicalSpan`], the automatic choice ([`DfdKernel::Auto`]) for the others.
    pub fn kernel(self) -> DfdKernel {
        if self == DfdMethod::PhysicalSpan { DfdKernel::Fast } else { DfdKernel::Auto }
    }

    /// The render settings (at `blur`, `focus`), loss and renderer that the method inverts.
    pub fn setup(self, blur: f32, focus: f32) -> (RenderSettings, LossVariant, DfdRenderer) {
        let s =
            RenderSettings { blur, focus, lens: 0, occlusion: true, profile: Profile::Physical, aperture: crate::render::Aperture::DISC };
        match self {
            DfdMethod::Physical | DfdMethod::PhysicalSpan => (s, LossVariant::L1GradHssim, DfdRenderer::DrBokeh),
            DfdMethod::Official => (RenderSettings { profile: Profile::Official, ..s }, LossVariant::L1GradHssim, DfdRenderer::DrBokeh),
            DfdMethod::NoOcclusion => (RenderSettings { occlusion: false, ..s }, LossVariant::L1GradHssim, DfdRenderer::DrBokeh),
            DfdMethod::GaussPsf => (s, LossVariant::L1GradHssim, DfdRenderer::GaussPsf),
            DfdMethod::L1Grad => (s, LossVariant::L1Grad, DfdRenderer::DrBokeh),
            DfdMethod::L1GradSsim => (s, LossVariant::L1GradSsim, DfdRenderer::DrBokeh),
        }
    }
}

/// What a report row holds: an estimate, or one of the two reference disparities.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum RowKind {
    /// A method's estimate.
    Estimate(DfdMethod),
    /// The true disparity (re-render reference).
    TrueDisparity,
    /// The optimiser's start, a constant map.
    Init,
}

impl RowKind {
    /// The name in report.csv and report.md.
    pub fn name(self) -> &'static str {
        match self {
            RowKind::Estimate(m) => m.name(),
            RowKind::TrueDisparity => "true-disparity",
            RowKind::Init => "init",
        }
    }

    /// What the row is, for the report.
    pub fn label(self) -> &'static str {
        match self {
            RowKind::Estimate(m) => m.label(),
            RowKind::TrueDisparity => "reference: the true disparity",
            RowKind::Init => "reference: the optimiser's constant start",
        }
    }
}

/// Where a case comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum CaseSource {
    /// A generated scene traced here.
    Generated,
    /// A shared ground-truth (Mitsuba) scene.
    GroundTruth,
}

impl CaseSource {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            CaseSource::Generated => "generated",
            CaseSource::GroundTruth => "mitsuba",
        }
    }
}

/// Options of [`run`] (`drbokeh bench --dfd`'s flags).
#[derive(Clone, Debug)]
pub struct DfdBenchOptions {
    /// Generated scenes (0 with `groundtruth` for the shared scenes only).
    pub scenes: usize,
    /// Frame width of the generated scenes, pixels (>= 16); the ground-truth scenes are
    /// box-downsampled by the integer factor that brings their width nearest to it.
    pub width: usize,
    /// Frame height of the generated scenes, pixels (>= 16).
    pub height: usize,
    /// Blur strength K of the generated scenes, pixels of CoC radius per unit of disparity
    /// (None: [`default_blur`]). The ground-truth scenes keep theirs (divided by the factor).
    pub blur: Option<f32>,
    /// Seed of the scene generator and the tracer.
    pub seed: u64,
    /// A folder of scenes in the shared ground-truth format, evaluated after the generated
    /// ones: target = the setting focused nearest (largest focus), re-render at the farthest.
    pub groundtruth: Option<PathBuf>,
    /// Rays per pixel of the traced truths.
    pub spp: u32,
    /// Adam steps per level and levels of every estimate (the rest: [`DfdOptions::default`]).
    pub iters: usize,
    /// Resolution levels of every estimate.
    pub levels: usize,
    /// The methods, at least one.
    pub methods: Vec<DfdMethod>,
    /// What the methods are fed, each a run of every case (at least one; the figures and the
    /// per-case table show [`inputs::primary_input`]).
    pub inputs: Vec<Input>,
    /// The report folder (created).
    pub out: PathBuf,
    /// The command line, for the report.
    pub command: String,
}

impl Default for DfdBenchOptions {
    fn default() -> Self {
        DfdBenchOptions {
            scenes: 8,
            width: 64,
            height: 64,
            blur: None,
            seed: 1,
            groundtruth: None,
            spp: 256,
            iters: 100,
            levels: 3,
            methods: DfdMethod::ALL.to_vec(),
            inputs: vec![Input::Linear],
            out: PathBuf::from("dfd-report"),
            command: String::new(),
        }
    }
}

/// K of the generated scenes when not given: a tenth of the smaller side (6.4 at 64×64), a
/// CoC radius of that many pixels on the farthest plane when the nearest is in focus.
pub fn default_blur(width: usize, height: usize) -> f32 {
    width.min(height) as f32 / 10.0
}

/// Side of the window over which [`textured`] averages the gradient magnitude, pixels.
pub const TEXTURE_WINDOW: usize = 5;
/// A pixel is textured when the mean over the [`TEXTURE_WINDOW`]² window of the gradient
/// magnitude (central differences, per pixel) of the photo's sRGB-encoded luminance (clipped
/// to [0, 1]) is at least this.
pub const TEXTURE_THRESHOLD: f32 = 0.02;

/// One evaluated case.
pub struct DfdCase {
    /// The scene's name.
    pub scene: String,
    /// Where it comes from.
    pub source: CaseSource,
    /// The all-in-focus photo, linear RGB.
    pub aif: Image,
    /// The true normalized disparity (one channel).
    pub truth: Image,
    /// The thin-lens truth at `focus` (what every method inverts), linear RGB.
    pub target: Image,
    /// The thin-lens truth at `other_focus` (the re-render check), linear RGB.
    pub other: Image,
    /// Blur strength K, pixels per unit of disparity.
    pub blur: f32,
    /// Focus of the target: the nearest plane.
    pub focus: f32,
    /// Focus of the re-render check: the farthest plane.
    pub other_focus: f32,
    /// Pixels left out at each border when scoring: `ceil(K)`.
    pub border: usize,
    /// Textured pixels ([`textured`]).
    pub textured: Vec<bool>,
    /// The depths disparity 1 and 0 stand for (`z_min`, `z_max`), when the scene states them
    /// (the shared scenes; the generated ones have disparities only).
    pub z_range: Option<(f64, f64)>,
}

/// One row of report.csv: a case × (method or reference).
#[derive(Clone, Debug)]
pub struct DfdRow {
    /// The scene's name.
    pub scene: String,
    /// Where the case comes from.
    pub source: CaseSource,
    /// What the methods were fed.
    pub input: Input,
    /// The method or reference.
    pub kind: RowKind,
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Blur strength K.
    pub blur: f32,
    /// Focus of the target.
    pub focus: f32,
    /// Focus of the re-render.
    pub other_focus: f32,
    /// Pixels left out at each border.
    pub border: usize,
    /// Fraction of the scored pixels that are textured.
    pub textured_fraction: f64,
    /// Mean |estimate − truth| over the scored pixels (normalized disparity).
    pub mae: f64,
    /// The same over the textured scored pixels (NaN when there are none).
    pub mae_textured: f64,
    /// The re-render at `other_focus` against the traced truth there.
    pub rerender: Scores,
    /// AbsRel, RMSE and δ < 1.25 on depth and inverse depth (cases with a depth range).
    pub depth: Option<DepthErrors>,
    /// Wall time of the estimate, ms (0 for the references).
    pub time_ms: f64,
}

/// Everything a run produced.
pub struct DfdBenchResult {
    /// One row per case × method and reference.
    pub rows: Vec<DfdRow>,
    /// Cases evaluated.
    pub cases: usize,
    /// Per case: (scene, panels of its figure), written as `figures/SCENE.png`.
    pub figures: Vec<(String, Panels)>,
}

/// The textured pixels of a photo (see [`TEXTURE_THRESHOLD`]). O(pixels·window²).
pub fn textured(aif: &Image) -> Vec<bool> {
    let lum = luminance(&srgb(aif));
    let (w, h) = (lum.width, lum.height);
    let at = |x: usize, y: usize| lum.data[y * w + x];
    let mut grad = vec![0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let (x0, x1, y0, y1) = (x.saturating_sub(1), (x + 1).min(w - 1), y.saturating_sub(1), (y + 1).min(h - 1));
            let gx = (at(x1, y) - at(x0, y)) / (x1 - x0).max(1) as f32;
            let gy = (at(x, y1) - at(x, y0)) / (y1 - y0).max(1) as f32;
            grad[y * w + x] = (gx * gx + gy * gy).sqrt();
        }
    }
    let r = TEXTURE_WINDOW / 2;
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let (mut s, mut n) = (0f32, 0usize);
            for yy in y.saturating_sub(r)..=(y + r).min(h - 1) {
                for xx in x.saturating_sub(r)..=(x + r).min(w - 1) {
                    s += grad[yy * w + xx];
                    n += 1;
                }
            }
            s / n as f32 >= TEXTURE_THRESHOLD
        })
        .collect()
}

/// The re-render of a disparity map at `focus`: what `drbokeh render --layer` does with the
/// photo as one opaque layer over `disparity` at blur `blur` (the tool's default settings:
/// physical profile, automatic kernel choice and lens window). Linear RGB.
pub fn rerender(aif: &Image, disparity: &Image, blur: f32, focus: f32) -> Result<Image> {
    let mut cfg = Config::default();
    cfg.render.blur = Some(blur);
    let layer = Layer::from_parts(aif, &Image::filled(aif.width, aif.height, 1, 1.0), disparity, "all-in-focus layer")?;
    Ok(Pipeline::from_config(cfg)?.render_layers(vec![layer], Focus::Disparity(focus))?.image)
}

/// Mean |a − b| over the pixels of a one-channel pair at least `border` from every side
/// where `keep` holds; NaN when there are none.
pub fn mae(a: &Image, b: &Image, border: usize, keep: impl Fn(usize) -> bool) -> f64 {
    let (w, h) = (a.width, a.height);
    let (mut s, mut n) = (0f64, 0usize);
    for y in border..h.saturating_sub(border) {
        for x in border..w.saturating_sub(border) {
            let i = y * w + x;
            if keep(i) {
                s += (a.data[i] - b.data[i]).abs() as f64;
                n += 1;
            }
        }
    }
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// Generated case `index`: the scene of [`generate`] (procedural textures) at `blur`, its
/// radiance clipped to [0, 1] (the HDR highlights become white discs: a display-referred
/// photo pair, as the paper's; unclipped, the linear L1 of the loss is dominated by the
/// highlights' bokeh), traced at its nearest and farthest plane.
fn generated_case(opts: &DfdBenchOptions, index: usize) -> Result<DfdCase> {
    let mut sc = generate(opts.seed, index, opts.width, opts.height, &[]);
    for p in &mut sc.planes {
        p.rgb.map_inplace(|v| v.min(1.0));
    }
    let blur = opts.blur.unwrap_or_else(|| default_blur(opts.width, opts.height));
    let inputs = sc.inputs()?;
    let truth = inputs.disparity;
    let (near, far) = truth.data.iter().fold((f32::NEG_INFINITY, f32::INFINITY), |(hi, lo), &d| (hi.max(d), lo.min(d)));
    let planes = sc.trace_planes();
    let seed = opts.seed ^ (index as u64) << 20;
    let target = trace(&planes, &TraceSettings::new(blur, near, opts.spp, seed), sc.window(), &|_| {})?;
    let other = trace(&planes, &TraceSettings::new(blur, far, opts.spp, seed ^ 0x5151), sc.window(), &|_| {})?;
    Ok(DfdCase {
        scene: sc.name,
        source: CaseSource::Generated,
        textured: textured(&inputs.aif),
        aif: inputs.aif,
        truth,
        target,
        other,
        blur,
        focus: near,
        other_focus: far,
        border: blur.ceil() as usize,
        z_range: None,
    })
}

/// Box-average of `f × f` blocks (the frame cropped to a multiple of `f`).
pub fn box_down(img: &Image, f: usize) -> Image {
    let (w, h, c) = (img.width / f, img.height / f, img.channels);
    let mut o = Image::new(w, h, c);
    for y in 0..h {
        for x in 0..w {
            for k in 0..c {
                let mut s = 0f64;
                for yy in y * f..(y + 1) * f {
                    for xx in x * f..(x + 1) * f {
                        s += img.data[(yy * img.width + xx) * c + k] as f64;
                    }
                }
                o.data[(y * w + x) * c + k] = (s / (f * f) as f64) as f32;
            }
        }
    }
    o
}

/// A shared ground-truth scene as a case: target = its setting with the largest focus (the
/// nearest plane), re-render at the smallest. Downsampled by `factor` (box filter: the
/// thin-lens image of the downsampled scene is the downsampled thin-lens image, with K/factor;
/// the true disparity is block-averaged, so depth-edge pixels get intermediate labels).
fn groundtruth_case(dir: &Path, width: usize) -> Result<DfdCase> {
    let sc = GtScene::load(dir)?;
    let by_focus = |a: &&super::groundtruth::GtSetting, b: &&super::groundtruth::GtSetting| a.focus.total_cmp(&b.focus);
    let (Some(near), Some(far)) = (sc.settings.iter().max_by(by_focus), sc.settings.iter().min_by(by_focus)) else {
        return Err(Error::input(dir, "the scene has no focus setting"));
    };
    if near.focus <= far.focus {
        return Err(Error::input(dir, "the scene needs two settings at different foci"));
    }
    let factor = ((sc.aif.width as f64 / width as f64).round() as usize).max(1);
    let blur = near.blur / factor as f32;
    let aif = box_down(&sc.aif, factor);
    Ok(DfdCase {
        scene: sc.name.clone(),
        source: CaseSource::GroundTruth,
        textured: textured(&aif),
        truth: box_down(&sc.disparity, factor),
        target: box_down(&near.gt, factor),
        other: box_down(&far.gt, factor),
        aif,
        blur,
        focus: near.focus,
        other_focus: far.focus,
        border: blur.ceil() as usize,
        z_range: Some(sc.z_range),
    })
}

/// Scores one disparity map on a case (re-render included, from `aif`: the all-in-focus photo
/// `input` delivers).
fn score_map(case: &DfdCase, input: Input, aif: &Image, kind: RowKind, d: &Image, time_ms: f64) -> Result<DfdRow> {
    let img = rerender(aif, d, case.blur, case.other_focus)?;
    if !img.all_finite() {
        return Err(Error::Internal(format!("the re-render of {} on {} is not finite", kind.name(), case.scene)));
    }
    let (w, h, b) = (case.aif.width, case.aif.height, case.border);
    let scored = (h.saturating_sub(2 * b) * w.saturating_sub(2 * b)).max(1);
    let tex = (b..h.saturating_sub(b)).flat_map(|y| (b..w.saturating_sub(b)).map(move |x| y * w + x)).filter(|&i| case.textured[i]).count();
    Ok(DfdRow {
        scene: case.scene.clone(),
        source: case.source,
        input,
        kind,
        width: w,
        height: h,
        blur: case.blur,
        focus: case.focus,
        other_focus: case.other_focus,
        border: b,
        textured_fraction: tex as f64 / scored as f64,
        mae: mae(d, &case.truth, b, |_| true),
        mae_textured: mae(d, &case.truth, b, |i| case.textured[i]),
        rerender: score(&img, &case.other, b),
        depth: case.z_range.and_then(|z| depth_errors(d, &case.truth, z, b)),
        time_ms,
    })
}

/// A disparity map as a figure panel (grey, 0 black … 1 white, encoded so that the sRGB
/// panel shows the value itself).
fn disparity_panel(d: &Image) -> Image {
    let v: Vec<f32> = d.data.iter().flat_map(|&v| [crate::color::srgb_to_linear(v.clamp(0.0, 1.0)); 3]).collect();
    Image::from_vec(d.width, d.height, 3, v).expect("size")
}

/// Labelled figure panels (linear RGB).
type Panels = Vec<(String, Image)>;

/// Runs every method on one case fed as `input`: its rows and its figure's panels.
fn evaluate(case: &DfdCase, input: Input, opts: &DfdBenchOptions, log: &mut dyn FnMut(&str)) -> Result<(Vec<DfdRow>, Panels)> {
    let base = DfdOptions { iters: opts.iters, levels: opts.levels, ..DfdOptions::default() };
    let (aif, target) = (inputs::photo(&case.aif, input).0, inputs::photo(&case.target, input).0);
    let mut rows = vec![
        score_map(case, input, &aif, RowKind::TrueDisparity, &case.truth, 0.0)?,
        score_map(case, input, &aif, RowKind::Init, &Image::filled(case.aif.width, case.aif.height, 1, base.init), 0.0)?,
    ];
    // 8-bit inputs are integer photos: dfd recovers the all-in-focus photo's lights and takes
    // the target's clipped samples as "at least this much", as `drbokeh dfd` does.
    let encoding = input.encoding();
    let clip = dfd::clip_level(encoding);
    let light = dfd::aif_light(&aif, encoding, &[dfd::Shot { photo: &target, focus: case.focus, clip }], case.blur)?;
    let mut panels = vec![("AIF".to_string(), Image::clone(&aif)), (format!("target f={:.2}", case.focus), Image::clone(&target))];
    for &m in &opts.methods {
        let (s, loss, renderer) = m.setup(case.blur, case.focus);
        let o = DfdOptions { weights: loss.weights(), renderer, kernel: m.kernel(), ..base };
        let t = Instant::now();
        let d = dfd::estimate_stack(&light, &[dfd::Shot { photo: &target, focus: s.focus, clip }], &s, &o, |_| {})?.disparity;
        let ms = ms_since(t);
        let row = score_map(case, input, &aif, RowKind::Estimate(m), &d, ms)?;
        log(&format!(
            "{} {} ({}): disparity MAE {:.4}, re-render PSNR sRGB {:.2} dB, {:.1} s",
            case.scene,
            m.name(),
            input.name(),
            row.mae,
            row.rerender.psnr_srgb,
            ms / 1e3
        ));
        rows.push(row);
        if matches!(m, DfdMethod::Physical | DfdMethod::PhysicalSpan | DfdMethod::NoOcclusion | DfdMethod::GaussPsf) {
            panels.push((m.short().to_string(), disparity_panel(&d)));
        }
    }
    panels.push(("true disparity".to_string(), disparity_panel(&case.truth)));
    Ok((rows, panels))
}

/// Case `index` of a bench: the generated scenes first (`opts.scenes` of them), then the
/// ground-truth folders `dirs` ([`super::groundtruth::scene_dirs`] of `opts.groundtruth`).
pub fn load_case(opts: &DfdBenchOptions, dirs: &[PathBuf], index: usize, log: &mut dyn FnMut(&str)) -> Result<DfdCase> {
    if index < opts.scenes {
        log(&format!("scene {index}: generating and tracing ({} spp)", opts.spp));
        generated_case(opts, index)
    } else {
        let dir = dirs.get(index - opts.scenes).ok_or_else(|| Error::usage(format!("bench: no case {index}")))?;
        log(&format!("loading {}", dir.display()));
        groundtruth_case(dir, opts.width)
    }
}

/// Runs the evaluation: its rows and figure panels (written by
/// [`super::dfd_report::write_all`]). `log` receives a line per case and per estimate.
pub fn run(opts: &DfdBenchOptions, log: &mut dyn FnMut(&str)) -> Result<DfdBenchResult> {
    if opts.scenes > 0 && (opts.width < 16 || opts.height < 16) {
        return Err(Error::usage(format!("bench.size must be at least 16x16, got {}x{}", opts.width, opts.height)));
    }
    if opts.methods.is_empty() {
        return Err(Error::usage("bench.methods: no method selected"));
    }
    if opts.inputs.is_empty() {
        return Err(Error::usage("bench.inputs: no input selected"));
    }
    if opts.scenes == 0 && opts.groundtruth.is_none() {
        return Err(Error::usage("bench.scenes must be at least 1 (or give ground-truth scenes)"));
    }
    if let Some(k) = opts.blur {
        crate::render::check_blur("bench.blur", k)?;
    }
    let dirs = match &opts.groundtruth {
        Some(d) => super::groundtruth::scene_dirs(d)?,
        None => Vec::new(),
    };
    let mut res = DfdBenchResult { rows: Vec::new(), cases: 0, figures: Vec::new() };
    for i in 0..opts.scenes + dirs.len() {
        let case = load_case(opts, &dirs, i, log)?;
        for &input in &opts.inputs {
            let (rows, panels) = evaluate(&case, input, opts, log)?;
            res.rows.extend(rows);
            if input == inputs::primary_input(&opts.inputs) {
                res.figures.push((case.scene.clone(), panels));
            }
        }
        res.cases += 1;
    }
    Ok(res)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The texture mask: a flat photo has no textured pixel, a noise photo is all textured.
    #[test]
    fn texture_mask_separates_flat_from_noise() {
        assert!(textured(&Image::filled(20, 20, 3, 0.3)).iter().all(|&t| !t));
        let mut seed = 1u64;
        let noise: Vec<f32> = (0..20 * 20 * 3)
            .map(|_| {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                (seed >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect();
        assert!(textured(&Image::from_vec(20, 20, 3, noise).unwrap()).iter().all(|&t| t));
    }

    /// Box downsampling averages blocks and crops the remainder.
    #[test]
    fn box_down_averages_blocks() {
        let img = Image::from_vec(5, 2, 1, vec![0.0, 1.0, 2.0, 3.0, 9.0, 4.0, 5.0, 6.0, 7.0, 9.0]).unwrap();
        let d = box_down(&img, 2);
        assert_eq!((d.width, d.height), (2, 1));
        assert_eq!(d.data, vec![2.5, 4.5]);
    }
}
