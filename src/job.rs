//! One render job: files in, file out. The CLI's `render` and `batch` both run jobs through
//! [`run`], so reading, size checks, the pipeline, `--save-layers` and the atomic write are
//! written once.

use crate::color::Transfer;
use crate::config::Config;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::io::{self, ReadLimits};
use crate::pipeline::{Focus, Outcome, Pipeline, Report, Scene, StageReport};
use crate::render::Layer;
use crate::stages::depth;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The files of one job and where its result goes.
#[derive(Clone, Debug)]
pub struct Job {
    pub image: Option<PathBuf>,
    pub depth: Option<PathBuf>,
    pub matte: Option<PathBuf>,
    /// Ready-made layers (front first) instead of image + depth.
    pub layers: Vec<PathBuf>,
    pub focus: Focus,
    pub output: PathBuf,
    pub save_layers: Option<PathBuf>,
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
    let cfg: &Config = pipeline.config();
    let limits = ReadLimits { max_pixels: cfg.input.max_pixels };
    let transfer = cfg.render.gamma.map(Transfer::Gamma).unwrap_or(Transfer::Srgb);
    let focus = job.focus;
    let output = &job.output;
    check_output(output, &job.inputs())?;
    io::OutputFormat::from_path(output)?;
    let t_read = Instant::now();
    let mut read_warnings = Vec::new();
    let outcome: Outcome = if !job.layers.is_empty() {
        let layers = job
            .layers
            .iter()
            .map(|p| {
                let file = io::read_layer_file(p, &limits)?;
                read_warnings.extend(file.warnings);
                let mut l = Layer::new(file.image, &p.display().to_string())?;
                if let Some(g) = cfg.render.gamma {
                    // The official inference raises colours in double precision.
                    l.map_colors(|c| (c.max(0.0) as f64).powf(g as f64) as f32);
                }
                Ok(l)
            })
            .collect::<Result<Vec<_>>>()?;
        let read_ms = t_read.elapsed().as_secs_f64() * 1e3;
        let mut out = pipeline.render_layers(layers, focus)?;
        out.report.stages.insert(0, stage("read", read_ms));
        out
    } else {
        let image_path = job.image.as_ref().ok_or_else(|| Error::usage("an IMAGE (or --layer) is required"))?;
        let rgb = io::read_photo(image_path, transfer, &limits)?;
        let mut depth_stage = None;
        let disparity = match &job.depth {
            Some(depth_path) => {
                let map = io::read_depth_map(depth_path, &limits)?;
                read_warnings.extend(map.warnings);
                let raw_depth = map.image;
                let raw_depth = fit_to(raw_depth, &rgb, depth_path, image_path, &mut read_warnings)?;
                depth::normalize(&raw_depth, cfg.input.depth_kind, depth_path)?
            }
            None => {
                // No depth map: the configured depth model predicts relative disparity.
                let t = Instant::now();
                let (d, r) = crate::stages::depth_onnx::estimate_without_depth_map(&rgb, &cfg.depth.onnx, &cfg.onnx)?;
                read_warnings.extend(r.warnings.iter().cloned());
                let detail = serde_json::to_value(&r).ok();
                depth_stage = Some(StageReport { name: "depth_model", status: "ran", reason: None, ms: t.elapsed().as_secs_f64() * 1e3, detail });
                d
            }
        };
        let matte = match &job.matte {
            Some(p) => Some(fit_to(io::read_matte(p, &limits)?, &rgb, p, image_path, &mut read_warnings)?),
            None => None,
        };
        let read_ms = t_read.elapsed().as_secs_f64() * 1e3;
        let mut out = pipeline.run_with(&Scene { rgb, disparity, matte }, focus, job.save_layers.is_some())?;
        if let Some(s) = depth_stage {
            out.report.stages.insert(0, s);
        }
        out.report.stages.insert(0, stage("read", read_ms));
        out
    };
    let Outcome { mut image, layers, mut report } = outcome;
    report.warnings.splice(0..0, read_warnings);

    if let Some(dir) = &job.save_layers {
        let t = Instant::now();
        save_layers(dir, &layers)?;
        report.stages.push(stage("save_layers", t.elapsed().as_secs_f64() * 1e3));
    }

    let t_write = Instant::now();
    let png_transfer = match cfg.render.gamma {
        Some(g) => {
            image.map_inplace(|v| v.max(0.0).powf(1.0 / g));
            Transfer::Linear
        }
        None => Transfer::Srgb,
    };
    io::write_output(output, &image, cfg.output.bit_depth, png_transfer)?;
    report.stages.push(stage("write", t_write.elapsed().as_secs_f64() * 1e3));
    report.output = Some(output.display().to_string());
    report.total_ms = t0.elapsed().as_secs_f64() * 1e3;
    Ok(report)
}

pub(crate) fn stage(name: &'static str, ms: f64) -> StageReport {
    StageReport { name, status: "ran", reason: None, ms, detail: None }
}

/// Refuses an output that would overwrite an input.
pub fn check_output(output: &Path, inputs: &[PathBuf]) -> Result<()> {
    let canon = |p: &Path| std::fs::canonicalize(p).ok();
    if let Some(out) = canon(output) {
        for i in inputs {
            if canon(i).as_deref() == Some(out.as_path()) {
                return Err(Error::usage(format!("output {} is also an input; choose another -o", output.display())));
            }
        }
    }
    Ok(())
}

/// Brings a depth map or matte to the photo's size: an equal aspect ratio is resized with a
/// warning, a different one is an error naming both files.
pub fn fit_to(map: Image, rgb: &Image, path: &Path, image_path: &Path, warnings: &mut Vec<String>) -> Result<Image> {
    if (map.width, map.height) == (rgb.width, rgb.height) {
        return Ok(map);
    }
    let (a, b) = (map.width as f64 / map.height as f64, rgb.width as f64 / rgb.height as f64);
    if (a / b - 1.0).abs() > 0.01 {
        return Err(Error::input(
            path,
            format!("is {}x{} but the image {} is {}x{} (a different aspect ratio)", map.width, map.height, image_path.display(), rgb.width, rgb.height),
        ));
    }
    warnings.push(format!("{} is {}x{}; resized to the image's {}x{}", path.display(), map.width, map.height, rgb.width, rgb.height));
    Ok(map.resized(rgb.width, rgb.height))
}

/// Writes each layer as `layerN.exr` (R,G,B,A,D; feed back with --layer) plus PNG previews.
pub fn save_layers(dir: &Path, layers: &[Layer]) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let names: Vec<String> = match layers.len() {
        2 => vec!["fg".into(), "bg".into()],
        1 => vec!["bg".into()],
        n => (0..n).map(|i| format!("layer{i}")).collect(),
    };
    for (name, l) in names.iter().zip(layers) {
        let img = l.image();
        io::write_exr(&dir.join(format!("{name}.exr")), img, &["R", "G", "B", "A", "D"])?;
        io::write_png(&dir.join(format!("{name}_color.png")), &img.select_channels(&[0, 1, 2]), 8, Transfer::Srgb)?;
        io::write_png(&dir.join(format!("{name}_alpha.png")), &img.channel(3), 8, Transfer::Linear)?;
        io::write_png(&dir.join(format!("{name}_disparity.png")), &img.channel(4), 16, Transfer::Linear)?;
    }
    Ok(())
}
