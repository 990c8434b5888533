//! Focus sweep from saved layers through `refocus::Refocuser`: reads the layers once, then
//! times one render per focus (fast kernel, default settings, K as given).
//!
//!   cargo run --release --example refocus -- BLUR FOCUS[,FOCUS...] LAYER.exr [LAYER.exr ...]
//!
//! Layers as `drbokeh render --save-layers DIR` writes them (e.g. `DIR/0_fg.exr`, `DIR/1_bg.exr`).

use drbokeh::io::ReadLimits;
use drbokeh::refocus::Refocuser;
use drbokeh::render::Layer;
use drbokeh::{Config, Focus, Pipeline};
use std::path::Path;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() < 3 {
        return Err("usage: refocus BLUR FOCUS[,FOCUS...] LAYER.exr [LAYER.exr ...]".into());
    }
    let blur: f32 = args[0].parse()?;
    let foci: Vec<f32> = args[1].split(',').map(str::parse).collect::<Result<_, _>>()?;
    let t = Instant::now();
    let layers = args[2..]
        .iter()
        .map(|p| Layer::new(drbokeh::io::read_layer_file(Path::new(p), &ReadLimits::new(ReadLimits::DEFAULT_MAX_PIXELS))?.image, p))
        .collect::<drbokeh::Result<Vec<_>>>()?;
    println!("read {} layers: {:.3} s", layers.len(), t.elapsed().as_secs_f64());
    let mut config = Config::default();
    config.render.blur = Some(blur);
    let refocuser = Refocuser::new(Pipeline::from_config(config)?, layers)?;
    for focus in foci {
        let t = Instant::now();
        let (image, _) = refocuser.render(Focus::Disparity(focus))?;
        println!("focus {focus}: {:.3} s ({}x{})", t.elapsed().as_secs_f64(), image.width, image.height);
    }
    Ok(())
}
