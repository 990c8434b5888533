//! One render job: files in, file out. The CLI's `render` and `batch` both run jobs through
//! [`run`], so reading, size checks, the pipeline, `--save-layers` and the atomic write are
//! written once.

use crate::color::Transfer;
use crate::config::Config;
use crate::error::{Error, Result};
use crate::focus_pull::{FocusPull, FramePattern};
use crate::image::Image;
use crate::io::{self, ReadLimits};
use crate::pipeline::{BuildLayers, DepthSource, Focus, Outcome, Pipeline, Report, Scene, StageReport};
use crate::render::Layer;
use crate::report::MatteSource;
use crate::stages::depth;
use crate::timing::ms_since;
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The files of one job and where its result goes.
#[derive(Clone, Debug)]
pub struct Job {
    /// The photo (PNG/JPEG/TIFF/EXR/NPY, HEIC with libheif); None with `layers`.
    pub image: Option<PathBuf>,
    /// Its depth map; None: the depth map the photo embeds (Dynamic Depth, GDepth or a HEIC's
    /// depth image, unless `input.embedded_depth = false`), else the configured depth model.
    pub depth: Option<PathBuf>,
    /// Its optional foreground matte; None: the matte a HEIC photo embeds, if any (unless
    /// `input.embedded_matte = false`).
    pub matte: Option<PathBuf>,
    /// Ready-made layers (front first) instead of image + depth.
    pub layers: Vec<PathBuf>,
    /// Where the focal plane is.
    pub focus: Focus,
    /// The result file; its extension picks the format (png, exr, npy).
    pub output: PathBuf,
    /// Folder to write the rendered layers to (see [`save_layers`]), if any.
    pub save_layers: Option<PathBuf>,
    /// A focus pull instead of one render: `output` is then the frames' pattern
    /// ([`crate::focus_pull`]) and `focus` is not used.
    pub pull: Option<FocusPull>,
}

impl Job {
    /// Every input file of the job.
    pub fn inputs(&self) -> Vec<PathBuf> {
        self.image.iter().chain(&self.depth).chain(&self.matte).chain(&self.layers).cloned().collect()
    }
}

/// Reads the job's inputs, runs `pipeline` and writes the output atomically. Returns the
/// report (stages, timings, warnings, output path).
pub fn run(pipeline: &Pipeline, job: &Job) -> Result<Report> {
    let t0 = Instant::now();
    // A focus pull builds its layers once, at the frame that reveals most ([`FocusPull::build_settings`]).
    let pull = match &job.pull {
        Some(p) => {
            p.check()?;
            Some((p, FramePattern::parse(&job.output)?))
        }
        None => None,
    };
    let build_pipeline;
    let (pipeline, focus) = match &pull {
        Some((p, _)) => {
            // Without a blur range every frame has the configured blur (the size default when
            // unset): only the focus decides, and any K ranks the frames alike.
            let mut cfg = pipeline.config().clone();
            let (f, k) = p.build_settings(cfg.render.blur.unwrap_or(1.0));
            if p.blur.is_some() {
                cfg.render.blur = Some(k);
            }
            build_pipeline = Pipeline::from_config(cfg)?;
            (&build_pipeline, Focus::Disparity(f))
        }
        None => (pipeline, job.focus),
    };
    let cfg: &Config = pipeline.config();
    let output = &job.output;
    let inputs = io::InputFiles::new(job.inputs());
    match &pull {
        Some((p, pattern)) => {
            for i in 0..p.frames {
                inputs.check_write(&pattern.path(i), "output")?;
            }
        }
        None => inputs.check_write(output, "output")?,
    }
    if let Some(dir) = &job.save_layers {
        check_layer_folder(dir)?;
        // Every name the layers may get (the pipeline makes one up to `[segment] layers`),
        // before the run spends any time; `save_layers` checks again what it actually writes.
        for n in (1..=cfg.segment.layers.most().max(2)).chain([job.layers.len()]) {
            for file in layer_file_names(dir, n).iter().flat_map(LayerFiles::all) {
                inputs.check_write(file, "job.save_layers file")?;
                io::check_distinct(&[(output, "output"), (file, "job.save_layers file")])?;
            }
        }
    }
    let format = io::OutputFormat::from_path(output)?;
    preflight(job, cfg)?;
    // A focus pull renders its frames from the layers; a render at the job's focus is not kept.
    let build = match (&pull, &job.save_layers) {
        (Some(_), _) => BuildLayers::Only,
        (None, Some(_)) => BuildLayers::Always,
        (None, None) => BuildLayers::WhenRendered,
    };
    let (outcome, read_warnings) = read_and_run(pipeline, job, focus, build)?;
    let Outcome { mut image, layers, mut report } = outcome;
    report.warnings.splice(0..0, read_warnings);
    if cfg.output.bit_depth != io::BitDepth::Eight && format != io::OutputFormat::Png {
        report.warnings.push(format!(
            "a bit depth of {} (output.bit_depth) applies to PNG outputs only; {} is written as 32-bit float",
            cfg.output.bit_depth.bits(),
            output.display()
        ));
    }

    if let Some(dir) = &job.save_layers {
        let t = Instant::now();
        report.warnings.extend(save_layers(dir, &layers, &inputs)?);
        report.stages.push(StageReport::ran("save_layers", ms_since(t), None));
    }

    if let Some((p, pattern)) = &pull {
        report.frames = render_frames(cfg, p, pattern, layers, &mut report.warnings)?;
        report.stages.push(StageReport::ran("frames", report.frames.iter().map(|f| f.ms).sum(), None));
        report.total_ms = ms_since(t0);
        return Ok(report);
    }
    let t_write = Instant::now();
    write_image(output, &mut image, cfg)?;
    report.stages.push(StageReport::ran("write", ms_since(t_write), None));
    report.output = Some(output.display().to_string());
    report.total_ms = ms_since(t0);
    Ok(report)
}

