//! The whole job: image + disparity (+ matte) → layers → rendered image, with a report.
//!
//! [`Pipeline`] holds the configuration; [`Pipeline::run`] takes a decoded scene and a focus,
//! [`Pipeline::render_layers`] takes ready-made layers. Both return an [`Outcome`] with the
//! linear result, the layers used and a [`Report`] of what ran, what was skipped and why.

use crate::color::PhotoEncoding;
use crate::config::{Config, KernelChoice};
use crate::error::{Error, Result};
use crate::image::Image;

use crate::render::{self, Kernel, Layer, RenderSettings, lens};
pub use crate::report::{DepthSource, FrameReport, Report, StageReport, StageStatus, UsedParams};
use crate::stages::background::{BandReach, EdgeBand, ForegroundColour, InpaintOptions, Reach, fill_background, prepare_background};
use crate::stages::depth::Disparity;
use crate::stages::depth_edges;
use crate::stages::fill_depth::{DepthEdges, foreground_disparity, hard_mask};
use crate::stages::foreground::{EdgeColour, carried_colour, unmix_edges};
use crate::stages::layer_count::LayerCount;
use crate::stages::light_recovery::{self, Recovered};
use crate::stages::matting;
use crate::stages::segment::{self, SegmentMethod, Segmentation};
use crate::stages::slices;
use crate::stages::work_box;
use crate::timing::ms_since;
use rayon::prelude::*;
use std::time::Instant;

/// A decoded input scene.
pub struct Scene {
    /// Linear RGB (3 channels).
    pub rgb: Image,
    /// Normalized disparity of every pixel.
    pub disparity: Disparity,
    /// Optional foreground matte (one channel, [0, 1]).
    pub matte: Option<Image>,
    /// How the photo was stored: an integer photo's clipped lights are restored by the
    /// highlights stage ([`light_recovery`]).
    pub encoding: PhotoEncoding,
}

/// How the focal plane is chosen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Focus {
    /// Normalized disparity of the focal plane (0 far … 1 near).
    Disparity(f32),
    /// The disparity under pixel (x, y), robustly (median of a small window).
    At(i64, i64),
    /// A metric depth (depth maps only).
    Depth(f64),
}

/// The result of a run.
pub struct Outcome {
    /// Rendered image, linear RGB (3 channels); in gamma mode, still before the inverse gamma.
    /// Empty (0x0) with [`BuildLayers::Only`].
    pub image: Image,
    /// The layers that were rendered (or built, with [`BuildLayers::Always`] and
    /// [`BuildLayers::Only`]), front first; empty when nothing was built.
    pub layers: Vec<Layer<'static>>,
    /// What ran, what was skipped and why, with timings.
    pub report: Report,
}

/// Receives a warning the moment it is known (a long exact render is announced before it
/// starts, not in the report after it).
pub type Notice = Box<dyn Fn(&str) + Send + Sync>;

/// Why the scene is one layer when occlusion is off (the `segment` stage's skip reason).
const NO_OCCLUSION_ONE_LAYER: &str = "render.occlusion = false renders the scene as one layer";

/// One peel of [`Pipeline::peel`]: a layer, the opaque scene behind it, and what was done.
struct Peeled {
    layer: Layer<'static>,
    /// The scene behind the layer.
    behind: Behind,
    fill_ms: f64,
    fill_detail: serde_json::Value,
    inpaint_ms: f64,
    inpaint_detail: serde_json::Value,
}

/// What one peel is asked for, besides the scene, the layer's alpha and the depth map's ramp
/// across its outline: the render's focus, blur and largest CoC radius (pixels), whether the
/// fill behind must be complete (`whole`: more slices are cut from it), and the layer's name
/// for messages.
#[derive(Clone, Copy)]
struct PeelSpec<'a> {
    focus: f32,
    blur: f32,
    max_coc: f32,
    whole: bool,
    what: &'a str,
    /// The edge band's rule for this layer (`[inpaint] edge_band`, or kept for a binary matte).
    edge_band: EdgeBand,
    /// [`InpaintOptions::lights_above`]: the recovered lights' floor, when highlights `auto`
    /// changed an integer photo.
    lights_above: Option<f32>,
}

/// The opaque scene behind a peeled layer: its colour (linear RGB) and disparity, inpainted,
/// on `window` of the frame (the peel's work box, or the whole frame); outside the window the
/// scene is the peel's input as it was.
struct Behind {
    rgb: Image,
    disparity: Image,
    window: work_box::Window,
}

impl Behind {
    /// The frame-sized scene, from the peel's input `photo` and `disp`.
    fn into_frame(self, photo: &Image, disp: &Image) -> (Image, Image) {
        if (self.rgb.width, self.rgb.height) == (photo.width, photo.height) {
            return (self.rgb, self.disparity);
        }
        let (x0, y0, ..) = self.window;
        rayon::join(
            || {
                let mut rgb = photo.clone();
                rgb.paste(&self.rgb, x0, y0);
                rgb
            },
            || {
                let mut d = disp.clone();
                d.paste(&self.disparity, x0, y0);
                d
            },
        )
    }

    /// The opaque layer of the scene, from the peel's input `photo` and `disp`, without a
    /// frame-sized copy of either on the way.
    fn into_layer(self, photo: &Image, disp: &Image, what: &str) -> Result<Layer<'static>> {
        Layer::new(work_box::opaque_layer(&self.rgb, &self.disparity, photo, disp, self.window), what)
    }
}

/// The configured pipeline.
pub struct Pipeline {
    config: Config,
    notice: Option<Notice>,
    /// `[aperture]`, resolved once (an image aperture read).
    aperture: render::Aperture,
}

/// An exact-kernel render estimated to take longer than this (seconds) is announced.
const LONG_EXACT_SECONDS: f64 = 60.0;

/// Below [`lens::SHARP_COC_PX`] everywhere, the scene counts as all in focus.
use crate::render::lens::SHARP_COC_PX;

