//! Where a cat's eye render leaves the tracer on a generated bench scene: `SCENE=7 SEED=1
//! STRENGTH=1 [FAST=2] cargo run --release --example diag_cat_eye` traces and renders (exact kernel) the
//! scene with and without the cat's eye, prints their PSNRs, the worst pixels and the total
//! light, and writes sRGB PNGs of both to `$OUT` (default /tmp/diag). `BUBBLE=B` puts a disc
//! with the bubble profile `B` in the cat's eye's place.
use drbokeh::Image;
use drbokeh::bench::metrics::srgb;
use drbokeh::bench::run::score;
use drbokeh::bench::scenes::generate;
use drbokeh::bench::trace::{TraceSettings, trace};
use drbokeh::render::{self, Aperture, Kernel, Profile, RenderSettings};

fn save(img: &Image, path: &str) {
    let s = srgb(img);
    let buf: Vec<u8> = s.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0 + 0.5) as u8).collect();
    image::RgbImage::from_raw(img.width as u32, img.height as u32, buf).expect("size").save(path).expect("write");
}

fn env(k: &str, d: f64) -> f64 {
    std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d)
}

fn main() -> drbokeh::Result<()> {
    let (seed, index, strength) = (env("SEED", 1.0) as u64, env("SCENE", 7.0) as usize, env("STRENGTH", 1.0) as f32);
    let out = std::env::var("OUT").unwrap_or_else(|_| "/tmp/diag".into());
    std::fs::create_dir_all(&out).expect("the output folder");
    let sc = generate(seed, index, 128, 128, &[]);
    let inputs = sc.inputs()?;
    println!("{}: blur {} focus {} planes {:?}", sc.name, sc.blur, sc.focus, sc.planes.iter().map(|p| p.disparity).collect::<Vec<_>>());
    let b = env("BUBBLE", 0.0) as f32;
    let second = if b != 0.0 {
        ("bubble", Aperture::with_bubble(&drbokeh::render::aperture::ShapeSpec::Disc, 1.0, b, "b")?)
    } else {
        ("cat", Aperture::DISC.with_cat_eye(strength)?)
    };
    for (name, a) in [("disc", Aperture::DISC), second] {
        let mut ts = TraceSettings::new(sc.blur, sc.focus, 256, seed ^ (index as u64) << 20);
        ts.aperture = a;
        let gt = trace(&sc.trace_planes(), &ts, sc.window(), &|_| {})?;
        let lens = render::auto_lens(&inputs.plane_layers, sc.blur, sc.focus);
        let s = RenderSettings { blur: sc.blur, focus: sc.focus, lens, occlusion: true, profile: Profile::Physical, aperture: a };
        // `FAST=Q`: the fast kernel at quality Q instead of the exact one.
        let kernel = std::env::var("FAST").ok().and_then(|q| q.parse().ok()).map_or(Kernel::Exact, |quality| Kernel::Fast { quality });
        let img = render::render(&inputs.plane_layers, &s, kernel)?;
        let border = sc.max_coc.ceil() as usize;
        let sco = score(&img, &gt, border);
        println!("{name}: psnr linear {:.2}", sco.psnr);
        let mut worst: Vec<(f32, usize)> = (0..gt.width * gt.height)
            .map(|i| ((0..3).map(|c| (img.data[i * 3 + c] - gt.data[i * 3 + c]).abs()).fold(0.0, f32::max), i))
            .collect();
        worst.sort_by(|a, b| b.0.total_cmp(&a.0));
        for &(e, i) in worst.iter().take(6) {
            println!(
                "  ({}, {}) err {e:.3} render {:?} truth {:?}",
                i % gt.width,
                i / gt.width,
                &img.data[i * 3..i * 3 + 3],
                &gt.data[i * 3..i * 3 + 3]
            );
        }
        let sum = |im: &Image| im.data.iter().map(|&v| v as f64).sum::<f64>();
        println!("  total light render {:.1} truth {:.1}", sum(&img), sum(&gt));
        save(&img, &format!("{out}/{name}_render.png"));
        save(&gt, &format!("{out}/{name}_truth.png"));
    }
    Ok(())
}
