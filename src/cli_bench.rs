//! The `trace` and `bench` subcommands: flag parsing and progress display; the work is in
//! `drbokeh::bench::{trace, run}`.

use crate::{ApertureArgs, as_flags, set_threads};
use clap::builder::{PossibleValuesParser, TypedValueParser};
use clap::{Args, ValueEnum};
use drbokeh::Error;
use drbokeh::bench::dfd_eval::{self, DfdBenchOptions, DfdMethod};
use drbokeh::bench::inputs::Input;
use drbokeh::bench::run::{self as bench_run, BenchOptions, Method};
use drbokeh::bench::trace::{self, Footprint, Plane, TraceSettings, Window};
use drbokeh::color::Transfer;
use drbokeh::io::{self, ReadLimits};
use drbokeh::render::Layer;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Clone, Copy, ValueEnum)]
pub enum FootprintArg {
    /// Rays through the pixel centre, planes read bilinearly: the exact pixel-box integral of
    /// box texels (converges fastest).
    Analytic,
    /// Rays spread over the pixel square (stratified), planes read as box texels.
    Sampled,
}

/// `--methods`: the bench's rendering methods, by their short names (the full report names and
/// `no-occlusion` are accepted too, as [`Method::parse`] does).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum MethodArg {
    /// Dr.Bokeh on the exact two layers.
    #[value(alias = "drbokeh-layers")]
    Layers,
    /// Dr.Bokeh on one exact layer per depth plane.
    #[value(alias = "drbokeh-sliced")]
    Sliced,
    /// Dr.Bokeh from the classical pipeline.
    #[value(alias = "drbokeh-pipeline")]
    Pipeline,
    /// Classical scatter without occlusion, one layer.
    #[value(alias = "no-occlusion", alias = "scatter-no-occlusion")]
    Scatter,
    /// Per-pixel gather within its own CoC.
    Gather,
}

/// `--inputs`: what the methods are fed (see [`Input`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum InputArg {
    /// The linear HDR all-in-focus view (the ceiling).
    Linear,
    /// The view as an 8-bit sRGB photo, clipped at white.
    Srgb8,
    /// The same after a camera PSF (Gaussian, σ = 0.7 px) before clipping.
    #[value(name = "srgb8-psf")]
    Srgb8Psf,
}

impl From<InputArg> for Input {
    fn from(i: InputArg) -> Input {
        match i {
            InputArg::Linear => Input::Linear,
            InputArg::Srgb8 => Input::Srgb8,
            InputArg::Srgb8Psf => Input::Srgb8Psf,
        }
    }
}

impl From<MethodArg> for Method {
    fn from(m: MethodArg) -> Method {
        match m {
            MethodArg::Layers => Method::Layers,
            MethodArg::Sliced => Method::Sliced,
            MethodArg::Pipeline => Method::Pipeline,
            MethodArg::Scatter => Method::Scatter,
            MethodArg::Gather => Method::Gather,
        }
    }
}

#[derive(Args)]
pub struct TraceArgs {
    #[command(flatten)]
    aperture: ApertureArgs,
    /// A layer (5-channel EXR R,G,B,A,D or NPY H x W x 5, linear radiance), one fronto-parallel
    /// plane: D must be constant where A > 0. Repeat, front first.
    #[arg(long, value_name = "PATH", required = true)]
    layer: Vec<PathBuf>,
    /// Focal plane as normalized disparity.
    #[arg(long, allow_hyphen_values = true)]
    focus: f32,
    /// Blur strength K: CoC radius in pixels per unit of relative disparity (as `render`).
    #[arg(long, value_name = "K")]
    blur: f32,
    /// Rays per pixel (rounded up to a power of two).
    #[arg(long, value_name = "N", default_value_t = 1024)]
    spp: u32,
    /// Seed of the sample scrambles (the result is deterministic for a seed).
    #[arg(long, value_name = "S", default_value_t = 0)]
    seed: u64,
    /// How the pixel footprint is integrated.
    #[arg(long, value_enum, default_value = "analytic")]
    footprint: FootprintArg,
    /// Output: .exr or .npy (linear float32) or .png (8-bit sRGB, clipped).
    #[arg(short, long, value_name = "OUT")]
    output: PathBuf,
    /// Worker threads [default: all cores].
    #[arg(long, value_name = "N", value_parser = crate::parse_threads)]
    threads: Option<usize>,
    /// Also print the estimated noise (two halves of the samples) and the time.
    #[arg(short, long)]
    verbose: bool,
}