/// Reads the job's inputs (photo, depth map or the photo's own, matte; or layers) and runs
/// `pipeline` on them at `focus`, the layers built as `build` says: the outcome and what the
/// reading found worth a warning (ignored options first). The output is not written.
fn read_and_run(pipeline: &Pipeline, job: &Job, mut focus: Focus, build: BuildLayers) -> Result<(Outcome, Vec<String>)> {
    let cfg: &Config = pipeline.config();
    let limits = ReadLimits { max_pixels: cfg.input.max_pixels };
    let transfer = cfg.render.gamma.map(Transfer::Gamma).unwrap_or(Transfer::Srgb);
    let mut read_warnings = ignored_options(job, cfg);
    let t_read = Instant::now();
    let outcome: Outcome = if !job.layers.is_empty() {
        // The files side by side (each EXR read is sequential in part: its chunks come from the
        // file in order); the first error in the layers' order is the one reported.
        let read: Vec<Result<io::LayerFile>> = job.layers.par_iter().map(|p| io::read_layer_file(p, &limits)).collect();
        let layers = job
            .layers
            .iter()
            .zip(read)
            .map(|(p, file)| {
                let file = file?;
                read_warnings.extend(file.warnings);
                let mut l = Layer::new(file.image, &p.display().to_string())?;
                if let Some(g) = cfg.render.gamma {
                    // The official inference raises colours in double precision.
                    l.map_colors(|c| (c.max(0.0) as f64).powf(g as f64) as f32);
                }
                Ok(l)
            })
            .collect::<Result<Vec<_>>>()?;
        let read_ms = ms_since(t_read);
        let mut out =
            if build == BuildLayers::Only { pipeline.check_layers(layers, focus)? } else { pipeline.render_layers(layers, focus)? };
        out.report.stages.insert(0, StageReport::ran("read", read_ms, None));
        out
    } else {
        let image_path = job.image.as_ref().ok_or_else(|| Error::usage("a job needs an image (or layers)"))?;
        // The three files side by side: each decoder is sequential in part (a PNG's inflate),
        // so one file's decode overlaps another's. Errors are reported in the order the files
        // are used (photo, depth, matte), as one after the other would. Without a depth file,
        // the photo's embedded depth map is read beside the photo.
        let (rgb, (depth_read, matte_file)) = rayon::join(
            || io::read_photo_file(image_path, transfer, &limits),
            || {
                rayon::join(
                    || match &job.depth {
                        Some(p) => DepthRead::File(io::read_depth_map(p, &limits)),
                        None if cfg.input.embedded_depth => {
                            DepthRead::Embedded(io::embedded::read_embedded(image_path, &limits).map(|e| e.map(Box::new)))
                        }
                        None => DepthRead::Off,
                    },
                    || match &job.matte {
                        Some(p) => MatteRead::File(io::read_matte(p, &limits)),
                        None if cfg.input.embedded_matte && io::detect_format(image_path).ok() == Some(io::FileFormat::Heif) => {
                            MatteRead::Embedded(io::heif_depth::read_matte(image_path, &limits))
                        }
                        None => MatteRead::None,
                    },
                )
            },
        );
        let io::Photo { image: rgb, encoding, warnings } = rgb?;
        read_warnings.extend(warnings);
        let mut depth_stage = None;
        let (disparity, source) = match depth_read {
            DepthRead::File(map) => {
                let depth_path = job.depth.as_ref().expect("a depth file was read");
                let map = map?;
                read_warnings.extend(map.warnings);
                let source = DepthSource::File {
                    path: depth_path.display().to_string(),
                    width: map.image.width,
                    height: map.image.height,
                    bit_depth: map.bit_depth,
                };
                // Normalized (holes filled) at the map's own size, then resized: a hole (NaN,
                // a depth of 0) must not be averaged into its neighbours.
                let mut disparity = depth::normalize(&map.image, cfg.input.depth_kind, depth_path)?;
                if disparity.is_flat() {
                    read_warnings.push(flat_warning(&depth_path.display().to_string()));
                    focus = Focus::Disparity(disparity.map.data[0]);
                }
                disparity.map = fit_to(disparity.map, &rgb, depth_path, image_path, &mut read_warnings)?;
                (disparity, source)
            }
            DepthRead::Embedded(Ok(Some(e))) => {
                // Metric depth, normalized and resized as a depth file of the same values is
                // (the embedded map is usually smaller than the photo: no warning for that).
                read_warnings.extend(e.warnings);
                if cfg.input.depth_kind != depth::DepthKind::Depth {
                    read_warnings.push(format!(
                        "input.depth_kind = \"disparity\" is ignored: the depth map embedded in {} holds metric depth",
                        image_path.display()
                    ));
                }
                let mut disparity = depth::normalize(&e.depth, depth::DepthKind::Depth, image_path)?;
                if disparity.is_flat() {
                    read_warnings.push(flat_warning(&format!("the depth map embedded in {}", image_path.display())));
                    focus = Focus::Disparity(disparity.map.data[0]);
                }
                if !crate::io::embedded_depth::same_aspect((e.depth.width, e.depth.height), (rgb.width, rgb.height)) {
                    return Err(Error::input(
                        image_path,
                        format!(
                            "{}: the embedded depth image is {}x{} but the photo is {}x{} (a different aspect ratio)",
                            e.info.data_field(),
                            e.depth.width,
                            e.depth.height,
                            rgb.width,
                            rgb.height
                        ),
                    ));
                }
                disparity.map = disparity.map.resized(rgb.width, rgb.height);
                let source = DepthSource::Embedded { path: image_path.display().to_string(), info: Box::new(e.info) };
                (disparity, source)
            }
            DepthRead::Embedded(Err(e)) => return Err(e),
            read @ (DepthRead::Embedded(Ok(None)) | DepthRead::Off) => {
                let why = match read {
                    DepthRead::Off => format!("input.embedded_depth = false ignores any depth map {} embeds", image_path.display()),
                    _ => match io::detect_format(image_path)? {
                        io::FileFormat::Jpeg => format!("{} embeds no depth map (no Dynamic Depth or GDepth XMP)", image_path.display()),
                        io::FileFormat::Heif => format!("{} embeds no depth map (no HEIF depth image)", image_path.display()),
                        _ => format!(
                            "{} embeds no depth map (embedded depth is read from JPEG photos: Dynamic Depth, GDepth XMP; and HEIC photos)",
                            image_path.display()
                        ),
                    },
                };
                // The configured depth model predicts relative disparity.
                let t = Instant::now();
                let (d, r) = crate::stages::depth_onnx::estimate_without_depth_map(&rgb, &cfg.depth.onnx, &cfg.onnx, &why)?;
                read_warnings.extend(r.warnings.iter().cloned());
                let source = DepthSource::Model { model: r.model.clone(), preset: r.preset.clone() };
                let detail = serde_json::to_value(&r).ok();
                depth_stage = Some(StageReport::ran("depth_model", ms_since(t), detail));
                (d, source)
            }
        };
        let (matte, matte_source) = match matte_file {
            MatteRead::File(m) => {
                let p = job.matte.as_ref().expect("a matte file was read");
                let m = m?;
                let source = MatteSource::File { path: p.display().to_string(), width: m.width, height: m.height };
                (Some(fit_to(m, &rgb, p, image_path, &mut read_warnings)?), Some(source))
            }
            MatteRead::Embedded(m) => match m? {
                // The embedded matte is usually smaller than the photo (half size on iPhones):
                // resized without a warning, as the embedded depth map is.
                Some(e) => {
                    let source = MatteSource::Embedded { path: image_path.display().to_string(), info: Box::new(e.info) };
                    (Some(e.matte.resized(rgb.width, rgb.height)), Some(source))
                }
                None => (None, None),
            },
            MatteRead::None => (None, None),
        };
        let read_ms = ms_since(t_read);
        let mut out = pipeline.run_with(&Scene { rgb, disparity, matte, encoding }, focus, build)?;
        if let Some(s) = depth_stage {
            out.report.stages.insert(0, s);
        }
        out.report.depth_source = Some(source);
        out.report.matte_source = matte_source;
        out.report.stages.insert(0, StageReport::ran("read", read_ms, None));
        out
    };
    Ok((outcome, read_warnings))
}

