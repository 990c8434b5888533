//! `drbokeh bench`: generate (or load) layered scenes, trace their ground truth, render every
//! method and setting from the same inputs, score them and write the report.
//!
//! Methods (see [`Method`]): Dr.Bokeh on the exact two layers, on one exact layer per depth
//! ("depth-sliced"), and from the realistic pipeline (layers estimated by the classical stages
//! from the all-in-focus image, disparity and matte); the classical scatter without occlusion
//! (one layer, the `--no-occlusion` baseline); and the gathering baseline ([`super::gather`]).
//! Renderer methods run with the exact kernel and the fast kernel's quality levels.
//!
//! Every method runs once per [`Input`] asked for (`--inputs`, [`super::inputs`]): the linear
//! HDR all-in-focus view (every setting), and the 8-bit sRGB photo without and with a camera
//! PSF (the reference and default settings, the realistic-depth ones and the pipeline with its
//! highlights stage off; issue 35).
//!
//! Scores are computed with a border of the largest CoC radius left out (inputs lack the
//! off-frame content the lens sees there), in linear light and on sRGB-encoded output clipped
//! to [0, 1]; see [`Scores`].

use super::gather::gather;
use super::groundtruth::GtScene;
use super::inputs::{self, Input, Prepared};
use super::metrics::{psnr, rmse, si_rmse, srgb, ssim, zncc};
use super::scenes::{FocusKind, SceneInputs, generate, gt_plane_layers};
use super::trace::{Plane, TraceSettings, trace_split};
use crate::color::Transfer;
use crate::config::{Config, KernelChoice};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::io::{ReadLimits, read_photo};
use crate::pipeline::{Focus, Pipeline, Scene};
use crate::render::{self, Kernel, Layer, RenderSettings};
use crate::stages::depth::Disparity;
use crate::timing::ms_since;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A rendering method of the benchmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Method {
    /// Dr.Bokeh on the exact two layers (all foreground planes, background).
    Layers,
    /// Dr.Bokeh on one exact layer per depth plane.
    Sliced,
    /// Dr.Bokeh from the classical pipeline (segment, fill depth, Telea inpaint).
    Pipeline,
    /// Classical scatter, no occlusion, one layer (`--no-occlusion`).
    Scatter,
    /// Per-pixel gather within its own CoC (SteReFo-style).
    Gather,
}

impl Method {
    /// Every method, in report order (the default of `--methods`).
    pub const ALL: [Method; 5] = [Method::Layers, Method::Sliced, Method::Pipeline, Method::Scatter, Method::Gather];

