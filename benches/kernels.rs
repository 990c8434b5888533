//! Renderer benchmarks (release build): `cargo bench --bench kernels`.
//! Groups: the exact kernel (the baseline), the fast kernel against blur radius at a fixed
//! size (official and physical profile) and against size at a fixed radius, threads 1 vs 2, and Telea inpainting vs size.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use drbokeh::Image;
use drbokeh::bench::stress::two_layer_scene;
use drbokeh::render::{Kernel, Profile, render};
use drbokeh::stages::inpaint::{TeleaOptions, inpaint_telea};
use std::time::Duration;

const FAST: Kernel = Kernel::Fast { quality: 2 };

fn exact(c: &mut Criterion) {
    let mut g = c.benchmark_group("exact");
    g.sample_size(10).measurement_time(Duration::from_secs(30));
    // 0.25 MP, 2 layers, K = 30 (largest CoC 30 px).
    let (layers, s) = two_layer_scene(512, 512, 30.0, true);
    g.bench_function("512x512_K30", |b| b.iter(|| render(&layers, &s, Kernel::Exact).unwrap()));
    g.finish();
}

fn fast_vs_radius(c: &mut Criterion) {
    let mut g = c.benchmark_group("fast_vs_radius_1MP");
    g.sample_size(10);
    for r in [16.0f32, 32.0, 64.0, 128.0] {
        let (layers, s) = two_layer_scene(1024, 1024, r, true);
        g.bench_with_input(BenchmarkId::from_parameter(r), &r, |b, _| b.iter(|| render(&layers, &s, FAST).unwrap()));
    }
    g.finish();
}

/// The default (physical) profile against blur radius: CoC 16 is where most sources are medium
/// disks drawn per radius bin (`render::fast::binned`).
fn fast_physical_vs_radius(c: &mut Criterion) {
    let mut g = c.benchmark_group("fast_physical_vs_radius_1MP");
    g.sample_size(10);
    for r in [16.0f32, 32.0, 64.0] {
        let (layers, mut s) = two_layer_scene(1024, 1024, r, true);
        s.profile = Profile::Physical;
        g.bench_with_input(BenchmarkId::from_parameter(r), &r, |b, _| b.iter(|| render(&layers, &s, FAST).unwrap()));
    }
    g.finish();
}

fn fast_vs_size(c: &mut Criterion) {
    let mut g = c.benchmark_group("fast_vs_size_r32");
    g.sample_size(10);
    for (w, h) in [(512usize, 512usize), (1024, 1024), (2048, 2048)] {
        let (layers, s) = two_layer_scene(w, h, 32.0, true);
        g.bench_with_input(BenchmarkId::from_parameter(format!("{w}x{h}")), &w, |b, _| b.iter(|| render(&layers, &s, FAST).unwrap()));
    }
    g.finish();
}

fn threads(c: &mut Criterion) {
    let mut g = c.benchmark_group("fast_threads_1MP_r64");
    g.sample_size(10);
    let (layers, s) = two_layer_scene(1024, 1024, 64.0, true);
    for n in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        g.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| b.iter(|| pool.install(|| render(&layers, &s, FAST).unwrap())));
    }
    g.finish();
}

fn telea(c: &mut Criterion) {
    let mut g = c.benchmark_group("telea_r3_ellipse31pct");
    g.sample_size(10);
    for (w, h) in [(512usize, 384usize), (1024, 768), (2048, 1536)] {
        let mut img = Image::new(w, h, 3);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 255) as f32 / 255.0;
        }
        // An ellipse covering ~31% of the frame.
        let (a, b) = (w as f32 * 0.30, h as f32 * 0.33);
        let mask: Vec<bool> = (0..w * h)
            .map(|i| (((i % w) as f32 - w as f32 / 2.0) / a).powi(2) + (((i / w) as f32 - h as f32 / 2.0) / b).powi(2) < 1.0)
            .collect();
        g.bench_with_input(BenchmarkId::from_parameter(format!("{w}x{h}")), &w, |bch, _| {
            bch.iter(|| {
                let mut im = img.clone();
                inpaint_telea(&mut im, &mask, TeleaOptions::new(3.0)).unwrap()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, exact, fast_vs_radius, fast_physical_vs_radius, fast_vs_size, threads, telea);
criterion_main!(benches);
