//! CLI glue of `drbokeh batch` (the work is in `drbokeh::batch`).

use crate::{PipelineArgs, as_flags, config_from, flag_names, parse_xy, set_threads};
use clap::Args;
use drbokeh::batch::{self, BatchOptions, ItemResult, Status};
use drbokeh::pipeline::Focus;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

#[derive(Args)]
pub struct BatchArgs {
    /// Folder of photos; each NAME.{png,jpg,jpeg,tif,tiff,exr} needs NAME.depth.* or NAME_depth.*
    /// (optional NAME.matte.* / NAME_matte.*); patterns in [batch] of pipeline.toml.
    input_dir: PathBuf,
    /// Output folder (created; subfolders mirrored with --recursive).
    #[arg(short, long, value_name = "OUTPUT_DIR")]
    output: PathBuf,
    /// Focal plane as normalized disparity, for images the manifest does not set.
    #[arg(long, allow_hyphen_values = true, conflicts_with = "focus_at")]
    focus: Option<f32>,
    /// Focus on the surface under pixel X,Y, for images the manifest does not set.
    #[arg(long, value_name = "X,Y", value_parser = parse_xy, allow_hyphen_values = true)]
    focus_at: Option<(i64, i64)>,
    /// Per-image overrides: CSV (columns image,focus,focus_at,blur,matte,output) or TOML
    /// ([[image]] tables with the same keys); image paths relative to INPUT_DIR.
    #[arg(long, value_name = "FILE")]
    manifest: Option<PathBuf>,
    /// The manifest's focus values are keyframes: images it does not focus get a focus
    /// interpolated between the keyframes around them (in sorted order; held before the first
    /// and after the last), as for the frames of a video.
    #[arg(long, requires = "manifest")]
    keyframes: bool,
    /// Smooth the images' focus values over the sequence (a Gaussian of this many seconds at
    /// --fps), so a video's focus does not jitter from frame to frame.
    #[arg(long, value_name = "SECONDS")]
    focus_smoothing: Option<f32>,
    /// Frames per second of the sequence, for --focus-smoothing.
    #[arg(long, value_name = "FPS", default_value_t = 30.0, requires = "focus_smoothing")]
    fps: f32,
    /// Also process subfolders (mirrored in the output folder).
    #[arg(long)]
    recursive: bool,
    /// Images processed at once, or `auto`: one per core when there are images enough and
    /// [batch] memory_budget_mb holds them (fewer for a short batch or large photos). Each
    /// image runs on its own share of the cores (--threads-per-image); --threads caps the
    /// whole batch.
    #[arg(long, value_name = "N|auto", default_value = "auto")]
    jobs: String,
    /// Threads of each image's stages and render, or `auto`: the batch's threads (--threads,
    /// else one per core) split evenly among the images in flight, at least one each.
    #[arg(long, value_name = "N|auto", default_value = "auto")]
    threads_per_image: String,
    /// Redo images whose output is up to date (same inputs and parameters).
    #[arg(long)]
    force: bool,
    /// Process only slice I of N (0-based), by sorted path: for Slurm arrays, GNU parallel,
    /// Kubernetes indexed jobs.
    #[arg(long, value_name = "I/N", value_parser = batch::parse_shard)]
    shard: Option<(usize, usize)>,
    /// Print the summary as JSON on stdout (no progress bar).
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    opts: PipelineArgs,
}

