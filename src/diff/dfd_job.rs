//! `drbokeh dfd` as a library call: reads the photos, runs [`dfd::estimate_stack`], writes the
//! disparity map (NPY or EXR, float32, atomically), the per-step loss log (CSV) and the loss
//! plot (PNG), and returns a report. No file is written over an input
//! ([`io::InputFiles`]), and nothing is written before the inputs are read and checked.
//!
//! Cost: the optimisation's (see [`dfd`]); the log and plot are O(steps).

use super::dfd::{self, DfdOptions, Event, Shot, Step, level_size};
use crate::color::{PhotoEncoding, Transfer};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::io::{self, OutputFormat, ReadLimits};
use crate::plot::{self, Point, Series, Ticks, XAxis};
use crate::render::{Profile, RenderSettings};
use crate::timing::ms_since;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The header of the loss log: one row per Adam step, terms unweighted (`loss` is the
/// weighted total that is minimised).
pub const LOG_HEADER: &str = "level,width,height,iter,loss,l1,smoothness,ssim";

/// One depth-from-defocus run, files in and out.
#[derive(Clone, Debug)]
pub struct DfdJob {
    /// The all-in-focus photo (any format `render` reads; integer formats are sRGB).
    pub aif: PathBuf,
    /// The photo of the same view focused at `settings.focus` with blur `settings.blur`.
    pub bokeh: PathBuf,
    /// More photos of the focal stack, each with the normalized disparity it is focused at
    /// (same view, size and blur); empty for one photo.
    pub stack: Vec<(PathBuf, f32)>,
    /// The disparity map to write: `.npy` (H x W float32) or `.exr` (channel Y).
    pub output: PathBuf,
    /// The loss log to write (CSV, [`LOG_HEADER`]), if any.
    pub log: Option<PathBuf>,
    /// The loss plot to write (PNG), if any.
    pub plot: Option<PathBuf>,
    /// The confidence map to write ([`crate::diff::dfd_confidence`]; `.npy`, `.exr` or a
    /// 16-bit `.png`), if any.
    pub confidence: Option<PathBuf>,
    /// Focus, blur K, profile and occlusion of the render being inverted (`lens` is ignored:
    /// see [`dfd::estimate`]).
    pub settings: RenderSettings,
    /// The optimisation's options.
    pub options: DfdOptions,
    /// Size limits of the photos.
    pub limits: ReadLimits,
}

/// Summary statistics of the estimated disparity.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Range {
    /// Smallest value.
    pub min: f32,
    /// Mean value.
    pub mean: f32,
    /// Largest value.
    pub max: f32,
}

/// What a [`run`] did (serialized as `drbokeh dfd --json`).
#[derive(Clone, Debug, serde::Serialize)]
pub struct DfdReport {
    /// The all-in-focus photo read.
    pub aif: PathBuf,
    /// The defocused photo read.
    pub bokeh: PathBuf,
    /// The focal stack's other photos and their foci as used (clamped to [0, 1]).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub stack: Vec<(PathBuf, f32)>,
    /// The disparity map written.
    pub output: PathBuf,
    /// The loss log written, if any.
    pub log: Option<PathBuf>,
    /// The loss plot written, if any.
    pub plot: Option<PathBuf>,
    /// The confidence map written, if any, and its mean.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub confidence: Option<(PathBuf, f32)>,
    /// Photo width, pixels.
    pub width: usize,
    /// Photo height, pixels.
    pub height: usize,
    /// Focal plane of the defocused photo (normalized disparity), as used: clamped to [0, 1]
    /// (with a warning).
    pub focus: f32,
    /// Blur K of the defocused photo (pixels per unit of disparity).
    pub blur: f32,
    /// The lens profile of the renderer inverted.
    pub profile: Profile,
    /// False for the no-occlusion ablation.
    pub occlusion: bool,
    /// The aperture the photos were taken with, as `--aperture` spells it with its options
    /// (`disc` by default; see [`crate::render::Aperture::label`]).
    pub aperture: String,
    /// The optimisation's options (`kernel` as given: `auto` by default).
    pub options: DfdOptions,
    /// How the estimate ran: the differentiable render (`auto` resolved), the size it
    /// optimised at before resizing to the photo's, the levels and the estimated cost (see
    /// [`dfd::plan`]).
    pub plan: dfd::DfdPlan,
    /// Adam steps run, all levels together.
    pub steps: usize,
    /// The first step's losses at the finest level (full size unless `plan` says otherwise):
    /// those of the map that level started from.
    pub first: Step,
    /// The losses of the map returned, at the finest level (evaluated after the last update).
    pub last: Step,
    /// What the user should know (a clamped focus, capped levels, a long run, a start that
    /// could not move, a photo that cannot tell the map or its near/far side), naming the
    /// parameters.
    pub warnings: Vec<String>,
    /// The estimated disparity's range.
    pub disparity: Range,
    /// Worker threads.
    pub threads: usize,
    /// Wall time of the whole run, ms.
    pub total_ms: f64,
}

