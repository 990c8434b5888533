//! Wall-clock timing of the kernels on the synthetic two-layer scene, one process, one run
//! after another (so ratios are measured side by side):
//!
//! `cargo run --release --example timing -- WIDTH HEIGHT MAX_COC [exact] [fast1 fast2 ...] [--runs N] [--threads N] [--profile official,physical] [--occlusion on,off] [--scene stress|bars]`
//!
//! Prints the median of N runs per kernel (exact runs once: it is slow), the speed-up and the
//! fast kernel's PSNR / max abs error against the exact one when both ran. `--profile` lists
//! the lens profiles to time, one after another in the same process (default: official);
//! `--occlusion` the occlusion settings (default: on). `--scene bars` times one opaque layer
//! instead: a textured ground in focus with thin bars in front of it, blurred to `MAX_COC`, in
//! the same layer (where the physical profile's in-layer depth groups matter).

use drbokeh::bench::metrics::psnr;
use drbokeh::bench::stress::{bars_in_one_layer, two_layer_scene};
use drbokeh::render::{Kernel, Layer, Profile, RenderSettings, render};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize| {
        args.get(i).and_then(|s| s.parse::<f32>().ok()).expect("usage: WIDTH HEIGHT MAX_COC [exact] [fastQ ...] [--runs N] [--threads N]")
    };
    let (w, h, coc) = (num(0) as usize, num(1) as usize, num(2));
    let opt = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|s| s.parse::<usize>().ok());
    let runs = opt("--runs").unwrap_or(3);
    if let Some(t) = opt("--threads") {
        rayon::ThreadPoolBuilder::new().num_threads(t).build_global().unwrap();
    }
    let profiles: Vec<Profile> = match args.iter().position(|a| a == "--profile").and_then(|i| args.get(i + 1)) {
        None => vec![Profile::Official],
        Some(list) => list
            .split(',')
            .map(|p| match p {
                "official" => Profile::Official,
                "physical" => Profile::Physical,
                other => panic!("unknown profile {other:?} (official, physical)"),
            })
            .collect(),
    };
    let list = |name: &str| args.iter().position(|a| a == name).and_then(|i| args.get(i + 1));
    let occlusion: Vec<bool> = list("--occlusion").map_or(vec![true], |l| l.split(',').map(|o| o == "on").collect());
    let (layers, s) = match list("--scene").map(String::as_str) {
        None | Some("stress") => two_layer_scene(w, h, coc, true),
        Some("bars") => bars_in_one_layer(w, h, coc),
        Some(other) => panic!("unknown scene {other:?} (stress, bars)"),
    };
    for profile in profiles {
        for &occlusion in &occlusion {
            time_kernels(&args, &layers, &RenderSettings { profile, occlusion, ..s }, runs);
        }
    }
}

/// Times the kernels `args` names on `layers` with settings `s`, `runs` times each.
fn time_kernels(args: &[String], layers: &[Layer], s: &RenderSettings, runs: usize) {
    let (w, h) = (layers[0].width(), layers[0].height());
    println!("profile {}{}:", s.profile.name(), if s.occlusion { "" } else { ", occlusion off" });
    println!(
        "{w}x{h} ({:.2} MP), {} layers, K = {}, lens = {}, {} threads",
        (w * h) as f64 / 1e6,
        layers.len(),
        s.blur,
        s.lens,
        rayon::current_num_threads()
    );
    let mut exact = None;
    for k in args.iter().skip(3).filter(|a| a.as_str() == "exact" || a.starts_with("fast")) {
        let kernel = if k == "exact" { Kernel::Exact } else { Kernel::Fast { quality: k[4..].parse().unwrap_or(2) } };
        let n = if k == "exact" { 1 } else { runs };
        let mut times = Vec::new();
        let mut out = None;
        for _ in 0..n {
            let t = Instant::now();
            out = Some(render(layers, s, kernel).unwrap());
            times.push(t.elapsed().as_secs_f64());
        }
        times.sort_by(f64::total_cmp);
        let med = times[times.len() / 2];
        let out = out.unwrap();
        match &exact {
            None if k == "exact" => {
                println!("{k:8} {med:9.3} s (1 run)");
                exact = Some((out, med));
            }
            Some((e, te)) => {
                let m = e.data.iter().zip(&out.data).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
                println!(
                    "{k:8} {med:9.3} s (median of {n})  speed-up {:7.1}x  PSNR vs exact {:6.2} dB  max abs {m:.4}",
                    te / med,
                    psnr(&out, e, 1.0, 0)
                );
            }
            None => println!("{k:8} {med:9.3} s (median of {n})"),
        }
    }
}