/// The layers of a job's scene (front first), built for `focus` with `pipeline`'s settings,
/// and the report of their making (stages, warnings, depth source). Nothing is written: what
/// `drbokeh view` serves from, and what `--save-layers` of a render at that focus writes.
pub fn build_layers(pipeline: &Pipeline, job: &Job, focus: Focus) -> Result<(Vec<Layer<'static>>, Report)> {
    preflight(job, pipeline.config())?;
    let (outcome, warnings) = read_and_run(pipeline, job, focus, BuildLayers::Only)?;
    let Outcome { layers, mut report, .. } = outcome;
    report.warnings.splice(0..0, warnings);
    Ok((layers, report))
}

/// Prepares a rendered `image` (linear RGB) for display as `drbokeh render` writes it: in
/// gamma mode (`render.gamma`) the inverse gamma is applied and the PNG stores the values as
/// they are (`Transfer::Linear`); otherwise the image stays and the PNG encodes sRGB. Returns
/// the transfer a PNG of it uses.
pub fn display_transfer(image: &mut Image, cfg: &Config) -> Transfer {
    match cfg.render.gamma {
        Some(g) => {
            image.map_inplace(|v| v.max(0.0).powf(1.0 / g));
            Transfer::Linear
        }
        None => Transfer::Srgb,
    }
}