pub fn trace(args: TraceArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    let t0 = Instant::now();
    drbokeh::io::InputFiles::new(&args.layer).check_write(&args.output, "output")?;
    io::OutputFormat::from_path(&args.output)?;
    let limits = ReadLimits::default();
    let planes = args
        .layer
        .iter()
        .map(|p| {
            let what = p.display().to_string();
            let file = io::read_layer_file(p, &limits)?;
            for w in &file.warnings {
                eprintln!("warning: {w}");
            }
            Plane::from_layer(&Layer::new(file.image, &what)?, &what)
        })
        .collect::<Result<Vec<_>, Error>>()?;
    let mut s = TraceSettings::new(args.blur, args.focus, args.spp, args.seed);
    s.aperture = args.aperture.config().resolve().map_err(as_flags)?;
    s.footprint = match args.footprint {
        FootprintArg::Analytic => Footprint::Analytic,
        FootprintArg::Sampled => Footprint::Sampled,
    };
    trace::validate(&planes, &s).map_err(as_flags)?;
    let (w, h) = (planes[0].width, planes[0].height);
    // A chromatic trace runs once per colour channel.
    let passes = if s.aperture.channel_scales().is_some() { 3 } else { 1 };
    let bar = ProgressBar::new(passes * h as u64);
    bar.set_style(ProgressStyle::with_template("tracing {bar:40} {pos}/{len} rows, {elapsed} (eta {eta})").expect("template"));
    let (img, half) = trace::trace_split(&planes, &s, Window::full(w, h), &|n| bar.inc(n as u64)).map_err(as_flags)?;
    bar.finish_and_clear();
    io::write_output(&args.output, &img, 8, Transfer::Srgb)?;
    if args.verbose {
        let other = drbokeh::Image::from_vec(w, h, 3, img.data.iter().zip(&half.data).map(|(f, h)| 2.0 * f - h).collect()).expect("size");
        let noise = drbokeh::bench::metrics::rmse(&half, &other, 0) / 2.0;
        eprintln!(
            "traced {w}x{h}, {} layer(s), {} rays/pixel, K = {}, focus = {} in {:.2} s ({} threads); estimated noise RMS {noise:.5}",
            planes.len(),
            args.spp.next_power_of_two().max(2),
            args.blur,
            args.focus,
            t0.elapsed().as_secs_f64(),
            rayon::current_num_threads()
        );
    }
    eprintln!("wrote {}", args.output.display());
    Ok(())
}

#[derive(Args)]
pub struct BenchArgs {
    #[command(flatten)]
    aperture: ApertureArgs,
    /// Evaluate depth from defocus instead of rendering methods (the paper's Table 2): each
    /// method estimates the disparity from the all-in-focus photo and a traced render focused
    /// on the nearest plane; scored on disparity error and on a re-render at the farthest
    /// plane's focus. --groundtruth scenes are added to the generated ones.
    #[arg(long)]
    dfd: bool,
    /// Number of generated scenes [default: 50; 8 with --dfd].
    #[arg(long, value_name = "N")]
    scenes: Option<usize>,
    /// Frame size of the generated scenes [default: 256x256; 64x64 with --dfd].
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    size: Option<(usize, usize)>,
    /// Seed of the scene generator (and of the tracer).
    #[arg(long, value_name = "S", default_value_t = 1)]
    seed: u64,
    /// Evaluate on scene folders in the shared ground-truth format (Mitsuba renders) instead
    /// (with --dfd: as well).
    #[arg(long, value_name = "DIR")]
    groundtruth: Option<PathBuf>,
    /// Texture the generated planes with crops of these photos (else procedural textures).
    #[arg(long, value_name = "DIR")]
    textures: Option<PathBuf>,
    /// Methods to run (comma-separated) [default: all].
    #[arg(long, value_name = "LIST", value_enum, value_delimiter = ',', num_args = 1.., ignore_case = true)]
    methods: Vec<MethodArg>,
    /// With --dfd: the depth-from-defocus methods to run (comma-separated, report names)
    /// [default: all]. The acceptance checks compare the default method with the ablations
    /// that ran.
    #[arg(
        long = "dfd-methods",
        value_name = "LIST",
        value_delimiter = ',',
        num_args = 1..,
        value_parser = PossibleValuesParser::new(DfdMethod::ALL.map(DfdMethod::name)).map(|s: String| DfdMethod::parse(&s).expect("a listed name")),
    )]
    dfd_methods: Vec<DfdMethod>,
    /// What the methods are fed (comma-separated): the linear HDR view, and the same view as an
    /// 8-bit sRGB photo clipped at white, without and with a camera PSF [default: all three;
    /// with --dfd: linear, and both photos of a case are fed alike].
    #[arg(long, value_name = "LIST", value_enum, value_delimiter = ',', num_args = 1.., ignore_case = true)]
    inputs: Vec<InputArg>,
    /// Report folder (report.csv, report.md, error_vs_time.png, crops/; with --dfd figures/).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
    /// Rays per pixel of the traced ground truth [default: 1024; 256 with --dfd].
    #[arg(long, value_name = "N")]
    spp: Option<u32>,
    /// Runs per render for the median time (repeated while the total stays under 1 s).
    #[arg(long, value_name = "N", default_value_t = 3)]
    repeats: usize,
    /// Side-by-side crops to write (the cases where Dr.Bokeh gains most over the scatter).
    #[arg(long, value_name = "N", default_value_t = 4)]
    crops: usize,
    /// With --dfd: Adam steps per resolution level of every estimate.
    #[arg(long, value_name = "N", default_value_t = 100)]
    iters: usize,
    /// With --dfd: resolution levels of every estimate (coarse to fine).
    #[arg(long, value_name = "N", default_value_t = 3)]
    levels: usize,
    /// With --dfd: blur strength K of the generated scenes [default: a tenth of the smaller side].
    #[arg(long, value_name = "K")]
    blur: Option<f32>,
    /// Worker threads [default: all cores].
    #[arg(long, value_name = "N", value_parser = crate::parse_threads)]
    threads: Option<usize>,
}