/// The "nothing is out of focus" rule: with the automatic kernel choice and every circle of
/// confusion below [`SHARP_COC_PX`] (`max_coc` = the largest radius, pixels), rendering is
/// skipped; returns the reason for the report. None when something must be rendered (an
/// explicitly chosen kernel always runs).
fn nothing_out_of_focus(kernel: KernelChoice, max_coc: f32) -> Option<String> {
    (kernel == KernelChoice::Auto && max_coc < SHARP_COC_PX)
        .then(|| format!("no pixel's circle of confusion reaches half a pixel (largest radius {max_coc:.3} px)"))
}

/// The disparity a click at pixel (`x`, `y`) of `layers` (front first, non-empty) focuses on:
/// the front-most layer that is mostly opaque there (alpha > 0.5), else the back layer. A
/// pixel outside the layers is a usage error naming `render.focus_at`.
pub fn disparity_at(layers: &[Layer], x: i64, y: i64) -> Result<f32> {
    let (w, h) = (layers[0].width(), layers[0].height());
    if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
        return Err(Error::usage(format!("render.focus_at {x},{y} is outside the {w}x{h} layers")));
    }
    let i = y as usize * w + x as usize;
    let l = layers.iter().find(|l| l.alpha(i) > 0.5).unwrap_or(layers.last().expect("non-empty"));
    Ok(l.disparity(i))
}

/// Whether [`Pipeline::run_with`] builds the layers when nothing is out of focus.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BuildLayers {
    /// Only when they are rendered: an all-in-focus scene returns the photo at once.
    WhenRendered,
    /// Always (for `--save-layers`), even when rendering is skipped.
    Always,
    /// Always, and never rendered: for callers that render the layers themselves (a viewer,
    /// a focus pull). The outcome's image is then empty (0x0).
    Only,
}

/// Why [`BuildLayers::Only`] skips the render.
const LAYERS_ONLY: &str = "only the layers were asked for";

/// Where the layers given to `render_prepared` come from, which decides who applies the
/// "nothing out of focus" rule.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LayerOrigin {
    /// Built by [`Pipeline::run_with`], which has applied the rule on the scene's disparity.
    Built,
    /// Given by the caller: the rule is applied here, on the layers, and an all-sharp set is
    /// alpha-composited.
    Given,
}

/// Default blur strength for an image: the official K = 30 at 1 MP, scaled with the image's
/// linear size so the look does not change with resolution.
pub fn default_blur(width: usize, height: usize) -> f32 {
    30.0 * ((width * height) as f32 / 1.0e6).sqrt()
}

impl Pipeline {
    /// A pipeline running `config`, after [`Config::validate`] (a bad value is a usage error naming its key).
    pub fn from_config(config: Config) -> Result<Self> {
        config.validate()?;
        let aperture = config.aperture.resolve()?;
        Ok(Pipeline { config, notice: None, aperture })
    }

    /// Calls `notice` with warnings that matter before a stage ends (they are in the
    /// report's warnings as well).
    pub fn with_notice(mut self, notice: Notice) -> Self {
        self.notice = Some(notice);
        self
    }

    fn warn_now(&self, report: &mut Report, msg: String) {
        if let Some(n) = &self.notice {
            n(&msg);
        }
        report.warnings.push(msg);
    }

    /// The configuration it runs with.
    pub fn config(&self) -> &Config {
        &self.config
    }

    fn blur_for(&self, w: usize, h: usize) -> f32 {
        self.config.render.blur.unwrap_or_else(|| default_blur(w, h))
    }

    /// Resolves the focus to a normalized disparity, clamping to [0, 1] with a warning.
    fn resolve_focus(
        focus: Focus,
        disparity_at: impl Fn(i64, i64) -> Result<f32>,
        disp: Option<&Disparity>,
        report: &mut Report,
    ) -> Result<f32> {
        let f = match focus {
            Focus::Disparity(f) => render::check_focus("render.focus", f)?,
            Focus::At(x, y) => disparity_at(x, y)?,
            Focus::Depth(z) => match disp {
                Some(d) => d.disparity_of_depth(z)?,
                None => return Err(Error::usage("render.focus_depth needs a depth map; with given layers use render.focus")),
            },
        };
        let (f, clamped) = render::focus_in_range("render.focus", f);
        report.warnings.extend(clamped);
        Ok(f)
    }

    /// Runs segmentation, depth filling, inpainting and rendering on a decoded scene.
    pub fn run(&self, scene: &Scene, focus: Focus) -> Result<Outcome> {
        self.run_with(scene, focus, BuildLayers::WhenRendered)
    }

