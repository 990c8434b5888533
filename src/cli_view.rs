//! `drbokeh view`: builds the layers once and serves the interactive refocus page and its API
//! ([`drbokeh::view`]) on 127.0.0.1 only.

use crate::{PipelineArgs, as_flags, config_from, set_threads};
use anyhow::Context;
use clap::Args;
use drbokeh::job::{self, Job};
use drbokeh::pipeline::{Focus, Pipeline, default_blur};
use drbokeh::view::{BLUR_RANGE, Viewer};
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

#[derive(Args)]
pub(crate) struct ViewArgs {
    /// The photo: PNG/JPEG/TIFF (8/16-bit, sRGB) or EXR (linear).
    #[arg(required_unless_present = "layer", conflicts_with = "layer")]
    image: Option<PathBuf>,
    /// Depth map (as for render); without it, the photo's own, else the depth model.
    #[arg(long, conflicts_with = "layer")]
    depth: Option<PathBuf>,
    /// Foreground matte: grey image or the alpha of an RGBA image, in [0, 1].
    #[arg(long, conflicts_with = "layer")]
    matte: Option<PathBuf>,
    /// Layers instead of a photo (5-channel EXR or NPY); repeat, front first.
    #[arg(long, value_name = "PATH")]
    layer: Vec<PathBuf>,
    /// Where "save full size" writes [default: IMAGE_bokeh.png].
    #[arg(short, long, value_name = "OUT")]
    output: Option<PathBuf>,
    /// Also write the layers served (EXR R,G,B,A,D, usable with render --layer) to DIR.
    #[arg(long, value_name = "DIR")]
    save_layers: Option<PathBuf>,
    /// Port on 127.0.0.1 [default: a free one].
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// Do not open the page in a browser.
    #[arg(long)]
    no_browser: bool,
    #[command(flatten)]
    opts: PipelineArgs,
}

/// Worker threads answering requests (each render uses every core through rayon).
const WORKERS: usize = 4;

pub(crate) fn view(args: ViewArgs) -> anyhow::Result<()> {
    set_threads(args.opts.threads)?;
    let _ = ctrlc::set_handler(|| {
        eprintln!("\nstopped");
        drbokeh::io::atomic::remove_in_flight_temps_and_exit(130);
    });
    let cfg = config_from(&args.opts)?;
    let first = args.image.as_ref().or(args.layer.first()).cloned().unwrap_or_default();
    let output = args.output.clone().unwrap_or_else(|| {
        let stem = first.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
        PathBuf::from(format!("{stem}_bokeh.png"))
    });
    let job = Job {
        image: args.image.clone(),
        depth: args.depth.clone(),
        matte: args.matte.clone(),
        layers: args.layer.clone(),
        focus: Focus::Disparity(0.0),
        output: output.clone(),
        save_layers: None,
        pull: None,
    };
    let inputs = drbokeh::io::InputFiles::new(job.inputs());
    inputs.check_write(&output, "output").map_err(as_flags)?;
    // The layers are built for the page's widest reach: focused at the far end (every nearer
    // pixel blurred) with the slider's largest blur, so any focus shows what lies behind.
    let size = layer_size(&job, &cfg)?;
    let blur = cfg.render.blur.unwrap_or_else(|| default_blur(size.0, size.1));
    let mut build_cfg = cfg.clone();
    build_cfg.render.blur = Some(blur * BLUR_RANGE);
    eprintln!("building the layers...");
    let (layers, report) = job::build_layers(&Pipeline::from_config(build_cfg)?, &job, Focus::Disparity(0.0)).map_err(as_flags)?;
    for w in &report.warnings {
        eprintln!("warning: {}", crate::flag_names(w));
    }
    eprintln!("layers built in {:.2} s ({})", report.total_ms / 1e3, stage_times(&report));
    if let Some(dir) = &args.save_layers {
        job::check_layer_folder(dir).map_err(as_flags)?;
        for w in job::save_layers(dir, &layers, &inputs).map_err(as_flags)? {
            eprintln!("warning: {w}");
        }
    }
    let mut command: Vec<String> = vec!["drbokeh".into(), "render".into()];
    match &args.image {
        Some(img) => {
            command.push(img.display().to_string());
            for (flag, p) in [("--depth", &args.depth), ("--matte", &args.matte)] {
                if let Some(p) = p {
                    command.extend([flag.to_string(), p.display().to_string()]);
                }
            }
        }
        None => args.layer.iter().for_each(|l| command.extend(["--layer".to_string(), l.display().to_string()])),
    }
    if let Some(c) = &args.opts.config {
        command.extend(["--config".to_string(), c.display().to_string()]);
    }
    let viewer = Arc::new(Viewer::new(cfg, layers, blur, output, command)?);
    let server =
        tiny_http::Server::http(("127.0.0.1", args.port)).map_err(|e| anyhow::anyhow!("cannot listen on 127.0.0.1:{}: {e}", args.port))?;
    let port = server.server_addr().to_ip().map(|a| a.port()).context("the server has no IP address")?;
    let url = format!("http://127.0.0.1:{port}/");
    {
        let mut out = std::io::stdout().lock();
        writeln!(out, "listening on {url}")?;
        out.flush()?;
    }
    if !args.no_browser {
        open_browser(&url);
    }
    let server = Arc::new(server);
    let workers: Vec<_> = (0..WORKERS)
        .map(|_| {
            let (server, viewer) = (server.clone(), viewer.clone());
            std::thread::spawn(move || {
                while let Ok(rq) = server.recv() {
                    let reply = viewer.handle(rq.method().as_str(), rq.url());
                    let header =
                        tiny_http::Header::from_bytes(&b"Content-Type"[..], reply.content_type.as_bytes()).expect("a valid header");
                    let nocache = tiny_http::Header::from_bytes(&b"Cache-Control"[..], &b"no-store"[..]).expect("a valid header");
                    let response =
                        tiny_http::Response::from_data(reply.body).with_status_code(reply.status).with_header(header).with_header(nocache);
                    // A client that went away is not the server's problem.
                    let _ = rq.respond(response);
                }
            })
        })
        .collect();
    for w in workers {
        let _ = w.join();
    }
    Ok(())
}

/// The photo's (or first layer's) size, from its header where it has one, for the default blur.
fn layer_size(job: &Job, cfg: &drbokeh::Config) -> anyhow::Result<(usize, usize)> {
    let path = job.image.as_ref().or(job.layers.first()).context("a photo or a layer is needed")?;
    let limits = drbokeh::io::ReadLimits { max_pixels: cfg.input.max_pixels };
    Ok(drbokeh::io::inspect::raster_size(path, &limits).map_err(as_flags)?)
}

/// Opens `url` in the desktop's browser, if there is one (failure is not an error: the URL
/// was printed).
fn open_browser(url: &str) {
    let cmd: &[&str] = if cfg!(target_os = "macos") {
        &["open"]
    } else if cfg!(windows) {
        &["cmd", "/C", "start", ""]
    } else {
        &["xdg-open"]
    };
    let _ = std::process::Command::new(cmd[0])
        .args(&cmd[1..])
        .arg(url)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn();
}

/// The stages that ran, with their wall times: "read 0.17 s, inpaint 0.57 s, ...".
fn stage_times(report: &drbokeh::report::Report) -> String {
    let ran = report.stages.iter().filter(|s| s.status == drbokeh::report::StageStatus::Ran);
    ran.map(|s| format!("{} {:.2} s", s.name, s.ms / 1e3)).collect::<Vec<_>>().join(", ")
}
