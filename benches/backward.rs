//! Cost of the backward pass against the forward of the same (exact) kernel:
//! `cargo bench --bench backward`. 128×128, two layers (a blurred backdrop behind an in-focus
//! disk and bars, largest CoC 15 px), lens 31, both profiles. Per profile: `forward` is
//! `render(.., Kernel::Exact)`; `record` is [`Tape::record`] (the differentiable forward,
//! keeping the per-pixel sums); `vjp` is [`Tape::vjp`] on a recorded tape; `record+vjp` is one
//! optimisation step's render and gradient. The ratio reported in README is
//! `record+vjp / forward` (medians). The ray test (physical, [`Tape::record_with`]) is timed
//! against its own recording, the only forward it has.

use criterion::{Criterion, criterion_group, criterion_main};
use drbokeh::Image;
use drbokeh::bench::stress::two_layer_scene;
use drbokeh::render::{Kernel, Profile, Smoothing, Tape, render};
use std::time::{Duration, Instant};

fn backward(c: &mut Criterion) {
    for profile in [Profile::Official, Profile::Physical] {
        let mut g = c.benchmark_group(format!("backward_{}_128x128_lens31", profile.name()));
        g.sample_size(20).measurement_time(Duration::from_secs(10));
        let (layers, mut s) = two_layer_scene(128, 128, 15.0, true);
        s.lens = 31;
        s.profile = profile;
        let sm = Smoothing::default();
        // A fixed pseudo-random cotangent in [-1, 1].
        let mut seed = Image::new(128, 128, 3);
        seed.data.iter_mut().enumerate().for_each(|(i, v)| *v = ((i * 7919 % 1000) as f32 / 500.0) - 1.0);
        g.bench_function("forward", |b| b.iter(|| render(&layers, &s, Kernel::Exact).unwrap()));
        g.bench_function("record", |b| b.iter(|| Tape::record(&layers, &s, sm).unwrap().image().data[0]));
        let tape = Tape::record(&layers, &s, sm).unwrap();
        g.bench_function("vjp", |b| b.iter(|| tape.vjp(&seed).unwrap()));
        g.bench_function("record+vjp", |b| b.iter(|| Tape::record(&layers, &s, sm).unwrap().vjp(&seed).unwrap()));
        g.finish();
    }
}

/// The ratio itself, robust to a shared machine: forward and record+vjp alternate, one
/// thread each, and the median of the per-pair ratios is printed (criterion's medians of the
/// two series, taken minutes apart, move with the machine's other load).
fn ratio(_: &mut Criterion) {
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    for profile in [Profile::Official, Profile::Physical] {
        let (layers, mut s) = two_layer_scene(128, 128, 15.0, true);
        s.lens = 31;
        s.profile = profile;
        let mut seed = Image::new(128, 128, 3);
        seed.data.iter_mut().enumerate().for_each(|(i, v)| *v = ((i * 7919 % 1000) as f32 / 500.0) - 1.0);
        let mut ratios: Vec<f64> = (0..9)
            .map(|_| {
                pool.install(|| {
                    let t0 = Instant::now();
                    render(&layers, &s, Kernel::Exact).unwrap();
                    let t1 = Instant::now();
                    Tape::record(&layers, &s, Smoothing::default()).unwrap().vjp(&seed).unwrap();
                    t1.elapsed().as_secs_f64() / (t1 - t0).as_secs_f64()
                })
            })
            .collect();
        ratios.sort_by(f64::total_cmp);
        println!(
            "backward_ratio_{}: (record+vjp)/forward, 1 thread, interleaved: median {:.2} (min {:.2}, max {:.2})",
            profile.name(),
            ratios[4],
            ratios[0],
            ratios[8]
        );
    }
    // The ray test has no render of its own outside the tape: its forward is the recording.
    let (layers, mut s) = two_layer_scene(128, 128, 15.0, true);
    s.lens = 31;
    s.profile = Profile::Physical;
    let mut seed = Image::new(128, 128, 3);
    seed.data.iter_mut().enumerate().for_each(|(i, v)| *v = ((i * 7919 % 1000) as f32 / 500.0) - 1.0);
    let sm = Smoothing::default();
    let mut ratios: Vec<f64> = (0..9)
        .map(|_| {
            pool.install(|| {
                let t0 = Instant::now();
                let tape = Tape::record_with(&layers, &s, sm, true).unwrap();
                let t1 = Instant::now();
                tape.vjp(&seed).unwrap();
                t0.elapsed().as_secs_f64() / (t1 - t0).as_secs_f64()
            })
        })
        .collect();
    ratios.sort_by(f64::total_cmp);
    println!(
        "backward_ratio_physical_ray: (record+vjp)/record, 1 thread: median {:.2} (min {:.2}, max {:.2})",
        ratios[4], ratios[0], ratios[8]
    );
}

criterion_group!(benches, ratio, backward);
criterion_main!(benches);