    /// The method's name in report.csv and report.md ("drbokeh-layers", ...).
    pub fn name(self) -> &'static str {
        match self {
            Method::Layers => "drbokeh-layers",
            Method::Sliced => "drbokeh-sliced",
            Method::Pipeline => "drbokeh-pipeline",
            Method::Scatter => "scatter-no-occlusion",
            Method::Gather => "gather",
        }
    }

    /// A short name for image labels.
    pub fn short(self) -> &'static str {
        match self {
            Method::Layers => "Dr.Bokeh",
            Method::Sliced => "sliced",
            Method::Pipeline => "pipeline",
            Method::Scatter => "scatter",
            Method::Gather => "gather",
        }
    }

    /// The method's legend in the plot and the crops.
    pub fn label(self) -> &'static str {
        match self {
            Method::Layers => "Dr.Bokeh, exact 2 layers",
            Method::Sliced => "Dr.Bokeh, exact layer per depth",
            Method::Pipeline => "Dr.Bokeh, classical pipeline",
            Method::Scatter => "scatter, no occlusion",
            Method::Gather => "gather (SteReFo-style)",
        }
    }

    /// Parses a method name (the short forms `layers`, `sliced`, `pipeline`, `scatter`,
    /// `gather` too).
    pub fn parse(s: &str) -> Option<Method> {
        let s = s.trim().to_ascii_lowercase();
        let alias = match s.as_str() {
            "layers" => Some(Method::Layers),
            "sliced" => Some(Method::Sliced),
            "pipeline" => Some(Method::Pipeline),
            "scatter" | "no-occlusion" => Some(Method::Scatter),
            _ => None,
        };
        alias.or_else(|| Method::ALL.into_iter().find(|m| m.name() == s))
    }

    /// The settings this method runs on `input`. On the linear input: every kernel setting and
    /// option. On the clipped (8-bit) inputs, to keep the run short: the reference and default
    /// settings, [`Variant::RealisticDepth`] for the methods that read the depth map, and for
    /// the pipeline [`Variant::HighlightsOff`] (auto against off) and
    /// [`Variant::RealisticNoMatte`] with and without matting (which run on every input).
    pub fn variants(self, input: Input) -> Vec<Variant> {
        use Variant::*;
        if input.is_clipped() {
            let mut v = vec![self.reference(), self.default_setting()];
            if self.reads_depth() {
                v.push(RealisticDepth);
            }
            if self == Method::Pipeline {
                v.extend([HighlightsOff, RealisticNoMatte, RealisticNoMatteRefineOff]);
            }
            v.dedup();
            return v;
        }
        match self {
            Method::Layers => vec![Exact, Fast(1), Fast(2), Fast(4), Fast(8), PhysicalExact, PhysicalFast(2)],
            Method::Sliced => vec![Exact, Fast(2), PhysicalExact, PhysicalFast(2)],
            Method::Pipeline => vec![
                Exact,
                Fast(2),
                PhysicalExact,
                PhysicalFast(2),
                RealisticDepth,
                RealisticNoMatte,
                RealisticNoMatteRefineOff,
                LayersAuto,
                RealisticLayersAuto,
                PatchMatch,
            ],
            Method::Scatter => vec![Exact, Fast(2), PhysicalExact, PhysicalFast(2), RealisticDepth],
            Method::Gather => vec![Plain, RealisticDepth],
        }
    }

    /// The setting used when methods are compared (the reference kernel).
    pub fn reference(self) -> Variant {
        if self == Method::Gather { Variant::Plain } else { Variant::Exact }
    }

    /// The tool's default settings (physical profile, fast kernel at quality 2; the gather has
    /// only one): what a user gets, the row the inputs are compared on.
    pub fn default_setting(self) -> Variant {
        if self == Method::Gather { Variant::Plain } else { Variant::PhysicalFast(2) }
    }

    /// True for the methods that read the depth map (and have [`Variant::RealisticDepth`]);
    /// the exact-layer methods carry their depth in the layers.
    pub fn reads_depth(self) -> bool {
        matches!(self, Method::Pipeline | Method::Scatter | Method::Gather)
    }
}

/// A kernel setting.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Variant {
    /// The exact kernel.
    Exact,
    /// The fast kernel at this quality (1 … 8).
    Fast(u32),
    /// The physical lens profile, exact kernel.
    PhysicalExact,
    /// The physical lens profile, fast kernel at this quality (the default settings at 2).
    PhysicalFast(u32),
    /// Methods with no kernel choice.
    Plain,
    /// The method's default settings (physical profile, fast kernel at quality 2), fed a
    /// depth map degraded as an estimator gives it ([`super::scenes::realistic_depth`]) instead
    /// of the exact one. Only for the methods that read the depth map.
    RealisticDepth,
    /// The pipeline's default settings with `--layers auto` (the background also cut at gaps
    /// of its depth), exact depth map.
    LayersAuto,
    /// [`Variant::LayersAuto`] fed the realistic depth map of [`Variant::RealisticDepth`].
    RealisticLayersAuto,
    /// The pipeline's default settings with `--inpaint patchmatch` (the colour behind the
    /// foreground filled from exemplar patches, `stages::patchmatch`), exact depth map.
    PatchMatch,
    /// The pipeline's default settings with `[highlights] mode = "off"` (the clipped photo as
    /// decoded), exact depth map and matte: against the defaults (`auto`) it shows what the
    /// highlights stage recovers. Clipped inputs only (on linear ones the stage does nothing).
    HighlightsOff,
    /// [`Variant::RealisticDepth`] without the matte: the pipeline segments from the realistic
    /// depth map alone, as with a phone photo and an estimator (issue 35's acceptance compares
    /// it with the baselines' realistic-depth rows).
    RealisticNoMatte,
    /// [`Variant::RealisticNoMatte`] with `[segment] refine = "off"`: the depth split's
    /// outline as it comes, against which issue 42's matting is judged.
    RealisticNoMatteRefineOff,
}

