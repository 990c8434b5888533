//! The `dfd` subcommand (depth from defocus): flag parsing, the progress bar and the summary;
//! the work is in `drbokeh::diff::dfd_job`.

use crate::{ApertureArgs, ProfileArg, as_flags, flag_names, print_json, set_threads};
use clap::{Args, ValueEnum};
use drbokeh::Error;
use drbokeh::diff::dfd::{self, DfdKernel, DfdOptions, Event, LossVariant};
use drbokeh::diff::dfd_job::{self, DfdJob};
use drbokeh::io::ReadLimits;
use drbokeh::render::RenderSettings;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::PathBuf;

/// `--loss`: the objectives of the paper's loss ablation.
// The names are the flag values (l1-grad, l1-grad-ssim, l1-grad-hssim), one prefix on purpose.
#[allow(clippy::enum_variant_names)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum LossArg {
    /// L1 + gradient smoothness.
    L1Grad,
    /// L1 + gradient smoothness + SSIM (11x11 window).
    L1GradSsim,
    /// L1 + gradient smoothness + hierarchical SSIM (windows 3, 5, 11, 21, 31): Eqn. 7.
    L1GradHssim,
}

impl From<LossArg> for LossVariant {
    fn from(l: LossArg) -> LossVariant {
        match l {
            LossArg::L1Grad => LossVariant::L1Grad,
            LossArg::L1GradSsim => LossVariant::L1GradSsim,
            LossArg::L1GradHssim => LossVariant::L1GradHssim,
        }
    }
}

/// `--kernel`: which differentiable render is inverted.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum DfdKernelArg {
    /// `ray` where it applies (physical profile, occlusion), at the finest size whose run fits
    /// the time budget (about 30 s on 2 cores at worst); `fast` otherwise.
    Auto,
    /// Spans, depth groups interpolated between depth bins (either profile).
    Fast,
    /// The exact kernel, tap by tap (O(pixels·lens²) per step).
    Exact,
    /// The exact kernel with the ray test for sources behind a target (physical profile only;
    /// O(pixels·lens²) per step).
    Ray,
}

impl From<DfdKernelArg> for DfdKernel {
    fn from(k: DfdKernelArg) -> DfdKernel {
        match k {
            DfdKernelArg::Auto => DfdKernel::Auto,
            DfdKernelArg::Fast => DfdKernel::Fast,
            DfdKernelArg::Exact => DfdKernel::Exact,
            DfdKernelArg::Ray => DfdKernel::Ray,
        }
    }
}

#[derive(Args)]
pub struct DfdArgs {
    /// The all-in-focus photo: PNG/JPEG/TIFF (8/16-bit, sRGB; clipped lights are recovered
    /// and checked against the defocused photos) or EXR/NPY (linear).
    aif: PathBuf,
    /// The same view focused at --focus with blur --blur (same formats, same size). More than
    /// one: a focal stack, each photo focused at its own --focus value (in the same order).
    #[arg(required = true, num_args = 1..)]
    bokeh: Vec<PathBuf>,
    /// Focal plane of each BOKEH photo as normalized disparity (0 far … 1 near): one value per
    /// photo (`--focus 0.5 1` or `--focus 0.5,1`).
    #[arg(long, required = true, num_args = 1.., value_delimiter = ',', allow_negative_numbers = true)]
    focus: Vec<f32>,
    /// Blur strength K of BOKEH: CoC radius in pixels per unit of normalized disparity.
    #[arg(long, value_name = "K", allow_hyphen_values = true)]
    blur: f32,
    /// Output disparity map, in the units of --focus (not re-normalized): .npy (H x W
    /// float32) or .exr (channel Y).
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
    // The counts and the step size are parsed signed (a negative value reaches the library's
    // rule, whose message names the flag, instead of clap's "unexpected argument '-1'").
    /// Adam steps per resolution level (1 to 100000).
    #[arg(long, value_name = "N", default_value_t = DfdOptions::default().iters as i64, allow_negative_numbers = true)]
    iters: i64,
    /// Resolution levels, coarse to fine (each half the size of the next); 1 = full size only.
    /// Capped where a level would be under 8 px a side (with a warning when asked for more than
    /// the photo has) or blur no pixel by 2 px.
    #[arg(long, value_name = "N", default_value_t = DfdOptions::default().levels as i64, allow_negative_numbers = true)]
    levels: i64,
    /// Adam's step size, in normalized disparity.
    #[arg(long, value_name = "LR", default_value_t = DfdOptions::default().learning_rate, allow_negative_numbers = true)]
    learning_rate: f32,
    /// The disparity every pixel starts from. A start within half a pixel of blur of the focal
    /// plane cannot move: it is replaced (half-way out on the side with more room), with a
    /// warning.
    #[arg(long, value_name = "D", default_value_t = DfdOptions::default().init, allow_hyphen_values = true)]
    init: f32,
    /// Lens calibration of the renderer inverted.
    #[arg(long, value_enum, default_value = "physical")]
    profile: ProfileArg,
    /// The objective (the paper's Table 2 variants).
    #[arg(long, value_enum, default_value = "l1-grad-hssim")]
    loss: LossArg,
    /// Invert the classical scatter without occlusion terms (the ablation).
    #[arg(long)]
    no_occlusion: bool,
    /// The differentiable render: auto, fast (spans), exact (tap by tap) or ray (exact with
    /// the ray test, physical profile).
    #[arg(long, value_enum, default_value = "auto")]
    kernel: DfdKernelArg,
    /// Write the loss terms of every step to this CSV (level, size, iteration, terms).
    #[arg(long, value_name = "CSV")]
    log: Option<PathBuf>,
    /// Write a plot of the loss per step (one curve per level) to this PNG.
    #[arg(long, value_name = "PNG")]
    plot: Option<PathBuf>,
    /// Also write where the map can be trusted, in [0, 1] (.npy, .exr or 16-bit .png): low
    /// where the all-in-focus photo has no texture at the blur's scale, and within half a pixel
    /// of blur of the focal plane (where any depth looks the same).
    #[arg(long, value_name = "OUT")]
    confidence: Option<PathBuf>,
    /// Worker threads [default: all cores].
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    threads: Option<i64>,
    /// Print a machine-readable summary (JSON) to stdout.
    #[arg(long)]
    json: bool,
    // The lens's aperture, as the photos were taken (a coded aperture makes depth better
    // posed): a shape other than the disc, or chromatic aberration, is inverted with the exact
    // kernel (`auto` picks exact or ray; `fast` draws the plain disc only).
    #[command(flatten)]
    aperture: ApertureArgs,
}

