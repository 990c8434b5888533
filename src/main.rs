//! The `drbokeh` command line: parses flags, calls the library, maps errors to exit codes
//! (0 success, 2 bad input or usage, 1 internal error).

use anyhow::Context;
use clap::{Args, Parser, Subcommand, ValueEnum};
use drbokeh::Error;
use drbokeh::config::{Config, KernelChoice};
use drbokeh::io::BitDepth;
use drbokeh::job::{self, Job};
use drbokeh::pipeline::{Focus, Pipeline};
use drbokeh::stages::depth::DepthKind;
use drbokeh::stages::layer_count::LayerCount;
use drbokeh::stages::light_recovery::HighlightMode;
use drbokeh::timing::ms_since;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

mod cli_batch;
mod cli_bench;
mod cli_dfd;
mod cli_inspect;
mod cli_view;

#[derive(Parser)]
#[command(name = "drbokeh", version, about = "Occlusion-aware lens blur (Dr.Bokeh) from one photo and its depth")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render lens blur for one photo + depth (+ matte), or for given layers.
    Render(RenderArgs),
    /// Ray-trace the thin-lens ground truth of a layered billboard scene.
    Trace(cli_bench::TraceArgs),
    /// Benchmark methods and settings against traced ground truth (error vs run time report).
    Bench(cli_bench::BenchArgs),
    /// Render every photo of a folder (resumable, parallel, shardable).
    Batch(cli_batch::BatchArgs),
    /// Depth from defocus: the disparity map that turns an all-in-focus photo into a photo of
    /// the same view focused at --focus (Adam through the differentiable renderer).
    Dfd(cli_dfd::DfdArgs),
    /// What a photo holds: size, colour, the depth map it embeds (Dynamic Depth,
    /// GDepth) and its parameters;
    /// --extract-depth writes that map for other tools.
    Inspect(cli_inspect::InspectArgs),
    /// Interactive refocus: builds the layers once and serves a page on 127.0.0.1 (click to
    /// focus, sliders for the blur and the look, save full size) and its HTTP API.
    View(cli_view::ViewArgs),
    /// Shell completions on stdout: `source <(drbokeh completions bash)`.
    Completions {
        /// The shell.
        #[arg(value_enum)]
        shell: clap_complete::Shell,
    },
    /// The manual page (roff) on stdout: `drbokeh man > drbokeh.1; man ./drbokeh.1`.
    Man,
}

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum ProfileArg {
    /// Calibrated to the thin lens (CoC exactly K|d|, uniform disks, coverage visibility).
    Physical,
    /// The official Dr.Bokeh formula (golden vectors).
    Official,
}

