//! Diagnosis of the highlights stage (`stages::light_recovery`) on the bench's generated
//! scenes: per scene, the lights it found against the scene's true highlights (radius,
//! radiance), the photo's PSF it read, and the light it put back against the light clipping
//! took.
//!
//! `cargo run --release --example diag_highlights -- SEED SCENES SIZE [psf]`
//! (e.g. `3 20 128`; `psf` for the bench's `srgb8-psf` input).

use drbokeh::bench::inputs::{Input, prepare};
use drbokeh::bench::scenes::generate;
use drbokeh::stages::light_recovery::{HighlightsOptions, Occluders, Recovered, recover};

fn main() -> drbokeh::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let arg = |i: usize, d: usize| args.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let (seed, scenes, size) = (arg(1, 3) as u64, arg(2, 20), arg(3, 128));
    let input = if args.get(4).is_some_and(|s| s == "psf") { Input::Srgb8Psf } else { Input::Srgb8 };
    let (mut lost_all, mut added_all) = (0.0f64, 0.0f64);
    // Per matched light: estimated over true radiance (mean of the channels).
    let mut ratios: Vec<f32> = Vec::new();
    for i in 0..scenes {
        let sc = generate(seed, i, size, size, &[]);
        let linear = sc.inputs()?;
        let prepared = prepare(&linear, input)?;
        let photo = &prepared.scene.aif;
        let lost = prepared.missing_light.unwrap_or(0.0);
        // OCCLUDERS=none|depth|matte (default matte): what the stage knows of the subject.
        let which = std::env::var("OCCLUDERS").unwrap_or_else(|_| "matte".into());
        let s = &prepared.scene;
        let occluders = match which.as_str() {
            "none" => None,
            "depth" => Some(Occluders { disparity: &s.realistic_disparity, matte: None }),
            "exactdepth" => Some(Occluders { disparity: &s.disparity, matte: None }),
            _ => Some(Occluders { disparity: &s.disparity, matte: Some(&s.matte) }),
        };
        let Recovered::Changed(out, report) =
            recover(photo, input.encoding(), &HighlightsOptions::default(), &Default::default(), occluders)?
        else {
            println!("{}: nothing clipped", sc.name);
            continue;
        };
        let added: f64 = out.data.iter().zip(&photo.data).map(|(o, p)| (o - p) as f64).sum();
        (lost_all, added_all) = (lost_all + lost, added_all + added);
        println!(
            "{}: {} clipped px, {} lights, {} left, PSF {:.2}; light put back {added:.0} of {lost:.0} ({:.2}x)",
            sc.name,
            report.clipped_pixels,
            report.lights,
            report.areas_left,
            report.psf_sigma,
            added / lost.max(1e-9)
        );
        let m = sc.margin as f32;
        for l in &report.brightest {
            let truth = sc
                .bg_highlights
                .iter()
                .min_by(|a, b| (a.cx - m - l.x).hypot(a.cy - m - l.y).total_cmp(&(b.cx - m - l.x).hypot(b.cy - m - l.y)));
            let t = truth.map(|h| (h.cx - m - l.x).hypot(h.cy - m - l.y) < 2.0).unwrap_or(false).then(|| truth.unwrap());
            if let Some(h) = t {
                ratios.push((0..3).map(|c| l.radiance[c] / (h.radiance * h.tint[c])).sum::<f32>() / 3.0);
            }
            println!(
                "  ({:5.1},{:5.1}) r {:.2} px {:3} radiance {:5.1} {:5.1} {:5.1} added {:7.1} | true: {}",
                l.x,
                l.y,
                l.radius,
                l.pixels,
                l.radiance[0],
                l.radiance[1],
                l.radiance[2],
                l.added,
                t.map_or("none near".into(), |h| format!(
                    "r {:.2} radiance {:.1} {:.1} {:.1}",
                    h.r,
                    h.radiance * h.tint[0],
                    h.radiance * h.tint[1],
                    h.radiance * h.tint[2]
                ))
            );
        }
    }
    ratios.sort_by(f32::total_cmp);
    let q = |p: f32| ratios.get(((ratios.len() as f32 - 1.0) * p).round() as usize).copied().unwrap_or(f32::NAN);
    let within = |tol: f32| ratios.iter().filter(|&&r| (r - 1.0).abs() <= tol).count();
    println!(
        "lights matched {}: radiance estimate / truth quartiles {:.2} {:.2} {:.2}, within 15% {}, within 50% {}, over 2x {}",
        ratios.len(),
        q(0.25),
        q(0.5),
        q(0.75),
        within(0.15),
        within(0.5),
        ratios.iter().filter(|&&r| r > 2.0).count()
    );
    println!("all: light put back {added_all:.0} of {lost_all:.0} ({:.2}x)", added_all / lost_all.max(1e-9));
    Ok(())
}