/// Writes a rendered `image` (linear RGB) to `output`, atomically, as `drbokeh render` does
/// ([`display_transfer`], `output.bit_depth` for a PNG).
pub fn write_image(output: &Path, image: &mut Image, cfg: &Config) -> Result<()> {
    let transfer = display_transfer(image, cfg);
    io::write_output(output, image, cfg.output.bit_depth.bits(), transfer)
}

/// The frames of a focus pull from `layers` (built once), each rendered by a
/// [`crate::refocus::Refocuser`] and written atomically to its file of `pattern`; the frames'
/// warnings (each once) go to `warnings`.
fn render_frames(
    cfg: &Config,
    pull: &FocusPull,
    pattern: &FramePattern,
    layers: Vec<Layer<'static>>,
    warnings: &mut Vec<String>,
) -> Result<Vec<crate::pipeline::FrameReport>> {
    if layers.is_empty() {
        return Err(Error::Internal("a focus pull's layers were not built".into()));
    }
    let (w, h) = (layers[0].width(), layers[0].height());
    let blur = cfg.render.blur.unwrap_or_else(|| crate::pipeline::default_blur(w, h));
    let refocuser = crate::refocus::Refocuser::new(Pipeline::from_config(cfg.clone())?, layers)?;
    let mut frames = Vec::with_capacity(pull.frames);
    for i in 0..pull.frames {
        let t = Instant::now();
        let (focus, k) = pull.frame(i, blur);
        let (mut image, r) = refocuser.render_with_blur(Focus::Disparity(focus), k)?;
        for m in r.warnings {
            if !warnings.contains(&m) {
                warnings.push(m);
            }
        }
        let path = pattern.path(i);
        write_image(&path, &mut image, cfg)?;
        frames.push(crate::pipeline::FrameReport { output: path.display().to_string(), focus, blur: k, ms: ms_since(t) });
    }
    Ok(frames)
}