pub fn dfd(args: DfdArgs) -> anyhow::Result<()> {
    let threads = args
        .threads
        .map(|n| usize::try_from(n).map_err(|_| Error::usage(format!("--threads must be a count of worker threads >= 1, got {n}"))))
        .transpose()?;
    set_threads(threads)?;
    // SIGINT/SIGTERM: remove the temporary output files, exit 130.
    let _ = ctrlc::set_handler(|| {
        eprintln!("\ninterrupted");
        drbokeh::io::atomic::remove_in_flight_temps_and_exit(130);
    });
    let options = DfdOptions {
        iters: dfd::check_iters("dfd.iters", args.iters).map_err(as_flags)?,
        levels: dfd::check_levels("dfd.levels", args.levels).map_err(as_flags)?,
        learning_rate: args.learning_rate,
        init: args.init,
        weights: LossVariant::from(args.loss).weights(),
        kernel: args.kernel.into(),
        ..DfdOptions::default()
    };
    if args.focus.len() != args.bokeh.len() {
        return Err(Error::usage(format!(
            "{} defocused photo(s) but {} --focus value(s): give one focal plane per photo, in the same order",
            args.bokeh.len(),
            args.focus.len()
        ))
        .into());
    }
    let mut shots = args.bokeh.into_iter().zip(args.focus);
    let (bokeh, focus) = shots.next().expect("clap requires one photo");
    let job = DfdJob {
        aif: args.aif,
        bokeh,
        stack: shots.collect(),
        output: args.output,
        log: args.log,
        plot: args.plot,
        confidence: args.confidence,
        settings: RenderSettings {
            blur: args.blur,
            focus,
            lens: 1,
            occlusion: !args.no_occlusion,
            profile: args.profile.into(),
            aperture: args.aperture.config().resolve().map_err(as_flags)?,
        },
        options,
        limits: ReadLimits::default(),
    };
    // The length comes with the plan (the levels the photo allows).
    let bar = ProgressBar::new(0);
    bar.set_style(ProgressStyle::with_template("dfd {bar:40} {pos}/{len} steps, {msg} ({elapsed}, eta {eta})").expect("template"));
    let mut report = dfd_job::run(&job, |e| match e {
        Event::Plan(p) => bar.set_length(p.steps as u64),
        // At once: a long run is announced before it starts.
        Event::Warning(m) => bar.suspend(|| eprintln!("warning: {}", flag_names(m))),
        Event::Step(s) => {
            bar.inc(1);
            bar.set_message(format!("level {} loss {:.5}", s.level, s.loss));
        }
    })
    .map_err(as_flags)?;
    bar.finish_and_clear();
    // The report speaks the library's names too: the JSON gets the flags.
    for w in &mut report.warnings {
        *w = flag_names(w);
    }
    if args.json {
        print_json(&report)?;
    } else {
        let (a, b, d) = (&report.first, &report.last, &report.disparity);
        eprintln!(
            "{}x{}, kernel {} at {}x{}: loss {:.5} -> {:.5} (L1 {:.5} -> {:.5}) at that size; disparity {:.3} .. {:.3}, mean {:.3}; {:.1} s ({} threads)",
            report.width,
            report.height,
            report.plan.kernel.name(),
            report.plan.width,
            report.plan.height,
            a.loss,
            b.loss,
            a.l1,
            b.l1,
            d.min,
            d.max,
            d.mean,
            report.total_ms / 1000.0,
            report.threads
        );
        for p in std::iter::once(&report.output).chain(&report.log).chain(&report.plot) {
            eprintln!("wrote {}", p.display());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every `--loss` name is the library's name of the variant it maps to.
    #[test]
    fn loss_flags_agree_with_the_library() {
        for arg in LossArg::value_variants() {
            let pv = arg.to_possible_value().expect("no hidden variants");
            assert_eq!(pv.get_name(), LossVariant::from(*arg).name());
        }
    }
}