impl Variant {
    /// The setting's name in reports: "exact", "fast-qQ" or "default".
    pub fn name(self) -> String {
        match self {
            Variant::Exact => "exact".into(),
            Variant::Fast(q) => format!("fast-q{q}"),
            Variant::PhysicalExact => "physical-exact".into(),
            Variant::PhysicalFast(q) => format!("physical-fast-q{q}"),
            Variant::Plain => "default".into(),
            Variant::RealisticDepth => "realistic-depth".into(),
            Variant::LayersAuto => "layers-auto".into(),
            Variant::RealisticLayersAuto => "realistic-depth-layers-auto".into(),
            Variant::PatchMatch => "patchmatch".into(),
            Variant::HighlightsOff => "highlights-off".into(),
            Variant::RealisticNoMatte => "realistic-depth-no-matte".into(),
            Variant::RealisticNoMatteRefineOff => "realistic-depth-no-matte-refine-off".into(),
        }
    }
    /// Whether this setting reads the realistic depth map instead of the exact one.
    pub fn realistic(self) -> bool {
        matches!(
            self,
            Variant::RealisticDepth | Variant::RealisticLayersAuto | Variant::RealisticNoMatte | Variant::RealisticNoMatteRefineOff
        )
    }

    /// Whether the pipeline is given the scene's matte with this setting.
    pub fn has_matte(self) -> bool {
        !matches!(self, Variant::RealisticNoMatte | Variant::RealisticNoMatteRefineOff)
    }

    /// The lens profile this setting renders with.
    pub fn profile(self) -> crate::render::Profile {
        match self {
            Variant::PhysicalExact
            | Variant::PhysicalFast(_)
            | Variant::RealisticDepth
            | Variant::LayersAuto
            | Variant::RealisticLayersAuto
            | Variant::PatchMatch
            | Variant::HighlightsOff
            | Variant::RealisticNoMatte
            | Variant::RealisticNoMatteRefineOff => crate::render::Profile::Physical,
            _ => crate::render::Profile::Official,
        }
    }
    fn kernel(self) -> Kernel {
        match self {
            Variant::Fast(q) | Variant::PhysicalFast(q) => Kernel::Fast { quality: q },
            Variant::RealisticDepth
            | Variant::LayersAuto
            | Variant::RealisticLayersAuto
            | Variant::PatchMatch
            | Variant::HighlightsOff
            | Variant::RealisticNoMatte
            | Variant::RealisticNoMatteRefineOff => Kernel::Fast { quality: 2 },
            _ => Kernel::Exact,
        }
    }
}

/// Benchmark options (the `bench` subcommand's flags).
#[derive(Clone, Debug)]
pub struct BenchOptions {
    /// Generated scenes (each is evaluated at several focus settings).
    pub scenes: usize,
    /// Frame width of the generated scenes, pixels (>= 16).
    pub width: usize,
    /// Frame height of the generated scenes, pixels (>= 16).
    pub height: usize,
    /// Seed of the scene generator and of the tracer: equal seeds, equal scenes and truths.
    pub seed: u64,
    /// Evaluate on folders in the shared ground-truth format instead of generated scenes.
    pub groundtruth: Option<PathBuf>,
    /// Photos to texture the generated planes with (else procedural textures).
    pub textures: Option<PathBuf>,
    /// The methods to run, at least one.
    pub methods: Vec<Method>,
    /// The inputs every method is fed, at least one, in report order (see [`Input`]).
    pub inputs: Vec<Input>,
    /// The report folder (created).
    pub out: PathBuf,
    /// Rays per pixel of the traced ground truth.
    pub spp: u32,
    /// Runs per render for the median time (renders under ~1 s total are repeated).
    pub repeats: usize,
    /// How many side-by-side crops to write.
    pub crops: usize,
    /// The command line, for the report.
    pub command: String,
    /// The aperture every method renders with and the generated scenes are traced with (the
    /// shared ground-truth folders were rendered with a disc: they refuse another shape).
    pub aperture: crate::config::ApertureConfig,
}

impl Default for BenchOptions {
    fn default() -> Self {
        BenchOptions {
            scenes: 50,
            width: 256,
            height: 256,
            seed: 1,
            groundtruth: None,
            textures: None,
            methods: Method::ALL.to_vec(),
            inputs: Input::ALL.to_vec(),
            out: PathBuf::from("bench-report"),
            spp: 1024,
            repeats: 3,
            crops: 4,
            command: String::new(),
            aperture: crate::config::ApertureConfig::default(),
        }
    }
}

