//! One opaque plane with 2 × 2 px point lights (radiance 20) near the corners, the edges and
//! the centre of a 128 px frame under a cat's eye, in front of and behind the focal plane:
//! the render (exact kernel, or `FAST=Q`) against the thin-lens tracer, with the plain disc
//! beside it. Prints the PSNR and, per light, the light in a window around it (render /
//! truth, above the plane's 0.2) and the shift of its centroid (px). `COC=R` (default 6),
//! `S=strength` (1), `SPP=N` (1024), `TEX=T` (a chequer of amplitude T under the lights; 0).
//! How the per-source norm of 2026-11-28 was found 9% bright at the frame's centre:
//! `cargo run --release --example diag_cat_eye_plane`.
use drbokeh::Image;
use drbokeh::bench::run::score;
use drbokeh::bench::trace::{Plane, TraceSettings, Window, trace};
use drbokeh::render::{self, Aperture, Kernel, Layer, Profile, RenderSettings};

fn env(k: &str, d: f64) -> f64 {
    std::env::var(k).ok().and_then(|v| v.parse().ok()).unwrap_or(d)
}

fn main() -> drbokeh::Result<()> {
    let n = 128usize;
    let coc = env("COC", 6.0) as f32;
    let spp = env("SPP", 1024.0) as u32;
    let lights = [(14usize, 14usize), (112, 14), (14, 112), (112, 112), (64, 64), (64, 14), (112, 64)];
    let mut img = Image::new(n, n, 5);
    for y in 0..n {
        for x in 0..n {
            let p = &mut img.data[(y * n + x) * 5..(y * n + x) * 5 + 5];
            let g = 0.2 + env("TEX", 0.0) as f32 * (((x / 4 + y / 4) % 2) as f32);
            p.copy_from_slice(&[g, g, g, 1.0, 0.5]);
        }
    }
    for &(lx, ly) in &lights {
        for y in ly..ly + 2 {
            for x in lx..lx + 2 {
                img.data[(y * n + x) * 5..(y * n + x) * 5 + 3].copy_from_slice(&[20.0, 20.0, 20.0]);
            }
        }
    }
    let layer = Layer::new(img, "plane")?;
    let plane = Plane::from_layer(&layer, "plane")?;
    for (side, focus) in [("front", 0.0f32), ("back", 1.0)] {
        let blur = coc / 0.5;
        for (name, a) in [("disc", Aperture::DISC), ("cat", Aperture::DISC.with_cat_eye(env("S", 1.0) as f32)?)] {
            let mut ts = TraceSettings::new(blur, focus, spp, 7);
            ts.aperture = a;
            let gt = trace(std::slice::from_ref(&plane), &ts, Window { x0: 0, y0: 0, width: n, height: n }, &|_| {})?;
            let layers = vec![layer.clone()];
            let lens = render::auto_lens(&layers, blur, focus);
            let s = RenderSettings { blur, focus, lens, occlusion: true, profile: Profile::Physical, aperture: a };
            let kernel = std::env::var("FAST").ok().and_then(|q| q.parse().ok()).map_or(Kernel::Exact, |quality| Kernel::Fast { quality });
            let r = render::render(&layers, &s, kernel)?;
            let sco = score(&r, &gt, 0);
            print!("{side} {name}: psnr {:.2} |", sco.psnr);
            for &(lx, ly) in &lights {
                let (mut sr, mut st, mut cr, mut ct) = (0f64, 0f64, [0f64; 2], [0f64; 2]);
                for y in ly.saturating_sub(12)..(ly + 14).min(n) {
                    for x in lx.saturating_sub(12)..(lx + 14).min(n) {
                        let i = (y * n + x) * 3 + 1;
                        let (a, b) = ((r.data[i] - 0.2) as f64, (gt.data[i] - 0.2) as f64);
                        sr += a;
                        st += b;
                        cr[0] += a * x as f64;
                        cr[1] += a * y as f64;
                        ct[0] += b * x as f64;
                        ct[1] += b * y as f64;
                    }
                }
                print!(" {:.1}/{:.1} ({:+.2},{:+.2})", sr, st, cr[0] / sr - ct[0] / st, cr[1] / sr - ct[1] / st);
            }
            println!();
        }
    }
    Ok(())
}