/// Above this share of a photo's pixels at white, `dfd` warns that the depth near them is less
/// certain ([`clipped_warning`]).
pub const CLIPPED_WARN: f64 = 0.001;

/// The warning for an integer photo with more than [`CLIPPED_WARN`] of its pixels at white (a
/// channel at the largest code): the light there is unknown, so neither photo says how a light
/// spreads, and on the bench 8-bit pairs cost the estimate most on scenes with bright lights
/// (`bench --dfd --inputs`, docs/dfd.md). None for linear photos.
fn clipped_warning(path: &Path, photo: &io::Photo) -> Option<String> {
    let PhotoEncoding::Integer { bits, transfer } = photo.encoding else { return None };
    let (img, white) = (&photo.image, transfer.decode(1.0));
    let n = img.data.chunks_exact(img.channels).filter(|px| px.iter().any(|&v| v >= white)).count();
    let share = n as f64 / (img.width * img.height).max(1) as f64;
    (share > CLIPPED_WARN).then(|| {
        format!(
            "{}: {n} pixels ({:.1}%) are at white in its {bits}-bit samples: their light is unknown, so the depth near them is less certain (a linear EXR keeps it)",
            path.display(),
            100.0 * share
        )
    })
}

/// Runs `job`: checks the destinations against the inputs (usage error), reads the photos
/// (I/O and input errors name the file), checks they have the same size (usage error naming
/// both files and sizes), estimates the disparity (telling `on` of the plan, each warning and
/// every Adam step as they come: [`dfd::estimate_with`]) and writes the output, the log and
/// the plot.
pub fn run(job: &DfdJob, mut on: impl FnMut(Event)) -> Result<DfdReport> {
    let t0 = Instant::now();
    check_destinations(job)?;
    // Lights clipped at white, said before the estimate. (The photo's own warning, an ignored
    // alpha, advises `render`'s --matte: not passed on here.)
    let mut told = Vec::new();
    let mut read = |path: &Path, on: &mut dyn FnMut(Event)| -> Result<(Image, PhotoEncoding)> {
        let photo = io::read_photo_file(path, Transfer::Srgb, &job.limits)?;
        if let Some(m) = clipped_warning(path, &photo) {
            on(Event::Warning(&m));
            told.push(m);
        }
        Ok((photo.image, photo.encoding))
    };
    let (aif, aif_encoding) = read(&job.aif, &mut on)?;
    let shots: Vec<(&PathBuf, f32)> =
        std::iter::once((&job.bokeh, job.settings.focus)).chain(job.stack.iter().map(|(p, f)| (p, *f))).collect();
    let mut photos = Vec::with_capacity(shots.len());
    for (path, _) in &shots {
        let (photo, encoding) = read(path, &mut on)?;
        if (aif.width, aif.height) != (photo.width, photo.height) {
            return Err(Error::usage(format!(
                "the all-in-focus photo {} is {}x{} but the defocused photo {} is {}x{}: they must be the same size",
                job.aif.display(),
                aif.width,
                aif.height,
                path.display(),
                photo.width,
                photo.height
            )));
        }
        photos.push((photo, dfd::clip_level(encoding)));
    }
    let stack: Vec<Shot> = photos.iter().zip(&shots).map(|((photo, clip), &(_, focus))| Shot { photo, focus, clip: *clip }).collect();
    let light = dfd::aif_light(&aif, aif_encoding, &stack, job.settings.blur)?;
    let mut steps = Vec::new();
    let est = dfd::estimate_stack(&light, &stack, &job.settings, &job.options, |e| {
        if let Event::Step(s) = e {
            steps.push(s);
        }
        on(e);
    })?;
    let disparity = &est.disparity;
    io::write_output(&job.output, disparity, 8, Transfer::Linear)?;
    let (w, h) = (aif.width, aif.height);
    if let Some(path) = &job.log {
        io::atomic::write_atomic(path, |f| f.write_all(log_csv(&steps, w, h).as_bytes()).map_err(|e| Error::io(path, e)))?;
    }
    if let Some(path) = &job.plot {
        plot::line_plot(
            path,
            "drbokeh dfd: loss per Adam step",
            &XAxis { title: "iteration (log scale)", ticks: Ticks::Plain },
            "loss",
            &loss_series(&steps, w, h),
        )?;
    }
    let confidence = match &job.confidence {
        Some(path) => {
            let foci: Vec<f32> = shots.iter().map(|&(_, f)| f).collect();
            let c = crate::diff::dfd_confidence::confidence_of_stack(&aif, disparity, job.settings.blur, &foci);
            io::write_output(path, &c, 16, Transfer::Linear)?;
            Some((path.clone(), (c.sum() / c.data.len().max(1) as f64) as f32))
        }
        None => None,
    };
    let n = disparity.data.len().max(1) as f64;
    Ok(DfdReport {
        aif: job.aif.clone(),
        bokeh: job.bokeh.clone(),
        stack: job.stack.iter().map(|(p, f)| (p.clone(), crate::render::focus_in_range("render.focus", *f).0)).collect(),
        output: job.output.clone(),
        log: job.log.clone(),
        plot: job.plot.clone(),
        confidence,
        width: w,
        height: h,
        focus: crate::render::focus_in_range("render.focus", job.settings.focus).0,
        blur: job.settings.blur,
        profile: job.settings.profile,
        occlusion: job.settings.occlusion,
        aperture: job.settings.aperture.label(),
        options: job.options,
        plan: est.plan,
        steps: steps.len(),
        first: est.first,
        last: est.last,
        warnings: told.into_iter().chain(est.warnings.iter().cloned()).collect(),
        disparity: Range {
            min: disparity.data.iter().copied().fold(f32::INFINITY, f32::min),
            mean: (disparity.sum() / n) as f32,
            max: disparity.data.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        },
        threads: rayon::current_num_threads(),
        total_ms: ms_since(t0),
    })
}