/// One evaluated case: a scene at one focus setting, with its ground truth and inputs.
pub struct Case {
    /// The scene's name.
    pub scene: String,
    /// The focus setting's name ("focus_fg", ...).
    pub setting: String,
    /// Report categories this case belongs to (`fg_in_focus`, `bg_in_focus`, `between`,
    /// `thin`, `highlights`).
    pub categories: Vec<&'static str>,
    /// Blur strength K, pixels of CoC radius per unit of normalized disparity.
    pub blur: f32,
    /// Focal plane, normalized disparity.
    pub focus: f32,
    /// Largest CoC radius in the frame, pixels.
    pub max_coc: f32,
    /// Pixels left out at each border when scoring.
    pub border: usize,
    /// The ground truth: linear RGB, the frame's size.
    pub gt: Image,
    /// Estimated RMS noise of `gt` (two-halves estimate), when it was traced here.
    pub gt_noise: Option<f64>,
    /// What every method renders from (layers, photo, disparity, matte), linear HDR: the
    /// other inputs are made from it ([`inputs::prepare`]).
    pub inputs: SceneInputs,
    /// The aperture traced and rendered (see [`BenchOptions::aperture`]).
    pub aperture: crate::config::ApertureConfig,
}

/// The scores of one render against the ground truth.
#[derive(Clone, Copy, Debug, Default)]
pub struct Scores {
    /// Root-mean-square error, linear light (the metrics below are linear too, up to the sRGB
    /// ones).
    pub rmse: f64,
    /// RMSE after the best gain (exposure-insensitive), linear light.
    pub si_rmse: f64,
    /// PSNR, dB, linear light, peak 1 (+inf for identical images).
    pub psnr: f64,
    /// Mean SSIM on luminance, linear light, peak 1 (1 = identical).
    pub ssim: f64,
    /// Zero-normalized cross-correlation, -1 … 1 (1 = identical up to gain and offset).
    pub zncc: f64,
    /// PSNR, dB, of the sRGB-encoded images clipped to [0, 1] (a headline figure, with
    /// `ssim_srgb`).
    pub psnr_srgb: f64,
    /// Mean SSIM on luminance of the sRGB-encoded, clipped images.
    pub ssim_srgb: f64,
    /// sRGB PSNR over the whole frame, borders included.
    pub psnr_srgb_full: f64,
}

/// Scores `img` against `gt` (both linear RGB, same size), leaving `border` pixels out at
/// each side (except `psnr_srgb_full`). Allocates two sRGB copies of each image.
pub fn score(img: &Image, gt: &Image, border: usize) -> Scores {
    let (a, b) = (srgb(img), srgb(gt));
    Scores {
        rmse: rmse(img, gt, border),
        si_rmse: si_rmse(img, gt, border),
        psnr: psnr(img, gt, 1.0, border),
        ssim: ssim(img, gt, 1.0, border),
        zncc: zncc(img, gt, border),
        psnr_srgb: psnr(&a, &b, 1.0, border),
        ssim_srgb: ssim(&a, &b, 1.0, border),
        psnr_srgb_full: psnr(&a, &b, 1.0, 0),
    }
}

/// One row of report.csv.
#[derive(Clone, Debug)]
pub struct Row {
    /// The scene's name.
    pub scene: String,
    /// The focus setting's name.
    pub setting: String,
    /// Report categories of the case (see [`Case::categories`]).
    pub categories: Vec<&'static str>,
    /// The method rendered.
    pub method: Method,
    /// Its kernel setting.
    pub variant: Variant,
    /// The input it rendered from.
    pub input: Input,
    /// Frame width, pixels.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// Worker threads the render used.
    pub threads: usize,
    /// Blur strength K, pixels of CoC radius per unit of normalized disparity.
    pub blur: f32,
    /// Focal plane, normalized disparity.
    pub focus: f32,
    /// Largest CoC radius in the frame, pixels.
    pub max_coc: f32,
    /// Pixels left out at each border when scoring.
    pub border: usize,
    /// Renders timed for the median.
    pub runs: usize,
    /// Median wall time of one render, ms.
    pub time_ms: f64,
    /// The render's scores against the ground truth.
    pub scores: Scores,
    /// Its scores along the subject's true outline ([`super::outline`]).
    pub outline: super::outline::OutlineScores,
    /// The pipeline's highlights stage against what clipping took from the photo (pipeline
    /// rows on clipped inputs; None otherwise).
    pub light: Option<LightRecovery>,
}

/// How much of the light clipping took from a photo the highlights stage gave back. Both sums
/// are linear light (white = 1) over the photo's samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LightRecovery {
    /// Light the stage added: Σ (its output − the photo), every sample (its report's
    /// `light_added`; 0 when it did not run).
    pub added: f64,
    /// Light clipping took: Σ (the linear view before clipping − the photo) over the samples
    /// stored as white ([`Prepared::missing_light`]).
    pub missing: f64,
}