impl From<ProfileArg> for drbokeh::render::Profile {
    fn from(p: ProfileArg) -> drbokeh::render::Profile {
        match p {
            ProfileArg::Physical => drbokeh::render::Profile::Physical,
            ProfileArg::Official => drbokeh::render::Profile::Official,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum KernelArg {
    /// The official formula, tap by tap; always run, even when nothing is out of focus.
    Exact,
    /// The fast kernel (same model, near-constant cost per pixel; see --quality).
    Fast,
    /// The fast kernel, and no rendering at all when nothing is out of focus.
    Auto,
}

#[derive(Clone, Copy, ValueEnum)]
enum SegmentArg {
    /// The matte when --matte is given, else the depth split.
    Auto,
    /// The --matte (required).
    Matte,
    /// Split near from far in the depth map.
    Depth,
    /// The saliency / matting model of [segment.onnx] (or u2net.onnx in --model-dir).
    Onnx,
}

#[derive(Clone, Copy, ValueEnum)]
enum InpaintArg {
    /// Telea fast-marching inpainting (no model).
    Telea,
    /// The inpainting model of [inpaint.onnx] (or lama.onnx in --model-dir).
    Onnx,
    /// Telea, then an exemplar (PatchMatch) fill of the colour: texture continues behind the
    /// subject (slower).
    Patchmatch,
}

/// `--bit-depth`: bits per sample of a PNG output.
#[derive(Clone, Copy, ValueEnum)]
enum BitDepthArg {
    /// 8 bits per sample.
    #[value(name = "8")]
    Eight,
    /// 16 bits per sample.
    #[value(name = "16")]
    Sixteen,
}

impl From<BitDepthArg> for BitDepth {
    fn from(b: BitDepthArg) -> BitDepth {
        match b {
            BitDepthArg::Eight => BitDepth::Eight,
            BitDepthArg::Sixteen => BitDepth::Sixteen,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum HighlightsArg {
    Auto,
    Off,
    Boost,
    Onnx,
}

impl From<HighlightsArg> for HighlightMode {
    fn from(h: HighlightsArg) -> HighlightMode {
        match h {
            HighlightsArg::Auto => HighlightMode::Auto,
            HighlightsArg::Off => HighlightMode::Off,
            HighlightsArg::Boost => HighlightMode::Boost,
            HighlightsArg::Onnx => HighlightMode::Onnx,
        }
    }
}

/// `--easing`.
#[derive(Clone, Copy, ValueEnum)]
enum EasingArg {
    /// Evenly spaced frames.
    Linear,
    /// Smoothstep: slow at both ends.
    Smooth,
}

#[derive(Clone, Copy, ValueEnum)]
enum DepthKindArg {
    Depth,
    Disparity,
}

#[derive(Args)]
#[command(group = clap::ArgGroup::new("focus_spec").required(true).args(["focus", "focus_at", "focus_depth", "focus_from"]))]
struct RenderArgs {
    /// The photo: PNG/JPEG/TIFF (8/16-bit, sRGB), EXR (linear), or HEIC/HEIF (with libheif).
    #[arg(required_unless_present = "layer", conflicts_with = "layer")]
    image: Option<PathBuf>,
    /// Depth map: EXR, 16-bit PNG/TIFF, float TIFF or NPY (H x W). Without it, the depth map
    /// the photo embeds (Dynamic Depth or GDepth in a JPEG, a HEIC's depth image), else the depth model ([depth.onnx] or --model-dir).
    #[arg(long, conflicts_with = "layer")]
    depth: Option<PathBuf>,
    /// Ignore the depth map the photo embeds (Dynamic Depth, GDepth, HEIF depth image); without --depth, the depth model is used.
    #[arg(long, conflicts_with = "layer")]
    no_embedded_depth: bool,
    /// Ignore the matte the photo embeds (a HEIC portrait matte); without --matte, none is used.
    #[arg(long, conflicts_with = "layer")]
    no_embedded_matte: bool,
    /// Foreground matte: grey image or the alpha of an RGBA image, in [0, 1]. Without it, the
    /// matte the photo embeds (a HEIC portrait matte), if any.
    #[arg(long, conflicts_with = "layer")]
    matte: Option<PathBuf>,
    /// A layer (5-channel EXR R,G,B,A,D or NPY H x W x 5, linear colours); repeat, front first.
    #[arg(long, value_name = "PATH")]
    layer: Vec<PathBuf>,
    /// Focal plane as normalized disparity (0 far … 1 near).
    #[arg(long, allow_hyphen_values = true)]
    focus: Option<f32>,
    /// Focus on the surface under pixel X,Y (median disparity of a small window).
    #[arg(long, value_name = "X,Y", value_parser = parse_xy, allow_hyphen_values = true)]
    focus_at: Option<(i64, i64)>,
    /// Focus at metric depth Z (with --depth-kind depth).
    #[arg(long, value_name = "Z", allow_negative_numbers = true)]
    focus_depth: Option<f64>,
    /// Focus pull: the first frame's focus (normalized disparity); with --focus-to, --frames
    /// and -o holding %d or %04d (frames/%04d.png). The layers are built once.
    #[arg(long, value_name = "F", allow_hyphen_values = true, requires_all = ["focus_to", "frames", "output"])]
    focus_from: Option<f32>,
    /// Focus pull: the last frame's focus (normalized disparity).
    #[arg(long, value_name = "F", allow_hyphen_values = true, requires = "focus_from")]
    focus_to: Option<f32>,
    /// Focus pull: how many frames.
    #[arg(long, value_name = "N", requires = "focus_from")]
    frames: Option<usize>,
    /// Focus pull: the first frame's blur K (with --blur-to) [default: --blur for every frame].
    #[arg(long, value_name = "K", allow_hyphen_values = true, requires_all = ["focus_from", "blur_to"])]
    blur_from: Option<f32>,
    /// Focus pull: the last frame's blur K.
    #[arg(long, value_name = "K", allow_hyphen_values = true, requires = "blur_from")]
    blur_to: Option<f32>,
    /// Focus pull: how focus and blur move between the ends [default: smooth].
    #[arg(long, value_enum, requires = "focus_from")]
    easing: Option<EasingArg>,
    /// Output: .png (8/16-bit sRGB), .exr or .npy (linear float32) [default: IMAGE_bokeh.png];
    /// for a focus pull, a pattern with %d or %04d.
    #[arg(short, long, value_name = "OUT")]
    output: Option<PathBuf>,
    /// Write the layers (EXR R,G,B,A,D, usable with --layer) and PNG previews to DIR.
    #[arg(long, value_name = "DIR")]
    save_layers: Option<PathBuf>,
    /// Print per-stage timings to stderr.
    #[arg(short, long)]
    verbose: bool,
    /// Print a machine-readable summary (JSON) to stdout.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    opts: PipelineArgs,
}

/// Options of the pipeline, shared by `render` and `batch`.
#[derive(Args)]
pub(crate) struct PipelineArgs {
    /// Blur strength K: CoC radius in pixels per unit of normalized disparity
    /// [default: 30 × sqrt(megapixels)].
    #[arg(long, value_name = "K", allow_hyphen_values = true)]
    blur: Option<f32>,
    /// Pipeline configuration (TOML); flags override it.
    #[arg(long, value_name = "TOML")]
    config: Option<PathBuf>,
    /// What the depth file holds.
    #[arg(long, value_enum)]
    depth_kind: Option<DepthKindArg>,
    /// Odd side of the square lens window [default: from the largest CoC in the scene].
    #[arg(long, value_name = "N", allow_negative_numbers = true)]
    lens: Option<usize>,
    /// Official "naive gamma": render on rgb^G and output ^(1/G) instead of exact sRGB.
    #[arg(long, value_name = "G", allow_negative_numbers = true)]
    gamma: Option<f32>,
    /// Which kernel renders the layers.
    #[arg(long, value_enum)]
    kernel: Option<KernelArg>,
    /// Fast-kernel quality: 1 (fastest) … 8 (converges to the exact kernel) [default: 2].
    #[arg(long, value_name = "Q", value_parser = clap::value_parser!(u32).range(1..=8))]
    quality: Option<u32>,
    /// Classical scatter without occlusion terms, one layer (a baseline for comparisons).
    #[arg(long)]
    no_occlusion: bool,
    /// Lens calibration: physical (calibrated to the thin lens) or official (the Dr.Bokeh
    /// formula) [default: physical].
    #[arg(long, value_enum)]
    profile: Option<ProfileArg>,
    /// PNG bit depth (8 or 16).
    #[arg(long, value_name = "BITS", value_enum)]
    bit_depth: Option<BitDepthArg>,
    /// Worker threads [default: all cores].
    #[arg(long, value_name = "N", value_parser = parse_threads)]
    threads: Option<usize>,
    /// Where the foreground layer comes from [default: auto].
    #[arg(long, value_enum)]
    segment: Option<SegmentArg>,
    /// How many layers: 2 (foreground over background), a count 1..=8, or auto (the background
    /// also cut at gaps of its depth) [default: 2].
    #[arg(long, value_name = "auto|N", value_parser = LayerCount::parse)]
    layers: Option<LayerCount>,
    /// How the background behind the foreground is filled [default: telea].
    #[arg(long, value_enum)]
    inpaint: Option<InpaintArg>,
    /// Folder with the ONNX models, named as their presets' files (u2net.onnx, lama.onnx, ...).
    #[arg(long, value_name = "DIR")]
    model_dir: Option<PathBuf>,
    /// Clipped highlights of an 8/16-bit photo: auto (their light estimated from the fringe
    /// around each light), off, boost (brightness above the threshold raised up to
    /// --highlight-gain times) or onnx (an inverse-tone-mapping model, [highlights.onnx] or
    /// expandnet.onnx in --model-dir) [default: auto; linear photos are left as they are].
    #[arg(long, value_enum)]
    highlights: Option<HighlightsArg>,
    /// Stored value in (0, 1] at or above which a sample is a clipped highlight (auto) or is
    /// boosted (boost) [default: 0.98].
    #[arg(long, value_name = "T")]
    highlight_threshold: Option<f32>,
    /// boost: the brightness factor at stored value 1, in [1, 100] [default: 4].
    #[arg(long, value_name = "G")]
    highlight_gain: Option<f32>,
    #[command(flatten)]
    aperture: ApertureArgs,
}

/// The bokeh's shape, shared by `render`, `batch`, `view`, `trace`, `bench` and `dfd`.
#[derive(Args)]
pub(crate) struct ApertureArgs {
    /// The aperture's shape: disc, blades:N[,rotation=DEG][,curvature=C] (3..=64 blades, a
    /// vertex at DEG counterclockwise from +x, y up; curvature 0 straight … 1 round) or
    /// image:PATH (a grey mask, bright = open, its longer side spanning the bokeh's diameter).
    /// The circumradius is the circle of confusion; bokeh in front of the focal plane shows
    /// the shape point-reflected [default: disc].
    #[arg(long, value_name = "SHAPE")]
    aperture: Option<String>,
    /// Aspect ratio of the bokeh: > 1 taller than wide (anamorphic), < 1 wider [default: 1].
    #[arg(long, value_name = "A", allow_negative_numbers = true)]
    anamorphic: Option<f32>,
    /// Radial intensity of the bokeh in [-1, 1]: > 0 a bright rim (an over-corrected lens's
    /// "soap bubble"), < 0 a bright centre [default: 0, uniform].
    #[arg(long, value_name = "B", allow_negative_numbers = true)]
    bubble: Option<f32>,
    /// Longitudinal chromatic aberration in [-0.5, 0.5]: red's circle of confusion scaled by
    /// 1 + C and blue's by 1 - C, so out-of-focus edges and lights get coloured fringes (red
    /// outside, blue inside for C > 0). Renders three passes [default: 0, none].
    #[arg(long, value_name = "C", allow_negative_numbers = true)]
    chromatic: Option<f32>,
    /// Optical vignetting ("cat's eye") in [0, 1]: toward the frame's corners the bokeh is cut
    /// by a second circle displaced toward the centre, as a real lens's barrel clips its
    /// pupil (any shape: disc, blades, an image, with or without --bubble) [default: 0, off].
    #[arg(long, value_name = "S", allow_negative_numbers = true)]
    cat_eye: Option<f32>,
}

impl ApertureArgs {
    /// `[aperture]` as the flags alone give it (for the commands that read no pipeline.toml).
    pub(crate) fn config(&self) -> drbokeh::config::ApertureConfig {
        let mut cfg = drbokeh::config::ApertureConfig::default();
        self.apply(&mut cfg);
        cfg
    }

    /// Overrides `[aperture]` with the flags given.
    pub(crate) fn apply(&self, cfg: &mut drbokeh::config::ApertureConfig) {
        if let Some(a) = &self.aperture {
            cfg.shape = a.clone();
        }
        cfg.anamorphic = self.anamorphic.unwrap_or(cfg.anamorphic);
        cfg.bubble = self.bubble.unwrap_or(cfg.bubble);
        cfg.chromatic = self.chromatic.unwrap_or(cfg.chromatic);
        cfg.cat_eye = self.cat_eye.unwrap_or(cfg.cat_eye);
    }
}

pub(crate) fn set_threads(n: Option<usize>) -> anyhow::Result<()> {
    if let Some(n) = n {
        let n = drbokeh::resources::check_threads(n, "--threads")?;
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("cannot set the thread count")?;
    }
    Ok(())
}

/// `--threads N`: a count within [`drbokeh::resources::check_threads`]'s range (a negative
/// one is named as such, not as a stray flag).
pub(crate) fn parse_threads(s: &str) -> Result<usize, String> {
    let n: i64 = s.trim().parse().map_err(|_| format!("expected a thread count (a whole number from 1), got '{s}'"))?;
    let n = usize::try_from(n).map_err(|_| format!("must be at least 1, got {n}"))?;
    drbokeh::resources::check_threads(n, "--threads").map_err(|e| e.to_string())
}

pub(crate) fn parse_xy(s: &str) -> Result<(i64, i64), String> {
    let (x, y) = s.split_once(',').ok_or_else(|| format!("expected X,Y (two integers), got '{s}'"))?;
    let p = |v: &str| v.trim().parse::<i64>().map_err(|_| format!("expected X,Y (two integers), got '{s}'"));
    Ok((p(x)?, p(y)?))
}

/// The command line, with every option that takes a value accepting one that starts with `-`
/// (`--threads -1`): clap would take `-1` for a flag and say "unexpected argument '-1'",
/// where the option's own rule names what it accepts.
fn command() -> clap::Command {
    let negatives = |a: clap::Arg| {
        let takes = a.get_action().takes_values() && !a.is_positional();
        if takes { a.allow_negative_numbers(true) } else { a }
    };
    <Cli as clap::CommandFactory>::command().mut_subcommands(move |sc| sc.mut_args(negatives))
}

fn main() -> ExitCode {
    let cli = match <Cli as clap::FromArgMatches>::from_arg_matches(&command().get_matches()) {
        Ok(cli) => cli,
        Err(e) => e.exit(),
    };
    if matches!(cli.command, Command::Render(_) | Command::Batch(_)) {
        // A frame's freed buffers serve its next stage, and in a batch the next image (see
        // the function).
        drbokeh::resources::reuse_large_allocations();
    }
    let result = std::panic::catch_unwind(|| match cli.command {
        Command::Render(args) => render(args).map(|()| ExitCode::SUCCESS),
        Command::Trace(args) => cli_bench::trace(args).map(|()| ExitCode::SUCCESS),
        Command::Bench(args) => cli_bench::bench(args).map(|()| ExitCode::SUCCESS),
        Command::Batch(args) => cli_batch::batch(args),
        Command::Dfd(args) => cli_dfd::dfd(args).map(|()| ExitCode::SUCCESS),
        Command::Inspect(args) => cli_inspect::run(args).map(|()| ExitCode::SUCCESS),
        Command::View(args) => cli_view::view(args).map(|()| ExitCode::SUCCESS),
        Command::Completions { shell } => {
            use clap::CommandFactory;
            let mut text = Vec::new();
            clap_complete::generate(shell, &mut Cli::command(), "drbokeh", &mut text);
            print_bytes(&text).map(|()| ExitCode::SUCCESS)
        }
        Command::Man => {
            use clap::CommandFactory;
            let mut text = Vec::new();
            clap_mangen::Man::new(Cli::command()).render(&mut text).context("cannot render the manual page")?;
            print_bytes(&text).map(|()| ExitCode::SUCCESS)
        }
    });
    match result {
        Ok(Ok(code)) => code,
        Ok(Err(e)) => {
            // Library errors already name their cause; other errors show their chain.
            match e.downcast_ref::<Error>() {
                Some(err) => eprintln!("error: {err}"),
                None => eprintln!("error: {e:#}"),
            }
            ExitCode::from(exit_code(&e))
        }
        Err(_) => {
            eprintln!("error: internal error (a bug): please report it with the command line");
            ExitCode::from(1)
        }
    }
}

/// The exit status of a failed command (docs/guide.md): 2 for bad input or usage (the
/// library's user errors), 1 for an internal error or any other failure.
fn exit_code(e: &anyhow::Error) -> u8 {
    match e.downcast_ref::<Error>() {
        Some(err) if err.is_user_error() => 2,
        _ => 1,
    }
}

pub(crate) fn config_from(args: &PipelineArgs) -> Result<Config, Error> {
    let mut cfg = match &args.config {
        Some(p) => Config::load(p)?,
        None => Config::default(),
    };
    let r = &mut cfg.render;
    r.blur = args.blur.or(r.blur);
    r.lens = args.lens.or(r.lens);
    r.gamma = args.gamma.or(r.gamma);
    if let Some(k) = args.kernel {
        r.kernel = match k {
            KernelArg::Exact => KernelChoice::Exact,
            KernelArg::Fast => KernelChoice::Fast,
            KernelArg::Auto => KernelChoice::Auto,
        };
    }
    if let Some(q) = args.quality {
        r.quality = q;
    }
    if let Some(p) = args.profile {
        r.profile = p.into();
    }
    if args.no_occlusion {
        r.occlusion = false;
    }
    if let Some(b) = args.bit_depth {
        cfg.output.bit_depth = b.into();
    }
    if let Some(s) = args.segment {
        use drbokeh::stages::segment::SegmentMethod;
        cfg.segment.method = match s {
            SegmentArg::Auto => SegmentMethod::Auto,
            SegmentArg::Matte => SegmentMethod::Matte,
            SegmentArg::Depth => SegmentMethod::Depth,
            SegmentArg::Onnx => SegmentMethod::Onnx,
        };
    }
    if let Some(n) = args.layers {
        cfg.segment.layers = n;
    }
    if let Some(m) = args.inpaint {
        use drbokeh::stages::inpaint_onnx::InpaintMethod;
        cfg.inpaint.method = match m {
            InpaintArg::Telea => InpaintMethod::Telea,
            InpaintArg::Onnx => InpaintMethod::Onnx,
            InpaintArg::Patchmatch => InpaintMethod::PatchMatch,
        };
    }
    if let Some(d) = &args.model_dir {
        cfg.onnx.model_dir = Some(d.clone());
    }
    if let Some(m) = args.highlights {
        cfg.highlights.mode = m.into();
    }
    args.aperture.apply(&mut cfg.aperture);
    cfg.highlights.threshold = args.highlight_threshold.unwrap_or(cfg.highlights.threshold);
    cfg.highlights.gain = args.highlight_gain.unwrap_or(cfg.highlights.gain);
    if let Some(k) = args.depth_kind {
        cfg.input.depth_kind = match k {
            DepthKindArg::Depth => DepthKind::Depth,
            DepthKindArg::Disparity => DepthKind::Disparity,
        };
    }
    cfg.validate().map_err(as_flags)?;
    Ok(cfg)
}

/// The names the library gives parameters in its messages (config keys such as `render.lens`,
/// parameter names such as `trace.spp`), and the command-line flags that set them. A key that
/// starts another key comes after it (`render.focus_at` before `render.focus`).
const FLAGS: [(&str, &str); 47] = [
    ("aperture.shape", "--aperture"),
    ("aperture.bubble", "--bubble"),
    ("aperture.chromatic", "--chromatic"),
    ("aperture.cat_eye", "--cat-eye"),
    ("aperture.anamorphic", "--anamorphic"),
    ("highlights.mode", "--highlights"),
    ("highlights.threshold", "--highlight-threshold"),
    ("highlights.gain", "--highlight-gain"),
    ("segment.layers", "--layers"),
    ("segment.method", "--segment"),
    ("inpaint.method", "--inpaint"),
    ("job.layers", "--layer"),
    ("job.matte", "--matte"),
    ("render.occlusion = false", "--no-occlusion"),
    ("render.profile", "--profile"),
    ("render.kernel", "--kernel"),
    ("render.focus_depth", "--focus-depth"),
    ("render.focus_at", "--focus-at"),
    ("render.focus", "--focus"),
    ("render.blur", "--blur"),
    ("render.lens", "--lens"),
    ("render.gamma", "--gamma"),
    ("render.quality", "--quality"),
    ("input.depth_kind = \"depth\"", "--depth-kind depth"),
    ("input.depth_kind = \"disparity\"", "--depth-kind disparity"),
    ("input.embedded_depth = false", "--no-embedded-depth"),
    ("input.embedded_matte = false", "--no-embedded-matte"),
    ("output.bit_depth", "--bit-depth"),
    ("batch.manifest", "--manifest"),
    ("job.save_layers", "--save-layers"),
    ("job.depth", "--depth"),
    ("onnx.model_dir", "--model-dir"),
    ("trace.blur", "--blur"),
    ("trace.focus", "--focus"),
    ("trace.spp", "--spp"),
    ("bench.size", "--size"),
    ("bench.methods", "--methods"),
    ("bench.scenes", "--scenes"),
    ("bench.blur", "--blur"),
    ("dfd.iters", "--iters"),
    ("dfd.kernel", "--kernel"),
    ("dfd.levels", "--levels"),
    ("dfd.learning_rate", "--learning-rate"),
    ("dfd.init", "--init"),
    ("dfd.log", "--log"),
    ("dfd.plot", "--plot"),
    ("dfd.confidence", "--confidence"),
];

/// `msg` with every library parameter name replaced by its flag (see [`FLAGS`]).
/// Writes `bytes` to stdout; a reader that went away (`drbokeh man | head`) is not an error.
fn print_bytes(bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(bytes).and_then(|()| out.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e).context("cannot write to standard output"),
        _ => Ok(()),
    }
}

pub(crate) fn flag_names(msg: &str) -> String {
    FLAGS.iter().fold(msg.to_owned(), |m, (key, flag)| m.replace(key, flag))
}

/// The library names parameters by their config keys (`render.lens`); on the command line
/// they are flags. Only usage errors are rewritten: an error in a config file (an input error
/// naming the file) keeps the file's keys.
pub(crate) fn as_flags(e: Error) -> Error {
    match e {
        Error::Usage(m) => Error::Usage(flag_names(&m)),
        other => other,
    }
}

/// Prints `value` as pretty JSON on stdout. A reader that went away (`drbokeh ... --json |
/// head`) is not an error: the outputs are already written.
pub(crate) fn print_json<T: serde::Serialize>(value: &T) -> anyhow::Result<()> {
    use std::io::Write;
    let text = serde_json::to_string_pretty(value).context("cannot serialize the report")?;
    match writeln!(std::io::stdout().lock(), "{text}") {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => Err(e).context("cannot write to standard output"),
        _ => Ok(()),
    }
}

fn render(args: RenderArgs) -> anyhow::Result<()> {
    // One image's workers reuse each other's freed buffers (see the function); before any
    // worker starts.
    let threads = args.opts.threads.unwrap_or_else(drbokeh::resources::cores);
    drbokeh::resources::share_allocator_arenas(threads);
    set_threads(args.opts.threads)?;
    // SIGINT/SIGTERM: nothing is worth finishing; remove the temporary output file, exit 130.
    let _ = ctrlc::set_handler(|| {
        eprintln!("\ninterrupted");
        drbokeh::io::atomic::remove_in_flight_temps_and_exit(130);
    });
    let t0 = Instant::now();
    let mut cfg = config_from(&args.opts)?;
    if args.no_embedded_depth {
        cfg.input.embedded_depth = false;
    }
    if args.no_embedded_matte {
        cfg.input.embedded_matte = false;
    }
    let focus = match (args.focus, args.focus_at, args.focus_depth, args.focus_from) {
        (Some(f), ..) | (_, _, _, Some(f)) => Focus::Disparity(f),
        (_, Some((x, y)), ..) => Focus::At(x, y),
        (_, _, Some(z), _) => Focus::Depth(z),
        _ => unreachable!("clap requires one focus flag"),
    };
    let pull = args.focus_from.map(|from| drbokeh::focus_pull::FocusPull {
        from,
        to: args.focus_to.expect("clap requires --focus-to"),
        frames: args.frames.expect("clap requires --frames"),
        blur: args.blur_from.zip(args.blur_to),
        easing: match args.easing {
            Some(EasingArg::Linear) => drbokeh::focus_pull::Easing::Linear,
            Some(EasingArg::Smooth) | None => drbokeh::focus_pull::Easing::Smooth,
        },
    });

    let job = Job {
        image: args.image.clone(),
        depth: args.depth.clone(),
        matte: args.matte.clone(),
        layers: args.layer.clone(),
        focus,
        output: args.output.clone().unwrap_or_else(|| {
            let first = args.image.as_ref().or(args.layer.first()).cloned().unwrap_or_default();
            let stem = first.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
            PathBuf::from(format!("{stem}_bokeh.png"))
        }),
        save_layers: args.save_layers.clone(),
        pull,
    };
    // Warnings that matter before the run ends (a long exact render) are printed at once;
    // the rest after the run.
    let shown = std::sync::Arc::new(std::sync::Mutex::new(Vec::<String>::new()));
    let seen = shown.clone();
    let pipeline = Pipeline::from_config(cfg)?.with_notice(Box::new(move |m| {
        let m = flag_names(m);
        eprintln!("warning: {m}");
        seen.lock().map(|mut s| s.push(m)).ok();
    }));
    let mut report = job::run(&pipeline, &job).map_err(as_flags)?;
    // The report speaks the library's names too: the JSON and the messages get the flags.
    for w in &mut report.warnings {
        *w = flag_names(w);
    }
    for r in report.stages.iter_mut().filter_map(|s| s.reason.as_mut()) {
        *r = flag_names(r);
    }
    report.total_ms = ms_since(t0);
    let output = job.output;

    let shown = shown.lock().map(|s| s.clone()).unwrap_or_default();
    for w in report.warnings.iter().filter(|w| !shown.contains(w)) {
        eprintln!("warning: {w}");
    }
    if args.verbose {
        if let Some(d) = &report.depth_source {
            eprintln!("{:>12}  {}", "depth", d.describe());
        }
        if let Some(m) = &report.matte_source {
            eprintln!("{:>12}  {}", "matte", m.describe());
        }
        for s in &report.stages {
            match &s.reason {
                Some(r) => eprintln!("{:>12}  skipped: {r}", s.name),
                None => eprintln!("{:>12}  {:9.1} ms", s.name, s.ms),
            }
        }
        let p = &report.params;
        eprintln!(
            "{:>12}  {:9.1} ms  ({}x{}, K = {}, focus = {}, lens = {}, {} layer(s), {} threads)",
            "total", report.total_ms, p.width, p.height, p.blur, p.focus, p.lens, p.layers, p.threads
        );
    }
    if args.json {
        print_json(&report)?;
    } else if let (Some(first), Some(last)) = (report.frames.first(), report.frames.last()) {
        eprintln!("wrote {} frames: {} … {}", report.frames.len(), first.output, last.output);
    } else {
        eprintln!("wrote {}", output.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn longer_keys_are_replaced_first() {
        // A key replaced first must not be the start of one replaced after it.
        for (i, (first, _)) in FLAGS.iter().enumerate() {
            for (after, _) in &FLAGS[i + 1..] {
                assert!(!after.starts_with(first), "{after} must come before {first}");
            }
        }
        assert_eq!(flag_names("render.focus_at 3,4 and render.focus"), "--focus-at 3,4 and --focus");
    }

    /// The guide's exit statuses: 2 for bad input and usage, 1 for an internal error (no
    /// command line is known to reach one, so the end-to-end tests cannot read it) and for a
    /// failure from outside the library.
    #[test]
    fn internal_errors_exit_1_and_user_errors_2() {
        assert_eq!(exit_code(&anyhow::Error::new(Error::Internal("a bug".into()))), 1);
        assert_eq!(exit_code(&anyhow::Error::new(Error::usage("bad flag"))), 2);
        assert_eq!(exit_code(&anyhow::Error::new(Error::input("photo.png", "truncated"))), 2);
        assert_eq!(exit_code(&anyhow::anyhow!("some other failure")), 1);
        // Context added at the command-line edge keeps the library's error and its status.
        assert_eq!(exit_code(&anyhow::Error::new(Error::usage("bad")).context("while rendering")), 2);
    }
}
