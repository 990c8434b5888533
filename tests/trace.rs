//! The thin-lens tracer (`drbokeh::bench::trace`) against analytic answers and against the
//! Mitsuba 3 renders in ../shared/groundtruth.

use crate::common;

use drbokeh::Image;
use drbokeh::bench::groundtruth::GtScene;
use drbokeh::bench::metrics::{psnr, rmse};
use drbokeh::bench::scenes::gt_plane_layers;
use drbokeh::bench::trace::{Footprint, Plane, TraceSettings, Window, trace, trace_split};
use drbokeh::render::Layer;

/// Fraction of a disk of radius `r` that lies beyond a line at signed distance `t` from its
/// centre (t > 0: the line does not reach the centre).
fn disk_fraction_beyond(t: f64, r: f64) -> f64 {
    if t >= r {
        return 0.0;
    }
    if t <= -r {
        return 1.0;
    }
    (r * r * (t / r).acos() - t * (r * r - t * t).sqrt()) / (std::f64::consts::PI * r * r)
}

/// The exact thin-lens image of a step edge at x = `edge` (0 left, 1 right) through a lens
/// of CoC radius `r`, averaged over each pixel's width (box filter).
fn step_reference(x: usize, edge: f64, r: f64) -> f64 {
    let n = 2000;
    (0..n)
        .map(|k| {
            let xc = x as f64 + (k as f64 + 0.5) / n as f64;
            // Light comes from where the disk around xc reaches x >= edge.
            disk_fraction_beyond(edge - xc, r)
        })
        .sum::<f64>()
        / n as f64
}

fn step_plane(w: usize, h: usize, edge: usize, d: f32) -> Plane {
    // R: step in x; G: step in y; B: constant.
    let mut rgb = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            rgb.pixel_mut(x, y).copy_from_slice(&[(x >= edge) as u8 as f32, (y >= edge) as u8 as f32, 0.5]);
        }
    }
    Plane::from_rgb_alpha(&rgb, &Image::filled(w, h, 1, 1.0), d)
}

#[test]
fn single_plane_blurs_to_the_analytic_disk_convolution() {
    let (w, h, edge) = (40, 40, 20);
    // CoC radius K·|D − f| = 20 · |0.3 − 0.1| = 4 px.
    let (k, d, f) = (20.0f32, 0.3f32, 0.1f32);
    let r = (k * (d - f)).abs() as f64;
    let plane = step_plane(w, h, edge, d);
    // The sampled footprint integrates a 4-D discontinuous function and converges more slowly.
    for (footprint, spp, max_tol) in [(Footprint::Analytic, 1024, 0.01), (Footprint::Sampled, 4096, 0.02)] {
        let mut s = TraceSettings::new(k, f, spp, 7);
        s.footprint = footprint;
        let img = trace(std::slice::from_ref(&plane), &s, Window::full(w, h), &|_| {}).unwrap();
        let (mut max_err, mut sq, mut n) = (0f64, 0f64, 0usize);
        for y in 8..h - 8 {
            for x in 8..w - 8 {
                let p = img.pixel(x, y);
                let (rx, ry) = (step_reference(x, edge as f64, r), step_reference(y, edge as f64, r));
                for (got, want) in [(p[0] as f64, rx), (p[1] as f64, ry), (p[2] as f64, 0.5)] {
                    let e = (got - want).abs();
                    max_err = max_err.max(e);
                    sq += e * e;
                    n += 1;
                }
            }
        }
        let rms = (sq / n as f64).sqrt();
        println!("{footprint:?}, {spp} spp: step edge through a CoC of radius {r} px: max error {max_err:.5}, RMS {rms:.5}");
        assert!(max_err < max_tol && rms < 0.003, "{footprint:?}: max {max_err} rms {rms}");
    }
}