impl LightRecovery {
    /// `added / missing`: 1 = all the missing light is back (above 1: too much). None when
    /// nothing was clipped.
    pub fn fraction(self) -> Option<f64> {
        (self.missing > 0.0).then(|| self.added / self.missing)
    }
}

/// Loads the photos of a texture folder (PNG/JPEG/TIFF/EXR), sorted by name.
pub fn load_textures(dir: &Path) -> Result<Vec<Image>> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            let ext = p.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
            ["png", "jpg", "jpeg", "tif", "tiff", "exr"].contains(&ext.as_str())
        })
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(Error::input(dir, "the textures folder holds no PNG, JPEG, TIFF or EXR image"));
    }
    paths
        .iter()
        .map(|p| {
            let img = read_photo(p, Transfer::Srgb, &ReadLimits::default())?;
            if img.width < 16 || img.height < 16 {
                return Err(Error::input(p, format!("texture is {}x{}; at least 16x16 is needed", img.width, img.height)));
            }
            Ok(img)
        })
        .collect()
}

/// Traces (or loads) the cases of a run, one at a time, handing each to `f`.
fn for_each_case(opts: &BenchOptions, log: &mut dyn FnMut(&str), f: &mut dyn FnMut(Case) -> Result<()>) -> Result<usize> {
    let aperture = opts.aperture.resolve()?;
    if let Some(dir) = &opts.groundtruth {
        if !aperture.is_disc() {
            return Err(Error::usage(format!(
                "aperture.shape {}: the ground-truth folders were rendered with a disc; bench other shapes on generated scenes",
                aperture.label()
            )));
        }
        let dirs = super::groundtruth::scene_dirs(dir)?;
        let mut n = 0;
        for d in dirs {
            let scene = GtScene::load(&d)?;
            let desc = crate::io::read_input_text(&d.join("params.json")).unwrap_or_default().to_ascii_lowercase();
            let inputs = SceneInputs {
                aif: scene.aif.clone(),
                disparity: scene.disparity.clone(),
                matte: scene.alpha.clone(),
                realistic_disparity: super::scenes::realistic_depth(&scene.disparity),
                two_layers: scene.exact_layers()?,
                plane_layers: gt_plane_layers(&scene)?,
            };
            for s in &scene.settings {
                let mut categories = vec![match s.name.as_str() {
                    n if n.contains("fg") => "fg_in_focus",
                    n if n.contains("bg") => "bg_in_focus",
                    _ => "between",
                }];
                if scene.name.contains("thin") || desc.contains("thin structure") {
                    categories.push("thin");
                }
                if desc.contains("highlight") {
                    categories.push("highlights");
                }
                log(&format!("{} {}", scene.name, s.name));
                f(Case {
                    scene: scene.name.clone(),
                    setting: s.name.clone(),
                    categories,
                    blur: s.blur,
                    focus: s.focus,
                    max_coc: s.coc_max,
                    border: s.coc_max.ceil() as usize,
                    gt: s.gt.clone(),
                    gt_noise: None,
                    inputs: inputs.clone(),
                    aperture: opts.aperture.clone(),
                })?;
                n += 1;
            }
        }
        return Ok(n);
    }
    let photos = match &opts.textures {
        Some(d) => load_textures(d)?,
        None => Vec::new(),
    };
    for i in 0..opts.scenes {
        let sc = generate(opts.seed, i, opts.width, opts.height, &photos);
        log(&format!("{}: tracing {} planes, {} spp", sc.name, sc.planes.len(), opts.spp));
        let planes: Vec<Plane> = sc.trace_planes();
        let mut ts = TraceSettings::new(sc.blur, sc.focus, opts.spp, opts.seed ^ (i as u64) << 20);
        ts.aperture = aperture;
        let (gt, half) = trace_split(&planes, &ts, sc.window(), &|_| {})?;
        let border = sc.max_coc.ceil() as usize;
        // Noise of the mean of all samples: half the RMS difference of the two halves.
        let other =
            Image::from_vec(gt.width, gt.height, 3, gt.data.iter().zip(&half.data).map(|(f, h)| 2.0 * f - h).collect()).expect("size");
        let noise = rmse(&half, &other, border) / 2.0;
        let mut categories = vec![match sc.focus_kind {
            FocusKind::Foreground => "fg_in_focus",
            FocusKind::Background => "bg_in_focus",
            FocusKind::Between => "between",
        }];
        if sc.thin {
            categories.push("thin");
        }
        if sc.highlights {
            categories.push("highlights");
        }
        f(Case {
            scene: sc.name.clone(),
            setting: sc.focus_kind.name().into(),
            categories,
            blur: sc.blur,
            focus: sc.focus,
            max_coc: sc.max_coc,
            border,
            gt,
            gt_noise: Some(noise),
            inputs: sc.inputs()?,
            aperture: opts.aperture.clone(),
        })?;
    }
    Ok(opts.scenes)
}