/// Refuses, before anything is read or written: a PNG (or unknown) output, two destinations
/// that are the same path, and a destination that is one of the photos.
fn check_destinations(job: &DfdJob) -> Result<()> {
    if OutputFormat::from_path(&job.output)? == OutputFormat::Png {
        return Err(Error::input(
            &job.output,
            "a disparity map is written as float32 .npy or .exr (PNG would quantize it): use .npy or .exr",
        ));
    }
    let dests: Vec<(&Path, &str)> = [
        (Some(&job.output), "output"),
        (job.log.as_ref(), "dfd.log"),
        (job.plot.as_ref(), "dfd.plot"),
        (job.confidence.as_ref(), "dfd.confidence"),
    ]
    .into_iter()
    .filter_map(|(p, what)| p.map(|p| (p.as_path(), what)))
    .collect();
    // As files, not spellings: `o/al.npy` and `./o/al.npy` are one destination.
    io::check_distinct(&dests)?;
    let inputs = io::InputFiles::new([&job.aif, &job.bokeh].into_iter().chain(job.stack.iter().map(|(p, _)| p)));
    dests.iter().try_for_each(|(p, what)| inputs.check_write(p, what))
}

/// The loss log as CSV text: [`LOG_HEADER`], then one row per step.
pub fn log_csv(steps: &[Step], width: usize, height: usize) -> String {
    let mut s = String::from(LOG_HEADER);
    s.push('\n');
    for st in steps {
        let (lw, lh) = level_size(width, height, st.level);
        let _ = writeln!(s, "{},{lw},{lh},{},{},{},{},{}", st.level, st.iter, st.loss, st.l1, st.smoothness, st.ssim);
    }
    s
}

/// One plot series per level (coarsest first): total loss against iteration + 1.
fn loss_series(steps: &[Step], width: usize, height: usize) -> Vec<Series> {
    let mut levels: Vec<usize> = steps.iter().map(|s| s.level).collect();
    levels.sort_unstable_by(|a, b| b.cmp(a));
    levels.dedup();
    levels
        .into_iter()
        .map(|level| {
            let (lw, lh) = level_size(width, height, level);
            Series {
                name: format!("level {level} ({lw}x{lh})"),
                points: steps
                    .iter()
                    .filter(|s| s.level == level)
                    .map(|s| Point { x: (s.iter + 1) as f64, value: s.loss, label: String::new() })
                    .collect(),
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_rows_name_the_level_size() {
        let st = |level, iter| Step { level, iter, loss: 0.5, l1: 0.25, smoothness: 0.125, ssim: 0.0 };
        let csv = log_csv(&[st(1, 0), st(0, 0)], 33, 20);
        assert_eq!(csv, format!("{LOG_HEADER}\n1,16,10,0,0.5,0.25,0.125,0\n0,33,20,0,0.5,0.25,0.125,0\n"));
        let series = loss_series(&[st(1, 0), st(1, 1), st(0, 0)], 33, 20);
        assert_eq!(series.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["level 1 (16x10)", "level 0 (33x20)"]);
        assert_eq!(series[0].points.len(), 2);
    }
}
