//! The matting stage on bench scenes (issue 42's diagnosis): per scene, the alpha error along
//! the true outline of the depth split and of its refinement, from the realistic depth map.
//!
//! `cargo run --release --example diag_matting -- SEED SCENES SIZE` (defaults 3 20 128);
//! `DUMP=DIR` writes the photo, the true matte, the split, the trimap, the band's fit and the refined matte as PNGs.
use drbokeh::bench::outline::Outline;
use drbokeh::bench::scenes::generate;
use drbokeh::color::Transfer;
use drbokeh::config::Config;
use drbokeh::io::write_png;
use drbokeh::stages::depth_edges;
use drbokeh::stages::fill_depth::hard_mask;
use drbokeh::stages::matting;
use drbokeh::stages::segment::{Segmentation, from_disparity};

fn main() -> drbokeh::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).map(|s| s.parse().unwrap()).unwrap_or(3);
    let n: usize = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(20);
    let size: usize = args.get(3).map(|s| s.parse().unwrap()).unwrap_or(128);
    let dump = std::env::var("DUMP").ok().map(std::path::PathBuf::from);
    let cfg = Config::default();
    for i in 0..n {
        let sc = generate(seed, i, size, size, &[]);
        let inp = sc.inputs()?;
        let coarse = match from_disparity(&inp.realistic_disparity, &cfg.segment) {
            Segmentation::Foreground(a) => a,
            Segmentation::SingleLayer(why) => {
                let exact = matches!(from_disparity(&inp.disparity, &cfg.segment), Segmentation::Foreground(_));
                println!("s{i:03}: one layer ({why}; with the exact depth: {})", if exact { "two layers" } else { "one too" });
                continue;
            }
        };
        let edges = depth_edges::measure(&inp.realistic_disparity, &hard_mask(&coarse, &cfg.fill_depth), size, size);
        let t = std::time::Instant::now();
        let (refined, info) =
            matting::refine(&inp.aif, &coarse, matting::band_for(&edges), cfg.segment.edge_softness, cfg.segment.refine.solver());
        let ms = t.elapsed().as_secs_f64() * 1e3;
        let outline = Outline::of(&inp.matte);
        let mae = |a| outline.score(&inp.aif, &inp.aif, Some((a, &inp.matte))).alpha_mae.unwrap();
        println!(
            "s{i:03}: edges in {:.1} out {:.1} ({} samples)  unknown {}  split {:.4}  refined {:.4}  {ms:.1} ms",
            edges.inside_px,
            edges.outside_px,
            edges.samples,
            info.unknown_px,
            mae(&coarse),
            mae(&refined)
        );
        if let Some(dir) = &dump {
            std::fs::create_dir_all(dir).ok();
            let p = |name: &str| dir.join(format!("s{i:03}_{name}.png"));
            write_png(&p("photo"), &inp.aif, 8, Transfer::Srgb)?;
            let tri = matting::trimap(&coarse, matting::band_for(&edges)).unwrap_or_else(|| coarse.clone());
            let (fitted, _) = matting::fit(&inp.aif, &coarse, matting::band_for(&edges), cfg.segment.refine.solver());
            for (name, a) in [("true", &inp.matte), ("split", &coarse), ("refined", &refined), ("trimap", &tri), ("fit", &fitted)] {
                write_png(&p(name), a, 8, Transfer::Linear)?;
            }
        }
    }
    Ok(())
}