#[test]
fn in_focus_plane_reproduces_its_texture_exactly() {
    let (w, h) = (23, 17);
    let mut rgb = Image::new(w, h, 3);
    let mut s = 12345u64;
    for v in &mut rgb.data {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        *v = (s >> 40) as f32 / (1u64 << 24) as f32 * 3.0;
    }
    let front = Plane::from_rgb_alpha(&rgb, &Image::filled(w, h, 1, 1.0), 0.8);
    // A defocused plane behind an opaque in-focus one is invisible.
    let back = Plane::from_rgb_alpha(&Image::filled(w, h, 3, 50.0), &Image::filled(w, h, 1, 1.0), 0.0);
    for footprint in [Footprint::Analytic, Footprint::Sampled] {
        let mut st = TraceSettings::new(40.0, 0.8, 64, 3);
        st.footprint = footprint;
        let img = trace(&[front.clone(), back.clone()], &st, Window::full(w, h), &|_| {}).unwrap();
        let err = common::max_abs_diff(&img.data, &rgb.data);
        assert!(err < 1e-5, "{footprint:?}: in-focus plane differs by {err}");
    }
}

#[test]
fn deterministic_for_a_seed_and_independent_of_threads() {
    let plane = step_plane(24, 24, 12, 1.0);
    let s = TraceSettings::new(6.0, 0.0, 64, 11);
    let a = trace(std::slice::from_ref(&plane), &s, Window::full(24, 24), &|_| {}).unwrap();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let b = pool.install(|| trace(std::slice::from_ref(&plane), &s, Window::full(24, 24), &|_| {}).unwrap());
    assert_eq!(a.data, b.data);
    let c = trace(std::slice::from_ref(&plane), &TraceSettings { seed: 12, ..s }, Window::full(24, 24), &|_| {}).unwrap();
    assert_ne!(a.data, c.data);
    assert!(rmse(&a, &c, 0) < 0.01);
}

/// The Mitsuba scenes rebuilt from their exact layers (one plane per depth) must match the
/// Mitsuba thin-lens renders. 512 rays per pixel keep this test short: the tracer's own noise
/// is then ~0.003–0.007 RMS where the background is far out of focus (bright highlights spread
/// over a CoC of 18 px), the Mitsuba images carry 0.0005–0.002, and PSNR 40 dB means RMSE 0.01
/// (peak 1, linear light), so the bound leaves room for both noises and flags any real bias
/// (a wrong CoC radius, sign or footprint costs 10 dB or more). The border of the largest CoC
/// is left out: the layers lack the off-frame content the lens sees there.
#[test]
fn shared_groundtruth_scenes_are_reproduced() {
    let dirs = common::case_dirs(&common::shared_dir().join("groundtruth"));
    assert!(!dirs.is_empty());
    for dir in dirs {
        let scene = GtScene::load(&dir).unwrap();
        let layers: Vec<Layer<'static>> = gt_plane_layers(&scene).unwrap();
        let planes: Vec<Plane> = layers.iter().map(|l| Plane::from_layer(l, "plane").unwrap()).collect();
        for s in &scene.settings {
            let ts = TraceSettings::new(s.blur, s.focus, 512, 1);
            let (img, half) = trace_split(&planes, &ts, Window::full(scene.bg.width, scene.bg.height), &|_| {}).unwrap();
            let border = s.coc_max.ceil() as usize;
            let other =
                Image::from_vec(img.width, img.height, 3, img.data.iter().zip(&half.data).map(|(f, h)| 2.0 * f - h).collect()).unwrap();
            let noise = rmse(&half, &other, border) / 2.0;
            let p = psnr(&img, &s.gt, 1.0, border);
            println!(
                "{:10} {:9} {} planes, CoC max {:5.2} px: PSNR {p:.2} dB (linear, border {border}), RMSE {:.5}, tracer noise {noise:.5}",
                scene.name,
                s.name,
                planes.len(),
                s.coc_max,
                rmse(&img, &s.gt, border)
            );
            assert!(p >= 40.0, "{} {}: PSNR {p:.2} dB < 40 dB", scene.name, s.name);
        }
    }
}
