//! Wall time of one `drbokeh dfd` step (span render + L1 + hierarchical SSIM + disparity VJP)
//! and of the span render alone, on `bench::stress::dfd_scene`, with the threads rayon is
//! given (`RAYON_NUM_THREADS`): the minimum and the median of `--reps` runs (the minimum is the
//! least disturbed by other load on a shared machine).
//!
//! `cargo run --release --example dfd_step_timing -- SIZE K [occlusion|no-occlusion] [span|exact|ray] [REPS] [physical|official]`

use drbokeh::bench::stress::{dfd_scene, dfd_settings};
use drbokeh::diff::loss::{self, HSSIM_WINDOWS};
use drbokeh::render::{Smoothing, SpanTape, Tape};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(1).map_or(512, |v| v.parse().expect("SIZE"));
    let k: f32 = args.get(2).map_or(30.0, |v| v.parse().expect("K"));
    let occlusion = args.get(3).is_none_or(|v| v != "no-occlusion");
    // `ray`: the exact tape with the ray test (physical profile).
    let ray = args.get(4).is_some_and(|v| v == "ray");
    let exact = ray || args.get(4).is_some_and(|v| v == "exact");
    let reps: usize = args.get(5).map_or(5, |v| v.parse().expect("REPS"));
    let official = args.get(6).is_some_and(|v| v == "official");
    let (layer, target) = dfd_scene(n);
    let mut s = dfd_settings(k, occlusion);
    if official {
        s.profile = drbokeh::render::Profile::Official;
    }
    let sm = Smoothing { edge_width: 1.0, fill_width: 0.1 };
    let (mut fwd, mut step) = (Vec::new(), Vec::new());
    for _ in 0..reps {
        let t0 = Instant::now();
        let (image, grad) = if exact {
            let tape = Tape::record_with(std::slice::from_ref(&layer), &s, sm, ray).unwrap();
            fwd.push(t0.elapsed().as_secs_f64());
            let l1 = loss::l1(tape.image(), &target);
            let hs = loss::hssim(tape.image(), &target, &HSSIM_WINDOWS);
            let mut seed = l1.grad;
            seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, h)| *g += h);
            (tape.image().data[0], tape.vjp(&seed).unwrap().layers[0].data[4])
        } else {
            let tape = SpanTape::record(&layer, &s, sm).unwrap();
            fwd.push(t0.elapsed().as_secs_f64());
            let l1 = loss::l1(tape.image(), &target);
            let hs = loss::hssim(tape.image(), &target, &HSSIM_WINDOWS);
            let mut seed = l1.grad;
            seed.data.iter_mut().zip(&hs.grad.data).for_each(|(g, h)| *g += h);
            (tape.image().data[0], tape.disparity_vjp(&seed).unwrap().data[0])
        };
        step.push(t0.elapsed().as_secs_f64());
        assert!(image.is_finite() && grad.is_finite());
    }
    let stats = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        (v[0], v[v.len() / 2])
    };
    let ((fmin, fmed), (smin, smed)) = (stats(&mut fwd), stats(&mut step));
    println!(
        "{n}x{n} K {k} {:?} {} {}, {} threads: forward min {:.3} s median {:.3} s; step min {:.3} s median {:.3} s",
        s.profile,
        if occlusion { "occlusion" } else { "no-occlusion" },
        if ray {
            "ray"
        } else if exact {
            "exact"
        } else {
            "span"
        },
        rayon::current_num_threads(),
        fmin,
        fmed,
        smin,
        smed
    );
}