/// Runs `f` once, then again while the total stays under ~1 s, up to `repeats` runs; returns
/// the last result, the median time (ms) and the number of runs.
fn timed<T>(repeats: usize, mut f: impl FnMut() -> Result<T>) -> Result<(T, f64, usize)> {
    let mut times = Vec::new();
    let t_all = Instant::now();
    let mut out;
    loop {
        let t = Instant::now();
        out = f()?;
        times.push(ms_since(t));
        if times.len() >= repeats.max(1) || t_all.elapsed().as_secs_f64() > 1.0 {
            break;
        }
    }
    times.sort_by(f64::total_cmp);
    let n = times.len();
    let med = if n % 2 == 1 { times[n / 2] } else { 0.5 * (times[n / 2 - 1] + times[n / 2]) };
    Ok((out, med, n))
}

/// What one render gave.
pub struct Rendered {
    /// The render, linear RGB.
    pub image: Image,
    /// The pipeline's highlights stage: linear light it added to the photo, summed over every
    /// sample (0 when it was skipped); None for the other methods.
    pub light_added: Option<f64>,
    /// The pipeline's foreground matte (its front layer's alpha; all ones when it rendered one
    /// layer); None for the other methods.
    pub alpha: Option<Image>,
}

/// The light the pipeline's highlights stage added (its report's `light_added`), 0 when the
/// stage did not run; an internal error when its report lacks the number.
fn light_added(report: &crate::pipeline::Report) -> Result<f64> {
    let Some(stage) = report.stages.iter().find(|s| s.name == "highlights") else { return Ok(0.0) };
    if stage.status != crate::pipeline::StageStatus::Ran {
        return Ok(0.0);
    }
    stage
        .detail
        .as_ref()
        .and_then(|d| d["light_added"].as_f64())
        .ok_or_else(|| Error::Internal("the highlights stage's report has no `light_added`".into()))
}

/// Renders one method/setting on a case from the inputs `photo` delivers (linear RGB).
pub fn render_method(case: &Case, photo: &Prepared, m: Method, v: Variant) -> Result<Rendered> {
    let inp: &SceneInputs = &photo.scene;
    let (blur, focus) = (case.blur, case.focus);
    let plain = |image: Result<Image>| image.map(|image| Rendered { image, light_added: None, alpha: None });
    let aperture = case.aperture.resolve()?;
    let renderer = |layers: &[Layer], occlusion: bool| -> Result<Image> {
        let lens = render::auto_lens(layers, blur * aperture.max_channel_scale(), focus);
        render::render(layers, &RenderSettings { blur, focus, lens, occlusion, profile: v.profile(), aperture }, v.kernel())
    };
    // The depth map the photo-based methods read.
    let disparity = if v.realistic() { &inp.realistic_disparity } else { &inp.disparity };
    match m {
        Method::Layers => plain(renderer(&inp.two_layers, true)),
        Method::Sliced => plain(renderer(&inp.plane_layers, true)),
        Method::Scatter => {
            let opaque = Image::filled(inp.aif.width, inp.aif.height, 1, 1.0);
            let single = Layer::from_parts(&inp.aif, &opaque, disparity, "all-in-focus layer")?;
            plain(renderer(&[single], false))
        }
        Method::Gather => plain(Ok(gather(&inp.aif, disparity, blur, focus))),
        Method::Pipeline => {
            let mut cfg = Config::default();
            cfg.render.blur = Some(blur);
            match v.kernel() {
                Kernel::Fast { quality } => {
                    cfg.render.kernel = KernelChoice::Fast;
                    cfg.render.quality = quality;
                }
                Kernel::Exact => cfg.render.kernel = KernelChoice::Exact,
            }
            cfg.render.profile = v.profile();
            cfg.aperture = case.aperture.clone();
            if matches!(v, Variant::LayersAuto | Variant::RealisticLayersAuto) {
                cfg.segment.layers = crate::stages::layer_count::LayerCount::Auto;
            }
            if v == Variant::PatchMatch {
                cfg.inpaint.method = crate::stages::inpaint_onnx::InpaintMethod::PatchMatch;
            }
            if v == Variant::RealisticNoMatteRefineOff {
                cfg.segment.refine = crate::stages::matting::RefineMethod::Off;
            }
            if v == Variant::HighlightsOff {
                cfg.highlights.mode = crate::stages::light_recovery::HighlightMode::Off;
            }
            let scene = Scene {
                rgb: inp.aif.clone(),
                disparity: Disparity { map: disparity.clone(), z_range: None, filled_fraction: 0.0 },
                matte: v.has_matte().then(|| inp.matte.clone()),
                encoding: photo.input.encoding(),
            };
            let out = Pipeline::from_config(cfg)?.run(&scene, Focus::Disparity(focus))?;
            let front = &out.layers[0];
            let alpha =
                Image::from_vec(front.width(), front.height(), 1, (0..front.width() * front.height()).map(|i| front.alpha(i)).collect())
                    .ok_or_else(|| Error::Internal("the front layer's alpha".into()))?;
            Ok(Rendered { light_added: Some(light_added(&out.report)?), image: out.image, alpha: Some(alpha) })
        }
    }
}