pub fn batch(args: BatchArgs) -> anyhow::Result<ExitCode> {
    set_threads(args.opts.threads)?;
    let cfg = config_from(&args.opts)?;
    let opts = BatchOptions {
        input_dir: args.input_dir.clone(),
        output_dir: args.output.clone(),
        recursive: args.recursive,
        force: args.force,
        shard: args.shard,
        jobs: parse_count(&args.jobs, "--jobs")?,
        threads_per_image: parse_count(&args.threads_per_image, "--threads-per-image")?,
        focus: args.focus.map(Focus::Disparity).or(args.focus_at.map(|(x, y)| Focus::At(x, y))),
        manifest: args.manifest.clone(),
        keyframes: args.keyframes,
        focus_smoothing: args.focus_smoothing.map(|s| (s, args.fps)),
    };
    // SIGINT/SIGTERM: stop starting images; those in flight finish (their writes are atomic).
    let cancel = Arc::new(AtomicBool::new(false));
    {
        let cancel = cancel.clone();
        let _ = ctrlc::set_handler(move || {
            if cancel.swap(true, Ordering::SeqCst) {
                // The images in flight are abandoned: their temporary files go with them.
                drbokeh::io::atomic::remove_in_flight_temps_and_exit(130);
            }
            eprintln!("\ninterrupted: finishing the images in flight (interrupt again to abort)");
        });
    }
    let fancy = !args.json && std::io::stderr().is_terminal();
    let bar = fancy.then(|| {
        let b = ProgressBar::new(0);
        b.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} {per_sec} eta {eta} {msg}").expect("template"));
        b
    });
    let progress = |done: usize, total: usize, r: &ItemResult| {
        // The summary (file and --json) keeps the library's names; lines for people get flags.
        let line =
            format!("{} {}{}", r.status.as_str(), r.image, r.reason.as_ref().map(|w| format!(": {}", flag_names(w))).unwrap_or_default());
        match &bar {
            Some(b) => {
                b.set_length(total as u64);
                b.set_position(done as u64);
                b.set_message(r.image.clone());
                if r.status == Status::Failed {
                    b.println(line);
                }
            }
            None if !args.json => eprintln!("[{done}/{total}] {line} ({:.1} s)", r.seconds),
            None => {}
        }
    };
    let summary = batch::run(&cfg, &opts, &cancel, &progress).map_err(as_flags)?;
    if let Some(b) = bar {
        b.finish_and_clear();
    }
    if args.json {
        crate::print_json(&summary)?;
    } else {
        eprintln!(
            "{} ok, {} skipped, {} failed{} in {:.1} s ({}); summary in {}",
            summary.ok,
            summary.skipped,
            summary.failed,
            if summary.cancelled > 0 { format!(", {} cancelled", summary.cancelled) } else { String::new() },
            summary.seconds,
            in_flight(&summary.threads_per_image),
            batch::summary_path(&args.output, args.shard).display()
        );
        for r in summary.items.iter().filter(|r| r.status == Status::Failed) {
            eprintln!("  failed {}: {}", r.image, flag_names(r.reason.as_deref().unwrap_or("")));
        }
    }
    Ok(if summary.cancelled > 0 {
        ExitCode::from(130)
    } else if summary.failed > 0 {
        ExitCode::from(3)
    } else {
        ExitCode::SUCCESS
    })
}

/// "4 images at a time, 4 threads each" (or "… 6 or 5 threads each").
fn in_flight(threads: &[usize]) -> String {
    let (lo, hi) = (threads.iter().min().copied().unwrap_or(1), threads.iter().max().copied().unwrap_or(1));
    let each = if lo == hi { format!("{hi}") } else { format!("{hi} or {lo}") };
    let (n, s) = (threads.len(), if hi == 1 { "" } else { "s" });
    format!("{n} image{} at a time, {each} thread{s} each", if n == 1 { "" } else { "s" })
}

/// `--jobs` and `--threads-per-image`: a count (bounded as `--threads`), or `auto` (`None`).
fn parse_count(v: &str, flag: &str) -> anyhow::Result<Option<usize>> {
    if v == "auto" {
        return Ok(None);
    }
    let n = v.parse::<usize>().map_err(|_| drbokeh::Error::usage(format!("{flag} must be a whole number or 'auto', got '{v}'")))?;
    Ok(Some(drbokeh::resources::check_threads(n, flag)?))
}