/// What was read for a photo's depth.
enum DepthRead {
    /// The depth file (`job.depth`).
    File(Result<io::DepthMap>),
    /// The photo's embedded depth map, if it has one.
    Embedded(Result<Option<Box<io::embedded_depth::EmbeddedDepth>>>),
    /// No depth file, and `input.embedded_depth = false`.
    Off,
}

/// Where a job's matte is read from.
enum MatteRead {
    /// A matte file (`--matte`).
    File(Result<Image>),
    /// The photo's embedded matte, if it has one (a HEIF photo without `--matte`).
    Embedded(Result<Option<io::heif_depth::EmbeddedMatte>>),
    /// None.
    None,
}

/// The warning for a depth map (`what`) with no depth range.
fn flat_warning(what: &str) -> String {
    // One plane: in focus wherever the focus is asked to be.
    format!("{what} has no depth range (every valid value is the same): the photo is one plane, taken as in focus; nothing is blurred")
}

/// The options set away from their defaults that this job cannot use, one warning each (in
/// the library's names): what segments and fills a photo means nothing for given layers, or
/// for the one-layer scatter without occlusion.
fn ignored_options(job: &Job, cfg: &Config) -> Vec<String> {
    let why = if !job.layers.is_empty() {
        "the layers are given (job.layers)"
    } else if !cfg.render.occlusion {
        "render.occlusion = false renders the scene as one layer"
    } else {
        return Vec::new();
    };
    let set = [
        (cfg.segment.layers != Default::default(), "segment.layers"),
        (cfg.segment.method != Default::default(), "segment.method"),
        (cfg.inpaint.method != Default::default(), "inpaint.method"),
        (job.matte.is_some(), "job.matte"),
        // One layer still gets the photo's light back; given layers are linear already.
        (!job.layers.is_empty() && cfg.highlights != Default::default(), "highlights"),
    ];
    set.iter().filter(|(on, _)| *on).map(|(_, key)| format!("{key} is ignored: {why}")).collect()
}

/// Cheap checks before anything is decoded or rendered, from file headers and the file
/// system: the output folder is writable, depth map and matte have the photo's aspect ratio,
/// and the run fits in the memory available.
fn preflight(job: &Job, cfg: &Config) -> Result<()> {
    for input in job.inputs() {
        io::check_regular_file(&input)?;
    }
    check_writable_folder(&job.output)?;
    if let Some(dir) = &job.save_layers
        && dir.is_dir()
    {
        check_writable_folder(&dir.join("x"))?;
    }
    let probe = io::inspect::probe_size;
    if let Some((image, (w, h))) = job.image.as_ref().and_then(|p| probe(p).map(|d| (p, d))) {
        for map in job.depth.iter().chain(&job.matte) {
            if let Some((mw, mh)) = probe(map) {
                check_aspect((mw as usize, mh as usize), (w as usize, h as usize), map, image)?;
            }
        }
        let pixels = w.saturating_mul(h).min(cfg.input.max_pixels);
        let need = pixels.saturating_mul(crate::resources::RENDER_BYTES_PER_PIXEL);
        crate::resources::check_memory(&format!("{} ({w}x{h}) through the pipeline", image.display()), need)?;
    } else if let Some((first, (w, h))) = job.layers.first().and_then(|p| probe(p).map(|d| (p, d))) {
        let need = w.saturating_mul(h).saturating_mul(crate::resources::layers_bytes_per_pixel(job.layers.len()));
        crate::resources::check_memory(&format!("{} layers of {w}x{h} (as {})", job.layers.len(), first.display()), need)?;
    }
    Ok(())
}

/// Refuses an output whose folder is missing or not writable, by creating and removing a
/// probe file there (permissions alone miss read-only mounts and ACLs).
fn check_writable_folder(output: &Path) -> Result<()> {
    let dir = io::folder_of(output);
    if !dir.is_dir() {
        return Err(Error::input(dir, format!("the folder of the output {} does not exist", output.display())));
    }
    let probe = dir.join(format!(".drbokeh-probe-{}", std::process::id()));
    match std::fs::OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        // A probe left by a killed run with our pid: the folder is writable.
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(Error::input(dir, format!("cannot write the output {} here: {e}", output.display()))),
    }
}

