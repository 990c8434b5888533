//! One optimisation step of `drbokeh dfd` (render, L1 + hierarchical SSIM, disparity
//! gradient): `cargo bench --bench dfd`. The span render (`render::SpanTape`, what `dfd` uses
//! by default) at 512×512 against the exact tape (`render::Tape`) at 128×128; see `dfd_step`.

use criterion::{Criterion, criterion_group, criterion_main};
use drbokeh::bench::stress::{dfd_scene, dfd_settings};
use drbokeh::diff::loss;
use drbokeh::render::{Profile, RenderSettings, Smoothing, SpanTape, Tape};
use std::time::Duration;

/// One step of `drbokeh dfd` at its defaults (L1 + hierarchical SSIM on the render, the
/// disparity gradient through the render): the span render (`SpanTape`, the default) at
/// 512×512 with K = 15 and 30, occlusion on and off, and the official profile at K = 15;
/// `forward` is `SpanTape::record` alone.
/// The exact tape's step at 128×128 (K = 30/4, as `dfd` renders its coarsest of 3 levels of a
/// 512 px photo, and K = 30: the exact step at 512 px takes minutes, extrapolated in README).
fn dfd_step(c: &mut Criterion) {
    let sm = Smoothing { edge_width: 1.0, fill_width: 0.1 };
    let windows = &loss::HSSIM_WINDOWS;
    let physical = Profile::Physical;
    for (n, k, occlusion, exact, profile) in [
        (512, 15.0, true, false, physical),
        (512, 30.0, true, false, physical),
        (512, 30.0, false, false, physical),
        (512, 15.0, true, false, Profile::Official),
        (128, 7.5, true, false, physical),
        (128, 7.5, true, true, physical),
        (128, 30.0, true, false, physical),
        (128, 30.0, true, true, physical),
    ] {
        let (layer, target) = dfd_scene(n);
        let s = RenderSettings { profile, ..dfd_settings(k, occlusion) };
        let kernel = if exact { "exact" } else { "span" };
        let official = if profile == Profile::Official { "_official" } else { "" };
        let mut g =
            c.benchmark_group(format!("dfd_step_{n}x{n}_k{k}_{}_{kernel}{official}", if occlusion { "occlusion" } else { "no_occlusion" }));
        g.sample_size(10).measurement_time(Duration::from_secs(if exact { 20 } else { 8 }));
        let step = || {
            let (image, seed_grad) = if exact {
                let tape = Tape::record(std::slice::from_ref(&layer), &s, sm).unwrap();
                let l1 = loss::l1(tape.image(), &target);
                let hs = loss::hssim(tape.image(), &target, windows);
                let mut seed = l1.grad;
                seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, h)| *g += h);
                let g = tape.vjp(&seed).unwrap();
                (tape.image().data[0], g.layers[0].data[4])
            } else {
                let tape = SpanTape::record(&layer, &s, sm).unwrap();
                let l1 = loss::l1(tape.image(), &target);
                let hs = loss::hssim(tape.image(), &target, windows);
                let mut seed = l1.grad;
                seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, h)| *g += h);
                let g = tape.disparity_vjp(&seed).unwrap();
                (tape.image().data[0], g.data[0])
            };
            image + seed_grad
        };
        if !exact {
            g.bench_function("forward", |b| b.iter(|| SpanTape::record(&layer, &s, sm).unwrap().image().data[0]));
        }
        g.bench_function("step", |b| b.iter(step));
        g.finish();
    }
}

criterion_group!(benches, dfd_step);
criterion_main!(benches);