    /// [`Pipeline::run`]; with [`BuildLayers::Always`], the layers are built even when nothing
    /// is out of focus and rendering is skipped (for `--save-layers`); with
    /// [`BuildLayers::Only`], they are built and not rendered.
    pub fn run_with(&self, scene: &Scene, focus: Focus, build: BuildLayers) -> Result<Outcome> {
        let t0 = Instant::now();
        let cfg = &self.config;
        let (w, h) = (scene.rgb.width, scene.rgb.height);
        let disp = &scene.disparity.map;
        let mut report = Report::default();
        if scene.disparity.filled_fraction > 0.0 {
            report.warnings.push(format!(
                "{:.2}% of the depth map was invalid (NaN, Inf or <= 0) and was filled from valid neighbours",
                scene.disparity.filled_fraction * 100.0
            ));
        }
        let focus = Self::resolve_focus(focus, |x, y| scene.disparity.disparity_at(x, y), Some(&scene.disparity), &mut report)?;
        let blur = self.blur_for(w, h);
        let max_coc = disp.data.par_iter().map(|&d| lens::coc_radius(d - focus, blur)).reduce(|| 0.0, f32::max);

        // Nothing is out of focus: the photo is its own answer (unless a kernel is asked for).
        let sharp = nothing_out_of_focus(cfg.render.kernel, max_coc);
        if let (Some(why), BuildLayers::WhenRendered) = (&sharp, build) {
            for name in ["highlights", "segment", "fill_depth", "inpaint", "slice", "render"] {
                report.skipped(name, why.clone());
            }
            report.params = self.params((w, h), (blur, focus, 0), "none", 0, max_coc);
            report.total_ms = ms_since(t0);
            return Ok(Outcome { image: scene.rgb.clone(), layers: Vec::new(), report });
        }

        // The light of clipped highlights, before anything is layered or filled.
        let t = Instant::now();
        let recovered = light_recovery::recover(
            &scene.rgb,
            scene.encoding,
            &cfg.highlights,
            &cfg.onnx,
            Some(light_recovery::Occluders { disparity: disp, matte: scene.matte.as_ref() }),
        )?;
        // `auto` changes integer photos only, which hold nothing above white: what it put there
        // is a light (it lifts light-sized blobs only; `boost` and a model lift skies and walls
        // too, which must stay fill sources).
        if let Recovered::Changed(_, r) | Recovered::Examined(r) = &recovered
            && r.over_budget > 0
        {
            report.warnings.push(format!(
                "highlights: {} clipped blobs could be lights; the {} largest were fitted and the rest left as they are (raise [highlights] max_lights to fit more)",
                cfg.highlights.max_lights + r.over_budget,
                cfg.highlights.max_lights
            ));
        }
        let lights_above = matches!(&recovered, Recovered::Changed(_, r) if r.mode == light_recovery::HighlightMode::Auto).then_some(1.0);
        let rgb = match &recovered {
            Recovered::Changed(img, r) => {
                report.ran("highlights", t, serde_json::to_value(r).ok());
                img
            }
            Recovered::Examined(r) => {
                report.ran("highlights", t, serde_json::to_value(r).ok());
                &scene.rgb
            }
            Recovered::Unchanged(why) => {
                report.skipped("highlights", *why);
                &scene.rgb
            }
        };

        let single = |report: &mut Report, why: &str| -> Result<Vec<Layer<'static>>> {
            for name in ["fill_depth", "inpaint", "slice"] {
                report.skipped(name, why.to_string());
            }
            Ok(vec![Layer::from_parts(rgb, &Image::filled(w, h, 1, 1.0), disp, "scene")?])
        };