/// Refuses a depth map or matte of `map` size whose aspect ratio differs from the photo's
/// `rgb` size by more than 1%, naming both files.
fn check_aspect(map: (usize, usize), rgb: (usize, usize), path: &Path, image_path: &Path) -> Result<()> {
    if !io::embedded_depth::same_aspect(map, rgb) {
        return Err(Error::input(
            path,
            format!("is {}x{} but the image {} is {}x{} (a different aspect ratio)", map.0, map.1, image_path.display(), rgb.0, rgb.1),
        ));
    }
    Ok(())
}

/// Brings a depth map or matte to the photo's size: an equal aspect ratio is resized with a
/// warning, a different one is an error naming both files.
pub fn fit_to(map: Image, rgb: &Image, path: &Path, image_path: &Path, warnings: &mut Vec<String>) -> Result<Image> {
    if (map.width, map.height) == (rgb.width, rgb.height) {
        return Ok(map);
    }
    check_aspect((map.width, map.height), (rgb.width, rgb.height), path, image_path)?;
    warnings.push(format!("{} is {}x{}; resized to the image's {}x{}", path.display(), map.width, map.height, rgb.width, rgb.height));
    Ok(map.resized(rgb.width, rgb.height))
}

/// The files `--save-layers` writes for one layer.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerFiles {
    /// R, G, B, A, D in linear light: feed back with `--layer`.
    pub exr: PathBuf,
    /// Previews: sRGB colour, alpha, 16-bit disparity.
    pub color: PathBuf,
    /// Preview of the layer's alpha (8-bit grey PNG).
    pub alpha: PathBuf,
    /// Preview of the layer's disparity (16-bit grey PNG, 0 far … 1 near).
    pub disparity: PathBuf,
}

impl LayerFiles {
    /// The four paths.
    pub fn all(&self) -> [&Path; 4] {
        [&self.exr, &self.color, &self.alpha, &self.disparity]
    }
}

/// Names of the files of `n` layers in `dir`, front first: `0_fg`, `1_bg` for the pipeline's
/// two layers (`0_bg` for one, `00_layer` … for more), each as `NAME.exr` plus
/// `NAME_color.png`, `NAME_alpha.png` and `NAME_disparity.png`. The index leads, zero-padded,
/// so a shell glob (`--layer DIR/*.exr`) lists the layers front to back.
pub fn layer_file_names(dir: &Path, n: usize) -> Vec<LayerFiles> {
    let stems: Vec<String> = match n {
        2 => vec!["0_fg".into(), "1_bg".into()],
        1 => vec!["0_bg".into()],
        n => {
            let digits = n.saturating_sub(1).max(1).to_string().len();
            (0..n).map(|i| format!("{i:0digits$}_layer")).collect()
        }
    };
    stems
        .into_iter()
        .map(|s| LayerFiles {
            exr: dir.join(format!("{s}.exr")),
            color: dir.join(format!("{s}_color.png")),
            alpha: dir.join(format!("{s}_alpha.png")),
            disparity: dir.join(format!("{s}_disparity.png")),
        })
        .collect()
}

/// Refuses a `--save-layers` destination that exists and is not a folder (the layers are
/// several files).
pub fn check_layer_folder(dir: &Path) -> Result<()> {
    match std::fs::metadata(dir) {
        Ok(m) if !m.is_dir() => Err(Error::usage(format!(
            "job.save_layers {} is a file: it must be a folder (created if missing) to write the layers into",
            dir.display()
        ))),
        _ => Ok(()),
    }
}

/// True for a file name that [`layer_file_names`] gives for some layer count: `0_fg`, `1_bg`,
/// `0_bg` or `N_layer` (digits), then `.exr`, `_color.png`, `_alpha.png` or `_disparity.png`.
fn is_layer_file_name(name: &str) -> bool {
    let Some(stem) = [".exr", "_color.png", "_alpha.png", "_disparity.png"].iter().find_map(|s| name.strip_suffix(s)) else {
        return false;
    };
    matches!(stem, "0_fg" | "1_bg" | "0_bg")
        || stem.strip_suffix("_layer").is_some_and(|i| !i.is_empty() && i.bytes().all(|b| b.is_ascii_digit()))
}