fn parse_size(s: &str) -> Result<(usize, usize), String> {
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(|| format!("expected WxH, e.g. 256x256, got '{s}'"))?;
    let p = |v: &str| v.trim().parse::<usize>().map_err(|_| format!("expected WxH, e.g. 256x256, got '{s}'"));
    let (w, h) = (p(w)?, p(h)?);
    // Generated scenes are traced at up to thousands of rays per pixel: larger frames would
    // run for days (and 100000x100000 aborted allocating 45 GB).
    if !(BENCH_SIDES.contains(&w) && BENCH_SIDES.contains(&h)) {
        return Err(format!("each side must be {} to {} pixels, got {w}x{h}", BENCH_SIDES.start(), BENCH_SIDES.end()));
    }
    Ok((w, h))
}

/// Accepted frame sides of generated bench scenes.
const BENCH_SIDES: std::ops::RangeInclusive<usize> = 16..=4096;
/// Peak bytes per pixel of one bench scene (planes, exact layers, traced truth, every
/// method's render and the crops), with margin.
const BENCH_BYTES_PER_PIXEL: u64 = 600;

/// The command line as typed, for the reports.
fn command_line() -> String {
    std::iter::once("drbokeh".to_string())
        .chain(std::env::args().skip(1).map(|a| if a.contains(' ') { format!("'{a}'") } else { a }))
        .collect::<Vec<_>>()
        .join(" ")
}

pub fn bench(args: BenchArgs) -> anyhow::Result<()> {
    set_threads(args.threads)?;
    if args.dfd {
        return bench_dfd(args);
    }
    if !args.dfd_methods.is_empty() {
        return Err(Error::usage("--dfd-methods needs --dfd (--methods chooses the rendering methods)").into());
    }
    let (w, h) = args.size.unwrap_or((256, 256));
    let scenes = args.scenes.unwrap_or(50);
    drbokeh::resources::check_memory(&format!("a {w}x{h} bench scene"), (w * h) as u64 * BENCH_BYTES_PER_PIXEL)?;
    let methods = if args.methods.is_empty() { Method::ALL.to_vec() } else { args.methods.iter().map(|&m| m.into()).collect() };
    let inputs = inputs_of(&args.inputs, &Input::ALL);
    if scenes == 0 && args.groundtruth.is_none() {
        return Err(Error::usage("--scenes must be at least 1").into());
    }
    // Checked (an image aperture read) before the report folder is made.
    let aperture = args.aperture.config();
    aperture.resolve().map_err(as_flags)?;
    let opts = BenchOptions {
        scenes,
        width: w,
        height: h,
        seed: args.seed,
        groundtruth: args.groundtruth.clone(),
        textures: args.textures.clone(),
        methods,
        inputs,
        out: args.out.clone(),
        spp: args.spp.unwrap_or(1024).clamp(2, 1 << 20),
        repeats: args.repeats.max(1),
        crops: args.crops,
        command: command_line(),
        aperture,
    };
    let t0 = Instant::now();
    let bar = if opts.groundtruth.is_some() { ProgressBar::new_spinner() } else { ProgressBar::new(opts.scenes as u64) };
    bar.set_style(ProgressStyle::with_template("{bar:30} {pos}/{len} {msg} ({elapsed}, eta {eta})").expect("template"));
    let mut first = true;
    let plain = !std::io::stderr().is_terminal();
    let res = bench_run::run(&opts, &mut |msg: &str| {
        if !first {
            bar.inc(1);
        }
        first = false;
        if plain {
            eprintln!("[{:7.1} s] {msg}", t0.elapsed().as_secs_f64());
        }
        bar.set_message(msg.to_string());
    })
    .map_err(as_flags)?;
    bar.finish_and_clear();
    drbokeh::bench::report::write_all(&opts, &res)?;
    eprintln!("{} cases in {:.1} s ({} threads)", res.cases, t0.elapsed().as_secs_f64(), rayon::current_num_threads());
    eprint!("{}", drbokeh::bench::report::comparisons(&drbokeh::bench::summary::primary_rows(&res.rows)));
    eprintln!("wrote {}", opts.out.join("report.md").display());
    Ok(())
}