        let layers = if !cfg.render.occlusion {
            report.skipped("segment", NO_OCCLUSION_ONE_LAYER);
            single(&mut report, NO_OCCLUSION_ONE_LAYER)?
        } else {
            let t = Instant::now();
            let mut seg_model = None;
            let seg = match (cfg.segment.method, &scene.matte) {
                (SegmentMethod::Onnx, _) => {
                    let (s, r) = crate::stages::segment_onnx::from_model(&scene.rgb, &cfg.segment.onnx, &cfg.onnx)?;
                    report.warnings.extend(r.warnings.iter().cloned());
                    seg_model = Some(r);
                    s
                }
                (SegmentMethod::Matte, None) => return Err(Error::usage("segment.method = \"matte\" needs a matte (the scene has none)")),
                (SegmentMethod::Auto | SegmentMethod::Matte, Some(m)) => segment::from_matte(m),
                _ => segment::from_disparity(disp, &cfg.segment),
            };
            let source = if seg_model.is_some() {
                "onnx"
            } else if scene.matte.is_some() && cfg.segment.method != SegmentMethod::Depth {
                "matte"
            } else {
                "depth split"
            };
            match seg {
                Segmentation::SingleLayer(why) => {
                    report.ran("segment", t, Some(serde_json::json!({"source": source, "layers": 1, "why": why, "model": seg_model})));
                    single(&mut report, &format!("one layer: {why}"))?
                }
                Segmentation::Foreground(_) if cfg.segment.layers == LayerCount::Fixed(1) => {
                    let why = "segment.layers = 1";
                    report.ran("segment", t, Some(serde_json::json!({"source": source, "layers": 1, "why": why, "model": seg_model})));
                    single(&mut report, why)?
                }
                Segmentation::Foreground(alpha) => {
                    let (alpha, refined) = self.refine_matte(rgb, disp, alpha, source == "matte");
                    // A binary matte from the user says no pixel outside it is mixed with the
                    // subject: its edge band is background, kept as the photo has it.
                    let binary = source == "matte" && alpha.data.par_iter().all(|&a| a == 0.0 || a == 1.0);
                    let edge_band =
                        if binary && cfg.inpaint.edge_band == EdgeBand::Tested { EdgeBand::Kept } else { cfg.inpaint.edge_band };
                    let fg_frac = alpha.sum() / alpha.data.len() as f64;
                    report.ran(
                        "segment",
                        t,
                        Some(serde_json::json!({
                            "source": source,
                            "layers": 2,
                            "foreground_fraction": fg_frac,
                            "model": seg_model,
                            "refine": refined
                        })),
                    );
                    self.peel_layers((rgb, disp), alpha, (focus, blur, max_coc), (edge_band, lights_above), &mut report)?
                }
            }
        };
        if let Some(why) = sharp.as_deref().or((build == BuildLayers::Only).then_some(LAYERS_ONLY)) {
            report.skipped("render", why);
            report.params = self.params((w, h), (blur, focus, 0), "none", layers.len(), max_coc);
            report.total_ms = ms_since(t0);
            let image = if build == BuildLayers::Only {
                self.settings_for(&layers, focus, blur)?;
                Image::new(0, 0, 3)
            } else {
                scene.rgb.clone()
            };
            return Ok(Outcome { image, layers, report });
        }
        let mut out = self.render_prepared(layers, focus, blur, report, LayerOrigin::Built)?;
        out.report.total_ms = ms_since(t0);
        Ok(out)
    }

    /// The layers behind a segmented foreground, front to back: the foreground over the
    /// background behind it, and with `[segment] layers` above 2 (or "auto") the background
    /// peeled further at the cuts of [`slices::background_cuts`], each slice over what it hides.
    /// Reports `fill_depth` and `inpaint` for the foreground's peel and a `slice` stage for the
    /// rest.
    fn peel_layers(
        &self,
        (rgb, disp): (&Image, &Image),
        alpha: Image,
        (focus, blur, max_coc): (f32, f32, f32),
        (edge_band, lights_above): (EdgeBand, Option<f32>),
        report: &mut Report,
    ) -> Result<Vec<Layer<'static>>> {
        let cfg = &self.config;
        let t = Instant::now();
        // The foreground's depth-edge ramp, when the cuts need it first (what they leave out);
        // else the peel measures it beside its colour carry.
        let edges = (cfg.segment.layers.most() > 2).then(|| self.edge_widths(disp, &alpha));
        let edges_ms = ms_since(t);
        let t = Instant::now();
        let cuts = if let Some(edges) = edges {
            // The visible background, less the band where a soft depth map still ramps towards
            // the foreground's depth (its values belong to neither population).
            let hard = hard_mask(&alpha, &cfg.fill_depth);
            let near = crate::stages::mask::dilate(&hard, alpha.width, alpha.height, edges.outside_px + 1.0);
            let background: Vec<bool> = near.iter().map(|&n| !n).collect();
            slices::background_cuts(disp, &background, cfg.segment.layers, &cfg.segment)
        } else {
            slices::Cuts::default()
        };
        let cut_ms = ms_since(t);
        // A fill that more slices are cut from must be complete: a pixel left unfilled deep under
        // a layer keeps that layer's depth and would be taken for a nearer slice.
        let whole = !cuts.thresholds.is_empty();
        let spec = PeelSpec { focus, blur, max_coc, whole, what: "foreground layer", edge_band, lights_above };
        let first = self.peel(rgb, disp, alpha, edges, spec, report)?;
        report.stages.push(StageReport::ran("fill_depth", edges_ms + first.fill_ms, Some(first.fill_detail)));
        report.stages.push(StageReport::ran("inpaint", first.inpaint_ms, Some(first.inpaint_detail)));
        let mut layers = vec![first.layer];
        // The scene behind the last peel and the frame its window sits in.
        let mut behind = first.behind;
        let mut frame = (std::borrow::Cow::Borrowed(rgb), std::borrow::Cow::Borrowed(disp));
        if cuts.thresholds.is_empty() {
            let why = cuts.limit.clone().unwrap_or_else(|| format!("segment.layers = {}", cfg.segment.layers));
            report.skipped("slice", why);
        } else {
            let t = Instant::now();
            let mut peeled = Vec::new();
            for (k, &cut) in cuts.thresholds.iter().enumerate() {
                let (rgb, disp) = behind.into_frame(&frame.0, &frame.1);
                let alpha = slices::slice_alpha(&disp, cut, cfg.segment.edge_softness);
                let whole = k + 1 < cuts.thresholds.len();
                let spec =
                    PeelSpec { focus, blur, max_coc, whole, what: "background slice", edge_band: cfg.inpaint.edge_band, lights_above };
                let p = self.peel(&rgb, &disp, alpha, None, spec, report)?;
                peeled.push(serde_json::json!({"cut": cut, "fill_depth": p.fill_detail, "inpaint": p.inpaint_detail}));
                layers.push(p.layer);
                behind = p.behind;
                frame = (std::borrow::Cow::Owned(rgb), std::borrow::Cow::Owned(disp));
            }
            report.stages.push(StageReport::ran(
                "slice",
                ms_since(t) + cut_ms,
                Some(serde_json::json!({"layers": cfg.segment.layers, "cuts": cuts, "slices": peeled})),
            ));
        }
        let t = Instant::now();
        layers.push(behind.into_layer(&frame.0, &frame.1, "background layer")?);
        // The last layer is the inpainting's output: its stacking counts there.
        if let Some(stage) = report.stages.iter_mut().find(|st| st.name == "inpaint") {
            stage.ms += ms_since(t);
        }
        Ok(layers)
    }

    /// The foreground's matte refined on the photo's edges when `[segment] refine` says so for
    /// its source (`stages::matting`; the band is the depth map's measured ramp around the
    /// outline), with what was done (None: as it came).
    fn refine_matte(&self, photo: &Image, disp: &Image, alpha: Image, user_matte: bool) -> (Image, Option<matting::Refined>) {
        if !self.config.segment.refine.applies_to(user_matte) {
            return (alpha, None);
        }
        let edges = self.edge_widths(disp, &alpha);
        let (refined, info) = matting::refine(
            photo,
            &alpha,
            matting::band_for(&edges),
            self.config.segment.edge_softness,
            self.config.segment.refine.solver(),
        );
        (refined, Some(info))
    }

    /// The ramp of `disp` across the outline of `alpha` (`[fill_depth] edges`; none when the
    /// depth map is trusted as given).
    fn edge_widths(&self, disp: &Image, alpha: &Image) -> depth_edges::EdgeWidths {
        let cfg = &self.config;
        match cfg.fill_depth.edges {
            DepthEdges::Snapped => depth_edges::measure(disp, &hard_mask(alpha, &cfg.fill_depth), alpha.width, alpha.height),
            DepthEdges::AsGiven => depth_edges::EdgeWidths::default(),
        }
    }

    /// One peel: the layer of `alpha` in the opaque scene (`photo`, `disp`) and the scene behind
    /// it. Fills the layer's disparity beyond its outline (fill_depth, with the depth map's
    /// ramp `edges` across that outline), inpaints what it hides (as deep as a blur can show
    /// it, or `whole`), and separates colours at its soft edge. With the Telea fill, on the
    /// part of the frame the stages can touch ([`work_box`]) when that is small enough, and
    /// widened to the frame after; PatchMatch and a model see the whole frame.
    /// `edges`: the ramp when the caller measured it already; None: the peel measures it.
    fn peel(
        &self,
        photo: &Image,
        disp: &Image,
        alpha: Image,
        edges: Option<depth_edges::EdgeWidths>,
        spec: PeelSpec,
        report: &mut Report,
    ) -> Result<Peeled> {
        let cfg = &self.config;
        let t = Instant::now();
        // The depth-edge measure and the foreground's colour carry need nothing of each other
        // (nor of the work box): side by side, before the rest. The measure counts in fill_depth.
        let ((edges, edges_ms), carried) = rayon::join(
            || {
                let t = Instant::now();
                (edges.unwrap_or_else(|| self.edge_widths(disp, &alpha)), ms_since(t))
            },
            || self.carry(photo, &alpha),
        );
        let carried = carried?;
        let local = cfg.inpaint.method == crate::stages::inpaint_onnx::InpaintMethod::Telea;
        let margin = work_box::margin(spec.max_coc, &edges, &cfg.fill_depth, &cfg.inpaint);
        let inner = match local.then(|| work_box::work_box(&alpha, margin)).flatten() {
            None => self.peel_frame(photo, disp, (alpha, carried, edges), spec, None, report)?,
            Some(b @ (x0, y0, x1, y1)) => {
                let (bw, bh) = (x1 - x0, y1 - y0);
                let (p, d, a) = (photo.crop(x0, y0, bw, bh), disp.crop(x0, y0, bw, bh), alpha.crop(x0, y0, bw, bh));
                drop(alpha);
                // The carried colour's window lies in the work box (the visible box grown by two).
                let carried = carried.map(|c| EdgeColour { x0: c.x0 - x0, y0: c.y0 - y0, ..c });
                self.peel_frame(&p, &d, (a, carried, edges), spec, Some((photo, disp, b)), report)?
            }
        };
        let fill_ms = inner.fill_ms + edges_ms;
        Ok(Peeled { fill_ms, inpaint_ms: ms_since(t) - fill_ms, ..inner })
    }

    /// The foreground's colour carried over its soft edge ([`carried_colour`], frame
    /// coordinates), or None with `[inpaint] foreground = "photo"`.
    fn carry(&self, photo: &Image, alpha: &Image) -> Result<Option<EdgeColour>> {
        match self.config.inpaint.foreground {
            ForegroundColour::Unmixed => carried_colour(photo, alpha, self.config.inpaint.radius),
            ForegroundColour::Photo => Ok(None),
        }
    }

    /// [`Pipeline::peel`] on the frame it is given (the layer's alpha with its carried edge
    /// colour, [`Pipeline::carry`], in this frame's coordinates, and the depth map's ramp across
    /// its outline), or on a window of a larger frame: with
    /// `within` = (the frame's photo, its disparity, the window), the layer is built frame-sized
    /// (outside the window transparent, see [`work_box::widen_layer`]); the scene behind stays
    /// window-sized.
    fn peel_frame(
        &self,
        photo: &Image,
        disp: &Image,
        (alpha, carried, edges): (Image, Option<EdgeColour>, depth_edges::EdgeWidths),
        spec: PeelSpec,
        within: Option<(&Image, &Image, work_box::Window)>,
        report: &mut Report,
    ) -> Result<Peeled> {
        let PeelSpec { focus, blur, max_coc, whole, what, edge_band, lights_above } = spec;
        let cfg = &self.config;
        let inpaint = InpaintOptions { edge_band, lights_above, ..cfg.inpaint.clone() };
        // Band pixels no blur of this render can reach keep the photo's colour.
        let band = (edges.outside_px, BandReach::Render { disparity: disp, focus, blur });
        let t = Instant::now();
        let classical = cfg.inpaint.method != crate::stages::inpaint_onnx::InpaintMethod::Onnx;
        // Depth filling and the background fill's region tests need none of each other's
        // results: they run side by side. (So the stages' times overlap: fill_depth reports its
        // own, inpaint the rest of the peel's wall time.)
        let ((fd, fill_ms), prepared) = rayon::join(
            || {
                let t = Instant::now();
                let fd = foreground_disparity(disp, &alpha, &cfg.fill_depth, (focus, blur), &edges);
                (fd, ms_since(t))
            },
            || classical.then(|| prepare_background(photo, disp, &alpha, &inpaint, band)),
        );
        let fd = fd?;
        // On a window, the pixels outside it took the quiet disparity: no blur can show them.
        let outside = match (within, fd.quiet) {
            (Some((frame, ..)), Some(_)) => frame.width * frame.height - photo.width * photo.height,
            _ => 0,
        };
        let fill_detail = serde_json::json!({
            "filled_px": fd.filled,
            "skipped_unreachable_px": fd.skipped + outside,
            "reach_px": fd.reach,
            "erode_px": fd.erode,
            "ramp_model": fd.ramp_model,
            "depth_edge_ramp": edges
        });
        // How deep under the layer a value behind it can still be seen: the layer shows what is
        // behind up to its visibility reach inside its outline, and a pixel behind scatters up
        // to σ ≤ max CoC + 1 plus the soft step's tail (disparities stay in [0, 1], so max_coc
        // bounds σ).
        let reach = if whole { Reach::Whole } else { Reach::Seen(fd.visible_reach + (max_coc + 1.0).ceil() + 4.0) };
        // The layer's frame-sized parts are stacked beside the fill (all three are the frame's
        // size by construction).
        let (filled, mut parts) = rayon::join(
            || match prepared {
                Some(p) => Ok((fill_background(p, photo, &alpha, &inpaint, reach)?, None)),
                None => {
                    let (bg, r) = crate::stages::inpaint_onnx::inpaint_background(photo, disp, &alpha, &inpaint, reach, band, &cfg.onnx)?;
                    Ok::<_, Error>((bg, Some(r)))
                }
            },
            || match within {
                None => Image::stack(&[photo, &alpha, &fd.disparity]),
                Some((frame, frame_disp, b)) => work_box::widen_layer(frame, frame_disp, &alpha, &fd.disparity, b, fd.quiet),
            },
        );
        let (mut bg, inpaint_model) = filled?;
        let reach = bg.reach;
        if let Some(r) = &inpaint_model {
            report.warnings.extend(r.warnings.iter().cloned());
        }
        let method = match cfg.inpaint.method {
            crate::stages::inpaint_onnx::InpaintMethod::Telea => "telea",
            crate::stages::inpaint_onnx::InpaintMethod::PatchMatch => "patchmatch",
            crate::stages::inpaint_onnx::InpaintMethod::Onnx => "onnx",
        };
        let (mut edge, unmixed) = unmix_edges(photo, &alpha, carried, &mut bg.rgb);
        // The photo's colour, the separated one on the edge's window: no frame-sized copy.
        if let Some(e) = &mut edge {
            if let Some((_, _, (x0, y0, ..))) = within {
                (e.x0, e.y0) = (e.x0 + x0, e.y0 + y0);
            }
            e.paste_into(&mut parts);
        }
        let layer = Layer::new(parts, what)?;
        // Stacking the layer is part of the stage (at 12.2 MP it was 0.2-0.3 s that no stage
        // counted).
        let inpaint_ms = ms_since(t) - fill_ms;
        let mut inpaint_detail = serde_json::json!({
            "method": method,
            "filled_px": bg.filled,
            "skipped_unreachable_px": bg.skipped,
            "reach_px": if reach.is_finite() { serde_json::json!(reach) } else { serde_json::json!("whole") },
            "edge_band": edge_band,
            "edge_band_px": bg.band.0,
            "edge_band_replaced_px": bg.band.1,
            "highlights_kept_px": bg.highlights_kept,
            "highlights_completed": bg.highlights_completed,
            "foreground_unmixed_px": unmixed,
            "model": inpaint_model
        });
        // The layer's parts and the fill's mask go before the caller stacks the next layer
        // (12.2 MP: 21 bytes per pixel less at the stage's peak).
        let window = match within {
            Some((.., b @ (x0, y0, x1, y1))) => {
                inpaint_detail["work_box"] = serde_json::json!([x0, y0, x1, y1]);
                b
            }
            None => (0, 0, photo.width, photo.height),
        };
        drop((edge, fd, alpha, bg.mask));
        let behind = Behind { rgb: bg.rgb, disparity: bg.disparity, window };
        Ok(Peeled { layer, behind, fill_ms, fill_detail, inpaint_ms, inpaint_detail })
    }

    /// Renders ready-made layers (front first). Colours must be linear; in gamma mode the
    /// caller has already raised them to the gamma. To render the same layers at several foci,
    /// see [`crate::refocus::Refocuser`].
    pub fn render_layers(&self, layers: Vec<Layer<'static>>, focus: Focus) -> Result<Outcome> {
        let (image, report) = self.render_given(&layers, focus, None)?;
        let layers = if self.renders_back_only(&layers) { vec![layers.into_iter().next_back().expect("non-empty")] } else { layers };
        Ok(Outcome { image, layers, report })
    }

    /// Given layers (front first) back unrendered, after the checks a render of them at `focus`
    /// makes ([`BuildLayers::Only`] for given layers): the outcome's image is empty (0x0).
    pub fn check_layers(&self, layers: Vec<Layer<'static>>, focus: Focus) -> Result<Outcome> {
        let t0 = Instant::now();
        let (mut report, focus, blur) = self.given(&layers, focus, None)?;
        self.settings_for(&layers, focus, blur)?;
        report.skipped("render", LAYERS_ONLY);
        report.params = self.params((layers[0].width(), layers[0].height()), (blur, focus, 0), "none", layers.len(), 0.0);
        report.total_ms = ms_since(t0);
        Ok(Outcome { image: Image::new(0, 0, 3), layers, report })
    }

    /// Renders borrowed `layers` (front first) at `focus` and `blur` (None: the configured
    /// blur): [`Pipeline::render_layers`] without giving the layers away (an interactive
    /// refocus, [`crate::view`]). The image (linear RGB) and the report.
    pub fn refocus(&self, layers: &[Layer], focus: Focus, blur: Option<f32>) -> Result<(Image, Report)> {
        self.render_given(layers, focus, blur)
    }

    /// Whether only the back layer of given `layers` is rendered (occlusion off).
    fn renders_back_only(&self, layers: &[Layer]) -> bool {
        !self.config.render.occlusion && layers.len() > 1
    }

    /// [`Pipeline::render_layers`] on borrowed layers (at `blur`, else the configured blur):
    /// the image and the report.
    fn render_given(&self, layers: &[Layer], focus: Focus, blur: Option<f32>) -> Result<(Image, Report)> {
        let t0 = Instant::now();
        let (mut report, focus, blur) = self.given(layers, focus, blur)?;
        let shown = if self.renders_back_only(layers) {
            report.warnings.push("render.occlusion = false renders only the back layer of the given layers".into());
            &layers[layers.len() - 1..]
        } else {
            layers
        };
        let (image, mut report) = self.render_borrowed(shown, focus, blur, report, LayerOrigin::Given)?;
        report.total_ms = ms_since(t0);
        Ok((image, report))
    }

    /// What every use of given layers starts with: a report whose building stages say the
    /// layers were given, the focus resolved on them and the blur (`blur`, checked, else the
    /// configured one). A usage error when there are no layers.
    fn given(&self, layers: &[Layer], focus: Focus, blur: Option<f32>) -> Result<(Report, f32, f32)> {
        let Some(first) = layers.first() else {
            return Err(Error::usage("no layers given"));
        };
        let mut report = Report::default();
        let focus = Self::resolve_focus(focus, |x, y| disparity_at(layers, x, y), None, &mut report)?;
        for name in ["segment", "fill_depth", "inpaint", "slice"] {
            report.skipped(name, "layers were given");
        }
        let blur = match blur {
            Some(k) => render::check_blur("render.blur", k)?,
            None => self.blur_for(first.width(), first.height()),
        };
        Ok((report, focus, blur))
    }

    fn render_prepared(&self, layers: Vec<Layer<'static>>, focus: f32, blur: f32, report: Report, origin: LayerOrigin) -> Result<Outcome> {
        let (image, report) = self.render_borrowed(&layers, focus, blur, report, origin)?;
        Ok(Outcome { image, layers, report })
    }

    /// Renders `layers` (front first) at `focus` and `blur`, adding to `report`.
    fn render_borrowed(&self, layers: &[Layer], focus: f32, blur: f32, mut report: Report, origin: LayerOrigin) -> Result<(Image, Report)> {
        let rc = &self.config.render;
        let (w, h) = (layers[0].width(), layers[0].height());
        let max_coc = render::max_scatter_radius(layers, blur, focus) - 1.0;
        if let (LayerOrigin::Given, Some(why)) = (origin, nothing_out_of_focus(rc.kernel, max_coc)) {
            report.skipped("render", format!("{why}: front-to-back alpha composite"));
            report.params = self.params((w, h), (blur, focus, 0), "none", layers.len(), max_coc);
            return Ok((render::alpha_composite(layers), report));
        }
        let s = self.settings_for(layers, focus, blur)?;
        let lens = s.lens;
        let (kernel, kernel_name) = match rc.kernel {
            KernelChoice::Exact => (Kernel::Exact, "exact".to_string()),
            KernelChoice::Auto | KernelChoice::Fast => (Kernel::Fast { quality: rc.quality }, format!("fast (quality {})", rc.quality)),
        };
        if kernel == Kernel::Exact {
            self.check_exact_cost(w, h, lens, layers, &mut report)?;
        }
        let t = Instant::now();
        // A fully transparent layer adds nothing and hides nothing: skip it.
        let (shown, empty): (Vec<usize>, Vec<usize>) = (0..layers.len()).partition(|&i| !layers[i].is_transparent());
        let image = if shown.is_empty() {
            Image::new(w, h, 3)
        } else {
            let visible: Vec<&Layer> = shown.iter().map(|&i| &layers[i]).collect();
            let (image, stats) = render::render_with_stats(&visible, &s, kernel)?;
            report.ran(
                "render",
                t,
                Some(serde_json::json!({"kernel": kernel_name, "lens": lens, "layers": layers.len(), "skipped_transparent_layers": empty, "per_layer": stats})),
            );
            image
        };
        if shown.is_empty() {
            report.skipped("render", "every layer is fully transparent: the result is black");
        }
        report.params = self.params((w, h), (blur, focus, lens), &kernel_name, layers.len(), max_coc);
        Ok((image, report))
    }

    /// The settings a render of `layers` at `focus` and `blur` uses (the configured lens, else
    /// the one the layers need), checked as every render checks them.
    fn settings_for(&self, layers: &[Layer], focus: f32, blur: f32) -> Result<RenderSettings> {
        let rc = &self.config.render;
        // Red's (or blue's) circle of confusion is the widest with chromatic aberration.
        let lens = rc.lens.unwrap_or_else(|| render::auto_lens(layers, blur * self.aperture.max_channel_scale(), focus));
        let s = RenderSettings { blur, focus, lens, occlusion: rc.occlusion, profile: rc.profile, aperture: self.aperture };
        render::validate(layers, &s)?;
        Ok(s)
    }

    #[allow(clippy::too_many_arguments)]
    /// The exact kernel lists its window's taps (12 bytes each) and visits every one per
    /// pixel: refuse what cannot fit, announce what will take minutes.
    fn check_exact_cost(&self, w: usize, h: usize, lens: usize, layers: &[Layer], report: &mut Report) -> Result<()> {
        let taps = render::aperture::disk_tap_count(lens);
        let shown = layers.iter().filter(|l| !l.is_transparent()).count();
        let bytes = taps.saturating_mul(std::mem::size_of::<render::aperture::Tap>() as u64)
            + (w * h) as u64 * crate::resources::layers_bytes_per_pixel(layers.len());
        crate::resources::check_memory(&format!("the exact kernel's {lens}x{lens} window on {w}x{h} layers"), bytes)?;
        let threads = rayon::current_num_threads();
        let secs = render::exact_seconds((w * h) as u64, lens, shown, threads);
        if secs > LONG_EXACT_SECONDS {
            let when = if secs < 5400.0 { format!("{:.0} minutes", secs / 60.0) } else { format!("{:.1} hours", secs / 3600.0) };
            self.warn_now(
                report,
                format!("the exact kernel will take about {when} here ({w}x{h} pixels x {taps} taps x {shown} layer(s) on {threads} threads); the fast kernel at quality 8 converges to it in a fraction of that"),
            );
        }
        Ok(())
    }

    /// `lens` 0 and kernel "none" when nothing was rendered.
    fn params(
        &self,
        (w, h): (usize, usize),
        (blur, focus, lens): (f32, f32, usize),
        kernel: &str,
        layers: usize,
        max_coc: f32,
    ) -> UsedParams {
        UsedParams {
            width: w,
            height: h,
            blur,
            focus,
            lens,
            kernel: kernel.into(),
            occlusion: self.config.render.occlusion,
            gamma: self.config.render.gamma,
            layers,
            max_coc_radius_px: max_coc,
            threads: rayon::current_num_threads(),
            aperture: self.aperture.label(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::render;

    /// A 256×192 textured scene with a small subject (a disk and a 2 px bar at disparity 0.85,
    /// a soft matte edge and a half-transparent patch inside) over a slanted background with
    /// HDR highlights next to the subject and far from it; the depth map sharp or smoothed (so
    /// that the depth-edge ramp model runs).
    fn small_subject(smoothed: bool) -> (Image, Image, Image) {
        let (w, h) = (256usize, 192usize);
        let mut seed = 21u64;
        let mut rnd = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut rgb = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| 0.2 + 0.4 * rnd()).collect()).unwrap();
        let (mut alpha, mut disp) = (Image::new(w, h, 1), Image::new(w, h, 1));
        for y in 0..h {
            for x in 0..w {
                let r = ((x as f32 - 64.0).powi(2) + (y as f32 - 70.0).powi(2)).sqrt();
                let disk = (18.5 - r).clamp(0.0, 1.0);
                let bar = if (70..73).contains(&y) && (64..100).contains(&x) { 1.0 } else { 0.0 };
                let mut a = f32::max(disk, bar);
                if (60..64).contains(&x) && (66..70).contains(&y) {
                    a = 0.5;
                }
                alpha.data[y * w + x] = a;
                disp.data[y * w + x] = if a > 0.5 { 0.85 } else { 0.2 + 0.1 * x as f32 / w as f32 };
            }
        }
        for &(x, y) in &[(84usize, 60usize), (45, 88), (200, 150)] {
            rgb.data[(y * w + x) * 3..(y * w + x) * 3 + 3].copy_from_slice(&[30.0, 25.0, 20.0]);
        }
        if smoothed {
            disp = crate::stages::mask::gaussian_blur(&disp, 2.0);
        }
        (rgb, alpha, disp)
    }

    /// The peel on its work box gives the same layers' render, bit for bit, as the peel on the
    /// whole frame (exact and fast kernels, subject in focus and far out of focus, sharp and
    /// smoothed depth), the same background layer and the same counts.
    #[test]
    fn peeling_on_the_work_box_matches_the_whole_frame() {
        let p = Pipeline::from_config(Config::default()).unwrap();
        for smoothed in [false, true] {
            let (rgb, alpha, disp) = small_subject(smoothed);
            for (focus, blur) in [(0.85f32, 12.0f32), (0.2, 24.0)] {
                let edges = p.edge_widths(&disp, &alpha);
                let mut report = Report::default();
                let spec =
                    PeelSpec { focus, blur, max_coc: blur, whole: false, what: "fg", edge_band: EdgeBand::Tested, lights_above: None };
                let boxed = p.peel(&rgb, &disp, alpha.clone(), None, spec, &mut report).unwrap();
                let carried = p.carry(&rgb, &alpha).unwrap();
                let whole = p.peel_frame(&rgb, &disp, (alpha.clone(), carried, edges), spec, None, &mut report).unwrap();
                let case = format!("smoothed {smoothed}, focus {focus}, blur {blur}");
                assert!(boxed.inpaint_detail.get("work_box").is_some(), "{case}: the work box was not used");
                assert_eq!(boxed.fill_detail, whole.fill_detail, "{case}");
                let (bg_box, bg_whole) =
                    (boxed.behind.into_layer(&rgb, &disp, "bg").unwrap(), whole.behind.into_layer(&rgb, &disp, "bg").unwrap());
                assert!(bg_box.image().data == bg_whole.image().data, "{case}: background layers differ");
                let s = RenderSettings {
                    blur,
                    focus,
                    lens: 2 * blur as usize + 5,
                    occlusion: true,
                    profile: lens::Profile::Physical,
                    aperture: crate::render::Aperture::DISC,
                };
                for kernel in [Kernel::Exact, Kernel::Fast { quality: 2 }] {
                    let a = render(&[boxed.layer.clone(), bg_box.clone()], &s, kernel).unwrap();
                    let b = render(&[whole.layer.clone(), bg_whole.clone()], &s, kernel).unwrap();
                    assert!(a.data == b.data, "{case}, {kernel:?}: renders differ");
                }
            }
        }
    }

    /// `BuildLayers::Only` builds the very layers a render builds, renders nothing (its image is
    /// empty, its report says why) and still refuses what a render of them would refuse.
    #[test]
    fn layers_only_are_the_rendered_layers_without_the_render() {
        let (rgb, matte, map) = small_subject(false);
        let scene = Scene {
            rgb,
            disparity: crate::stages::depth::Disparity { map, z_range: None, filled_fraction: 0.0 },
            matte: Some(matte),
            encoding: PhotoEncoding::Linear,
        };
        let p = Pipeline::from_config(Config::default()).unwrap();
        let focus = Focus::Disparity(0.2);
        let full = p.run_with(&scene, focus, BuildLayers::Always).unwrap();
        let only = p.run_with(&scene, focus, BuildLayers::Only).unwrap();
        assert_eq!(full.layers.len(), 2);
        assert_eq!(only.layers.len(), full.layers.len());
        for (a, b) in only.layers.iter().zip(&full.layers) {
            assert!(a.image().data == b.image().data, "the layers differ");
        }
        assert_eq!((only.image.width, only.image.height), (0, 0));
        let stage = |r: &Report, n: &str| r.stages.iter().find(|s| s.name == n).map(|s| (s.status, s.reason.clone())).unwrap();
        assert_eq!(stage(&full.report, "render").0, StageStatus::Ran);
        assert_eq!(stage(&only.report, "render"), (StageStatus::Skipped, Some(LAYERS_ONLY.to_string())));
        // Given layers: returned as they are, unrendered.
        let given = p.check_layers(full.layers.clone(), focus).unwrap();
        assert_eq!(given.layers.len(), 2);
        assert_eq!(stage(&given.report, "render"), (StageStatus::Skipped, Some(LAYERS_ONLY.to_string())));
        // A lens the render would refuse is refused without rendering.
        let mut cfg = Config::default();
        cfg.render.lens = Some(100_001);
        let wide = Pipeline::from_config(cfg).unwrap();
        let e = wide.run_with(&scene, focus, BuildLayers::Only).err().expect("a lens wider than the image is refused");
        assert!(e.to_string().contains("render.lens"), "{e}");
        assert!(wide.check_layers(full.layers, focus).is_err());
    }
}