/// Writes each layer (see [`layer_file_names`]); refuses, before writing anything, a file
/// name that is one of the run's `inputs`. Layer files of an earlier run in `dir` that this
/// run does not write (another layer count) are removed after the new ones are written, so
/// that `--layer DIR/*.exr` renders this run's layers only; one that is an input of this run
/// is kept. Returns a warning for each file removed or kept.
pub fn save_layers(dir: &Path, layers: &[Layer], inputs: &io::InputFiles) -> Result<Vec<String>> {
    let files = layer_file_names(dir, layers.len());
    inputs.check_writes(files.iter().flat_map(LayerFiles::all), "job.save_layers file")?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    for (f, l) in files.iter().zip(layers) {
        let img = l.image();
        io::write_exr(&f.exr, img, &["R", "G", "B", "A", "D"])?;
        io::write_png(&f.color, &img.select_channels(&[0, 1, 2]), 8, Transfer::Srgb)?;
        io::write_png(&f.alpha, &img.channel(3), 8, Transfer::Linear)?;
        io::write_png(&f.disparity, &img.channel(4), 16, Transfer::Linear)?;
    }
    let written: Vec<&Path> = files.iter().flat_map(LayerFiles::all).collect();
    let mut stale: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .flatten()
        .filter(|e| e.file_type().is_ok_and(|t| t.is_file()) && is_layer_file_name(&e.file_name().to_string_lossy()))
        .map(|e| e.path())
        .filter(|p| !written.iter().any(|w| io::same_destination(w, p)))
        .collect();
    stale.sort();
    let mut warnings = Vec::new();
    for p in stale {
        if inputs.contains(&p) {
            warnings.push(format!(
                "{} is a layer file of an earlier run and an input of this one: kept (a glob of {} picks it up too)",
                p.display(),
                dir.display()
            ));
        } else {
            std::fs::remove_file(&p).map_err(|e| Error::io(&p, e))?;
            warnings.push(format!(
                "removed {}: a layer file of an earlier run that this run's {} layer(s) replace",
                p.display(),
                layers.len()
            ));
        }
    }
    Ok(warnings)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name the layers get is recognised as a layer file (so a later run can clear it),
    /// and nothing else is.
    #[test]
    fn layer_file_names_are_recognised() {
        for n in [1, 2, 3, 8, 11] {
            for f in layer_file_names(Path::new("d"), n) {
                for p in f.all() {
                    assert!(is_layer_file_name(&p.file_name().unwrap().to_string_lossy()), "{}", p.display());
                }
            }
        }
        for other in ["photo.png", "0_fg.png", "_layer.exr", "a_layer.exr", "0_fg_color.jpg", "x0_bg.exr", "1_fg.exr"] {
            assert!(!is_layer_file_name(other), "{other}");
        }
    }

    /// A later run with fewer layers removes the earlier run's extra layer files, except one
    /// that is an input of the later run (`--layer DIR/2_layer.exr` saved back into DIR): that
    /// one is kept, with a warning, and nothing else of it survives.
    #[test]
    fn save_layers_removes_stale_layers_but_keeps_an_input() {
        let dir = tempfile::tempdir().unwrap();
        let layer = |v: f32| {
            let img = Image::filled(4, 3, 3, v);
            Layer::from_parts(&img, &Image::filled(4, 3, 1, 1.0), &Image::filled(4, 3, 1, v), "t").unwrap()
        };
        let three = [layer(0.1), layer(0.2), layer(0.3)];
        save_layers(dir.path(), &three, &io::InputFiles::default()).unwrap();
        let third = &layer_file_names(dir.path(), 3)[2];
        assert!(third.all().iter().all(|p| p.exists()));
        // The later run reads the third layer's EXR (under another name, through `..`).
        let alias = dir.path().join(".").join(third.exr.file_name().unwrap());
        let warnings = save_layers(dir.path(), &[layer(0.4), layer(0.5)], &io::InputFiles::new([&alias])).unwrap();
        assert!(third.exr.exists(), "the input was removed: {warnings:?}");
        for p in [&third.color, &third.alpha, &third.disparity] {
            assert!(!p.exists(), "{} was kept: {warnings:?}", p.display());
        }
        for f in &layer_file_names(dir.path(), 3)[..2] {
            assert!(f.all().iter().all(|p| !p.exists()), "3-layer names of the first two layers were kept: {warnings:?}");
        }
        assert_eq!(warnings.iter().filter(|w| w.contains("kept")).count(), 1, "{warnings:?}");
        assert_eq!(warnings.iter().filter(|w| w.starts_with("removed")).count(), 3 + 2 * 4, "{warnings:?}");
        assert!(layer_file_names(dir.path(), 2).iter().all(|f| f.all().iter().all(|p| p.exists())));
    }
}