/// The inputs `--inputs` names, in report order without repeats (`default` when none).
fn inputs_of(args: &[InputArg], default: &[Input]) -> Vec<Input> {
    let mut inputs: Vec<Input> = if args.is_empty() { default.to_vec() } else { args.iter().map(|&i| i.into()).collect() };
    inputs.sort();
    inputs.dedup();
    inputs
}

/// `bench --dfd`: the depth-from-defocus evaluation (the work is `bench::dfd_eval::run`).
fn bench_dfd(args: BenchArgs) -> anyhow::Result<()> {
    let d = DfdBenchOptions::default();
    let (w, h) = args.size.unwrap_or((d.width, d.height));
    drbokeh::resources::check_memory(&format!("a {w}x{h} bench scene"), (w * h) as u64 * BENCH_BYTES_PER_PIXEL)?;
    if !args.methods.is_empty() || args.textures.is_some() {
        return Err(Error::usage("--methods and --textures are not used with --dfd (--dfd-methods chooses its methods)").into());
    }
    if args.iters == 0 || args.levels == 0 {
        return Err(Error::usage("--iters and --levels must be at least 1").into());
    }
    let opts = DfdBenchOptions {
        scenes: args.scenes.unwrap_or(d.scenes),
        width: w,
        height: h,
        blur: args.blur,
        seed: args.seed,
        groundtruth: args.groundtruth.clone(),
        spp: args.spp.unwrap_or(d.spp).clamp(2, 1 << 20),
        iters: args.iters,
        levels: args.levels,
        methods: if args.dfd_methods.is_empty() {
            d.methods.clone()
        } else {
            DfdMethod::ALL.into_iter().filter(|m| args.dfd_methods.contains(m)).collect()
        },
        inputs: inputs_of(&args.inputs, &d.inputs),
        out: args.out.clone(),
        command: command_line(),
    };
    let t0 = Instant::now();
    let res = dfd_eval::run(&opts, &mut |msg: &str| eprintln!("[{:7.1} s] {msg}", t0.elapsed().as_secs_f64())).map_err(as_flags)?;
    drbokeh::bench::dfd_report::write_all(&opts, &res)?;
    eprintln!("{} cases in {:.1} s ({} threads)", res.cases, t0.elapsed().as_secs_f64(), rayon::current_num_threads());
    eprint!("{}", drbokeh::bench::dfd_report::acceptance(&res.rows));
    eprintln!("wrote {}", opts.out.join("report.md").display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every spelling `--methods` accepts means what the library's `Method::parse` makes of it.
    #[test]
    fn method_flags_agree_with_the_library() {
        for arg in MethodArg::value_variants() {
            let pv = arg.to_possible_value().expect("no hidden variants");
            for name in pv.get_name_and_aliases() {
                assert_eq!(Method::parse(name), Some(Method::from(*arg)), "{name}");
            }
        }
        assert_eq!(MethodArg::value_variants().len(), Method::ALL.len());
    }

    /// Every `--inputs` name is the library's name of the same input, and every input has one.
    #[test]
    fn input_flags_agree_with_the_library() {
        for arg in InputArg::value_variants() {
            let name = arg.to_possible_value().expect("no hidden variants").get_name().to_owned();
            assert_eq!(Input::parse(&name), Some(Input::from(*arg)), "{name}");
            assert_eq!(Input::from(*arg).name(), name);
        }
        assert_eq!(InputArg::value_variants().len(), Input::ALL.len());
    }
}