/// A side-by-side crop kept for the report.
pub struct CropPanel {
    /// `SCENE_SETTING`, the crop's file name stem.
    pub name: String,
    /// How much better Dr.Bokeh (exact layers) is than the scatter baseline here (sRGB dB).
    pub gain: f64,
    /// (label, sRGB-ready linear crop)
    pub panels: Vec<(String, Image)>,
}

/// Everything a run produced.
pub struct BenchResult {
    /// One row per (case, method, setting), as in report.csv.
    pub rows: Vec<Row>,
    /// The side-by-side crops written.
    pub crops: Vec<CropPanel>,
    /// Estimated RMS noise of each traced ground truth (empty for loaded ground truths).
    pub gt_noise: Vec<f64>,
    /// Cases evaluated.
    pub cases: usize,
}

/// Runs the benchmark and writes report.csv, report.md, error_vs_time.png and crops/ into
/// `opts.out`. `log` receives one line per case.
pub fn run(opts: &BenchOptions, log: &mut dyn FnMut(&str)) -> Result<BenchResult> {
    if opts.groundtruth.is_none() && (opts.width < 16 || opts.height < 16) {
        return Err(Error::usage(format!("bench.size must be at least 16x16, got {}x{}", opts.width, opts.height)));
    }
    if opts.methods.is_empty() {
        return Err(Error::usage("bench.methods: no method selected"));
    }
    if opts.inputs.is_empty() {
        return Err(Error::usage("bench.inputs: no input selected"));
    }
    // The crops and the report's method tables are drawn from one input: the linear one when
    // it runs (the ceiling), else the first asked for.
    let primary = super::inputs::primary_input(&opts.inputs);
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    let threads = rayon::current_num_threads();
    let mut rows = Vec::new();
    let mut crops: Vec<CropPanel> = Vec::new();
    let mut gt_noise = Vec::new();
    let mut worst: Option<CropPanel> = None;
    let methods = opts.methods.clone();
    let cases = for_each_case(opts, log, &mut |case: Case| {
        if let Some(n) = case.gt_noise {
            gt_noise.push(n);
        }
        let mut refs: Vec<(Method, Image, Scores)> = Vec::new();
        let true_outline = super::outline::Outline::of(&case.inputs.matte);
        for &input in &opts.inputs {
            let photo = inputs::prepare(&case.inputs, input)?;
            for &m in &methods {
                // The official profile draws the disc only: with another aperture only the
                // physical settings (and the gather, a disc whatever the aperture) run.
                let shaped = !case.aperture.is_disc();
                for v in m
                    .variants(input)
                    .into_iter()
                    .filter(|v| !shaped || m == Method::Gather || v.profile() == crate::render::Profile::Physical)
                {
                    let (out, ms, runs) = timed(opts.repeats, || render_method(&case, &photo, m, v))?;
                    let img = out.image;
                    if !img.all_finite() {
                        return Err(Error::Internal(format!(
                            "{} {} ({} input) produced a non-finite value on {}",
                            m.name(),
                            v.name(),
                            input.name(),
                            case.scene
                        )));
                    }
                    let scores = score(&img, &case.gt, case.border);
                    let outline = true_outline.score(&img, &case.gt, out.alpha.as_ref().map(|a| (a, &case.inputs.matte)));
                    let light = match (photo.missing_light, out.light_added) {
                        (Some(missing), Some(added)) => Some(LightRecovery { added, missing }),
                        _ => None,
                    };
                    if v == m.reference() && input == primary {
                        refs.push((m, img, scores));
                    }
                    rows.push(Row {
                        scene: case.scene.clone(),
                        setting: case.setting.clone(),
                        categories: case.categories.clone(),
                        method: m,
                        variant: v,
                        input,
                        width: case.gt.width,
                        height: case.gt.height,
                        threads,
                        blur: case.blur,
                        focus: case.focus,
                        max_coc: case.max_coc,
                        border: case.border,
                        runs,
                        time_ms: ms,
                        scores,
                        outline,
                        light,
                    });
                }
            }
        }
        if opts.crops > 0 {
            let find = |m: Method| refs.iter().find(|r| r.0 == m);
            let gain = match (find(Method::Layers), find(Method::Scatter)) {
                (Some(a), Some(b)) => a.2.psnr_srgb - b.2.psnr_srgb,
                _ => 0.0,
            };
            // The best cases for Dr.Bokeh, and (when there is one) the case where it loses most.
            let keep_best = opts.crops.saturating_sub(1).max(1);
            let better = crops.len() < keep_best || crops.iter().any(|c| c.gain < gain);
            let worse = opts.crops > 1 && gain < 0.0 && worst.as_ref().is_none_or(|w: &CropPanel| gain < w.gain);
            if better || worse {
                let mut images: Vec<(String, &Image)> = vec![("truth".into(), &case.gt)];
                images.extend(refs.iter().map(|(m, img, _)| (m.short().to_string(), img)));
                let (ours, base) = (find(Method::Layers).map(|r| &r.1), find(Method::Scatter).map(|r| &r.1));
                // Show where the difference is largest, in whichever direction this case goes.
                let panel = if worse { crop_panels(&case, &images, base, ours) } else { crop_panels(&case, &images, ours, base) };
                let c = CropPanel { name: format!("{}_{}", case.scene, case.setting), gain, panels: panel };
                if worse {
                    worst = Some(c);
                } else {
                    crops.push(c);
                    crops.sort_by(|a, b| b.gain.total_cmp(&a.gain));
                    crops.truncate(keep_best);
                }
            }
        }
        Ok(())
    })?;
    crops.extend(worst);
    Ok(BenchResult { rows, crops, gt_noise, cases })
}

/// Picks the `size`² window (inside the scored area) where the scatter baseline's error most
/// exceeds Dr.Bokeh's, and crops every image there.
pub fn crop_panels(case: &Case, images: &[(String, &Image)], ours: Option<&Image>, base: Option<&Image>) -> Vec<(String, Image)> {
    let gt = &case.gt;
    let (w, h) = (gt.width, gt.height);
    let b = case.border.min(w / 4).min(h / 4);
    let size = 96.min(w - 2 * b).min(h - 2 * b).max(1);
    let (mut best, mut at) = (f64::NEG_INFINITY, (b, b));
    if let (Some(o), Some(s)) = (ours, base) {
        let lum = |img: &Image, i: usize| {
            0.2126 * img.data[i * 3] as f64 + 0.7152 * img.data[i * 3 + 1] as f64 + 0.0722 * img.data[i * 3 + 2] as f64
        };
        let (so, ss, sg) = (srgb(o), srgb(s), srgb(gt));
        // Integral image of (scatter error - ours error).
        let mut integ = vec![0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let v = (lum(&ss, i) - lum(&sg, i)).abs() - (lum(&so, i) - lum(&sg, i)).abs();
                integ[(y + 1) * (w + 1) + x + 1] = v + integ[y * (w + 1) + x + 1] + integ[(y + 1) * (w + 1) + x] - integ[y * (w + 1) + x];
            }
        }
        let mut y = b;
        while y + size <= h - b {
            let mut x = b;
            while x + size <= w - b {
                let at_ = |xx: usize, yy: usize| integ[yy * (w + 1) + xx];
                let v = at_(x + size, y + size) - at_(x, y + size) - at_(x + size, y) + at_(x, y);
                if v > best {
                    best = v;
                    at = (x, y);
                }
                x += 4;
            }
            y += 4;
        }
    }
    images
        .iter()
        .map(|(name, img)| {
            let mut c = Image::new(size, size, 3);
            for y in 0..size {
                for x in 0..size {
                    c.pixel_mut(x, y).copy_from_slice(img.pixel(at.0 + x, at.1 + y));
                }
            }
            (name.clone(), c)
        })
        .collect()
}
