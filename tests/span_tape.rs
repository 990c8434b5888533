//! The span render of one opaque layer (`render::SpanTape`, the fast differentiable render of
//! depth from defocus) against the exact tape (`render::Tape`, itself checked against central
//! differences in tests/backward.rs) and against central differences of its own function, on
//! seeded small scenes: blocks at several depths (depth edges), a slanted plane and pixels
//! near the focal plane; finiteness on extreme inputs.

use crate::common;

use common::Rng;
use drbokeh::Image;
use drbokeh::render::layer::{CHANNELS, D};
use drbokeh::render::{Layer, Profile, RenderSettings, Smoothing, SpanTape, Tape};

/// A `w × h` opaque layer: noise colours (times `gain`), disparity from `depth(x, y)`.
fn layer(w: usize, h: usize, seed: u64, gain: f32, depth: impl Fn(usize, usize) -> f32) -> Layer<'static> {
    let mut rng = Rng::new(seed);
    let mut px = Vec::with_capacity(w * h * CHANNELS);
    for i in 0..w * h {
        px.extend_from_slice(&[rng.next_f32() * gain, rng.next_f32() * gain, rng.next_f32() * gain, 1.0, depth(i % w, i / w)]);
    }
    Layer::new(Image::from_vec(w, h, CHANNELS, px).unwrap(), "span test").unwrap()
}

/// The scenes: (name, layer, blur K, focus). Focus 1 (the nearest plane, as `bench --dfd`)
/// or just off a plane's disparity (pixels near the focal plane).
fn scenes() -> Vec<(&'static str, Layer<'static>, f32, f32)> {
    let (w, h) = (14, 13);
    // Depths off the bins' lattice (multiples of BIN_STEP relative to the focus), where the
    // interpolation has kinks that central differences straddle.
    let blocks = |x: usize, y: usize| {
        if x < 5 {
            1.0
        } else if y < 6 {
            0.6237
        } else {
            0.3071
        }
    };
    let mut rng = Rng::new(77);
    let noisy: Vec<f32> = (0..w * h).map(|_| 0.2 + 0.8 * rng.next_f32()).collect();
    vec![
        ("blocks K6 focus 1", layer(w, h, 1, 1.0, blocks), 6.0, 1.0),
        ("blocks K9 focus 0.99", layer(w, h, 2, 1.0, blocks), 9.0, 0.99),
        ("slant K5 focus 0.5", layer(w, h, 3, 1.0, |x, y| 0.3 + 0.03 * x as f32 + 0.01 * y as f32), 5.0, 0.503),
        ("noise K4 focus 1", layer(w, h, 4, 1.0, |x, y| noisy[y * w + x]), 4.0, 1.0),
        ("near focus K12", layer(w, h, 5, 1.0, |x, y| if (x + y) % 7 < 3 { 0.9813 } else { 0.9042 }), 12.0, 0.97),
    ]
}

/// The settings of a scene: a lens window that holds every disk (as `drbokeh dfd` sizes it).
fn settings(blur: f32, focus: f32, occlusion: bool) -> RenderSettings {
    let reach = (blur * focus.max(1.0 - focus)).ceil() as usize + 3;
    RenderSettings { blur, focus, lens: 2 * reach + 1, occlusion, profile: Profile::Physical, aperture: drbokeh::render::Aperture::DISC }
}

/// A scene's settings from its blur, focus and whether occlusion is on.
type Make = fn(f32, f32, bool) -> RenderSettings;

/// [`settings`] in the official profile.
fn official(blur: f32, focus: f32, occlusion: bool) -> RenderSettings {
    RenderSettings { profile: Profile::Official, ..settings(blur, focus, occlusion) }
}

/// [`official`] with the focus moved off the depth bins' lattice for central differences: a
/// plane exactly in focus (or at any multiple of `BIN_STEP` from it) sits on a kink of the
/// bins' hat weights, and the official footprint (`σ ≥ 1`) spreads even in focus, so its
/// one-sided VJP and the central difference disagree there (the physical in-focus source
/// stays on its own pixel, where the hats do not matter).
fn official_fd(blur: f32, focus: f32, occlusion: bool) -> RenderSettings {
    official(blur, focus + 0.0037, occlusion)
}

/// A seeded cotangent in [-1, 1].
fn cotangent(w: usize, h: usize, seed: u64) -> Image {
    let mut rng = Rng::new(seed);
    Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| 2.0 * rng.next_f32() - 1.0).collect()).unwrap()
}

fn disparity_of(g: &Image) -> Vec<f64> {
    g.data.iter().skip(D).step_by(CHANNELS).map(|&v| v as f64).collect()
}

/// The colour channels (R, G, B) of a layer-shaped gradient.
fn colour_of(g: &Image) -> Vec<f64> {
    g.data.chunks_exact(CHANNELS).flat_map(|px| px[..3].iter().map(|&v| v as f64)).collect()
}

fn f64s(g: &Image) -> Vec<f64> {
    g.data.iter().map(|&v| v as f64).collect()
}

/// `‖a - b‖ / ‖b‖` and `max|a - b| / max|b|`.
fn rel_err(a: &[f64], b: &[f64]) -> (f64, f64) {
    let n2 = |v: &mut dyn Iterator<Item = f64>| v.map(|x| x * x).sum::<f64>().sqrt();
    let diff = n2(&mut a.iter().zip(b).map(|(x, y)| x - y));
    let max_d = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max);
    let max_b = b.iter().fold(0f64, |m, x| m.max(x.abs()));
    (diff / n2(&mut b.iter().copied()).max(1e-30), max_d / max_b.max(1e-30))
}

const SMOOTH: Smoothing = Smoothing { edge_width: 1.0, fill_width: 0.1 };

/// One scene's span render against the exact tape.
struct VsTape {
    name: String,
    /// Max abs difference of the images.
    image: f32,
    /// Disparity gradient: relative L2 and relative max (see [`rel_err`]).
    disparity: (f64, f64),
    /// Colour gradient: relative L2 and relative max.
    colour: (f64, f64),
    /// `|Δ|` of the focus gradient over `Σ|∂L/∂D|` of the tape (the focus gradient is minus
    /// the sum of the disparity gradients, which may cancel), and `|Δ| / max(|tape|, 1e-3)` of
    /// K's.
    focus: f64,
    blur: f64,
}

/// For each seeded scene: the span render against the exact tape with occlusion on or off,
/// printed.
fn span_vs_tape(occlusion: bool, cot_seed: u64) -> Vec<VsTape> {
    span_vs_tape_with(occlusion, cot_seed, settings)
}

fn span_vs_tape_with(occlusion: bool, cot_seed: u64, settings: Make) -> Vec<VsTape> {
    scenes()
        .into_iter()
        .map(|(name, l, blur, focus)| {
            let s = settings(blur, focus, occlusion);
            let (w, h) = (l.width(), l.height());
            let tape = Tape::record(std::slice::from_ref(&l), &s, SMOOTH).unwrap();
            let span = SpanTape::record(&l, &s, SMOOTH).unwrap();
            let dimg = common::max_abs_diff(&span.image().data, &tape.image().data);
            let cot = cotangent(w, h, cot_seed);
            let exact = tape.vjp(&cot).unwrap();
            let fast = span.vjp(&cot).unwrap();
            assert_eq!(fast.disparity, span.disparity_vjp(&cot).unwrap());
            let disparity = rel_err(&f64s(&fast.disparity), &disparity_of(&exact.layers[0]));
            let colour = rel_err(&f64s(&fast.colour), &colour_of(&exact.layers[0]));
            let scalar = |a: f32, b: f32| (a as f64 - b as f64).abs() / (b.abs() as f64).max(1e-3);
            let d_l1: f64 = disparity_of(&exact.layers[0]).iter().map(|v| v.abs()).sum();
            let focus = (fast.focus as f64 - exact.focus as f64).abs() / d_l1.max(1e-3);
            let blur = scalar(fast.blur, exact.blur);
            let what = format!("{:?}, {}", s.profile, if occlusion { "occlusion" } else { "no occlusion" });
            eprintln!(
                "{name}, {what}: image {dimg:.1e}, disparity gradient rel L2 {:.1e}, max {:.1e}; colour {:.1e}, {:.1e}; focus {:.1e} ({} vs {}), K {:.1e} ({} vs {})",
                disparity.0, disparity.1, colour.0, colour.1, focus, fast.focus, exact.focus, blur, fast.blur, exact.blur
            );
            VsTape { name: name.to_string(), image: dimg, disparity, colour, focus, blur }
        })
        .collect()
}

/// Without occlusion the span render is the exact tape's function (one group, no bins): the
/// image to rounding and every gradient (disparity, colour, focus, K) to 1e-5 relative.
#[test]
fn without_occlusion_it_is_the_tape() {
    for t in span_vs_tape(false, 11) {
        let name = &t.name;
        assert!(t.image < 1e-5, "{name}: image differs by {}", t.image);
        assert!(t.disparity.0 < 1e-5 && t.disparity.1 < 1e-5, "{name}: disparity gradient {:?}", t.disparity);
        assert!(t.colour.0 < 1e-5 && t.colour.1 < 1e-5, "{name}: colour gradient {:?}", t.colour);
        assert!(t.focus < 1e-5 && t.blur < 1e-5, "{name}: focus {} K {}", t.focus, t.blur);
    }
}

/// With occlusion the depth groups are interpolated between bins `BIN_STEP` apart: the image
/// within 2e-4 of the tape's (measured 2e-5 … 4e-5) and the disparity gradient within 1% in
/// relative L2 (measured 0.05% … 0.26%) and 2% of the largest entry at the worst pixel
/// (measured 0.09% … 0.35%); the colour gradient within 5e-4 (measured 1.5e-5 … 6.3e-5), the
/// focus gradient (minus the sum of every disparity gradient) within 3% of `Σ|∂L/∂D|`
/// (measured ≤ 0.034%) and K's within 1% (measured 4e-6 … 0.22%).
#[test]
fn with_occlusion_it_is_close_to_the_tape() {
    for t in span_vs_tape(true, 12) {
        let name = &t.name;
        assert!(t.image < 2e-4, "{name}: image differs by {}", t.image);
        assert!(t.disparity.0 < 0.01 && t.disparity.1 < 0.02, "{name}: disparity gradient {:?}", t.disparity);
        assert!(t.colour.0 < 5e-4 && t.colour.1 < 5e-4, "{name}: colour gradient {:?}", t.colour);
        assert!(t.focus < 0.03 && t.blur < 0.01, "{name}: focus {} K {}", t.focus, t.blur);
    }
}

/// The official profile: the span render draws the exact kernel's soft step as the fast
/// kernel does (1 within `σ - 4`, the step out to `σ + 2.5`: within 6.2e-5 of the step), so
/// even without occlusion it differs from the tape by that truncation: the image within 5e-4
/// (measured 3.5e-5 … 1.9e-4), every gradient within 0.5% (measured ≤ 0.24%). With occlusion
/// the in-front weight `f`, interpolated between depth bins, has a steeper slope than the
/// physical groups where the target is in focus (`q = 0`): the disparity gradient within 8%
/// relative L2 (measured 0.18% … 3.5%; the interpolant's slope is piecewise constant), the
/// image, colour, focus and K as without.
#[test]
fn official_profile_is_close_to_the_tape() {
    for occlusion in [false, true] {
        let grad = if occlusion { 0.08 } else { 5e-3 };
        for t in span_vs_tape_with(occlusion, 14, official) {
            let name = &t.name;
            assert!(t.image < 5e-4, "{name}: image differs by {}", t.image);
            assert!(t.disparity.0 < grad && t.disparity.1 < grad, "{name}: disparity gradient {:?}", t.disparity);
            assert!(t.colour.0 < 5e-3 && t.colour.1 < 5e-3, "{name}: colour gradient {:?}", t.colour);
            assert!(t.focus < grad && t.blur < 0.01, "{name}: focus {} K {}", t.focus, t.blur);
        }
    }
}

/// The cases of the central-difference checks: the first four scenes, occlusion on and off,
/// both profiles (the official one off the bins' lattice, see [`official_fd`]).
fn fd_cases() -> Vec<(&'static str, Layer<'static>, RenderSettings)> {
    let makes: [(bool, Make); 4] = [(true, settings), (false, settings), (true, official_fd), (false, official_fd)];
    scenes()
        .into_iter()
        .take(4)
        .flat_map(|(name, l, blur, focus)| makes.map(|(occlusion, make)| (name, l.clone(), make(blur, focus, occlusion))))
        .collect()
}

/// `<cot, span render of layer>`: the scalar the central differences differentiate.
fn dot_loss(layer: &Layer, s: &RenderSettings, cot: &Image) -> f64 {
    let t = SpanTape::record(layer, s, SMOOTH).unwrap();
    t.image().data.iter().zip(&cot.data).map(|(a, b)| *a as f64 * *b as f64).sum()
}

/// How uncertain the central differences below are in absolute terms: the f32 render's
/// rounding (~1e-6 on the loss, over steps of 2·5e-4) moves them by ~1e-3.
const NOISE: f64 = 1e-3;

/// The VJP is the derivative of the span render's own function: central differences of
/// `<cot, image>` in every pixel's disparity (step 5e-4, checked against 2e-3: where they
/// disagree by more than 2% the function is not smooth there, e.g. a depth bin's centre or
/// the kink of `|d|` at the focal plane, and the pixel is skipped), both occlusion settings;
/// they agree to 2% plus 0.5% of the largest gradient plus `NOISE`; the worst relative error
/// where the difference is above `10·NOISE` is reported. Both profiles (the official one with
/// its focus off the bins' lattice, see [`official_fd`]).
#[test]
fn vjp_matches_central_differences() {
    let mut worst = 0f64;
    let (mut checked, mut skipped) = (0, 0);
    for (name, l, s) in fd_cases() {
        let occlusion = s.occlusion;
        let (w, h) = (l.width(), l.height());
        let cot = cotangent(w, h, 13);
        let span = SpanTape::record(&l, &s, SMOOTH).unwrap();
        let g = span.disparity_vjp(&cot).unwrap();
        let gmax = g.data.iter().fold(0f32, |m, v| m.max(v.abs())) as f64;
        let loss = |i: usize, dv: f32| {
            let mut img = l.image().to_image();
            img.data[i * CHANNELS + D] += dv;
            dot_loss(&Layer::new(img, "fd").unwrap(), &s, &cot)
        };
        for i in 0..w * h {
            let fd = |hh: f32| (loss(i, hh) - loss(i, -hh)) / (2.0 * hh as f64);
            let (a, b) = (fd(2e-3), fd(5e-4));
            if (a - b).abs() > 0.02 * a.abs().max(b.abs()) + 2e-3 * gmax + NOISE {
                skipped += 1;
                continue;
            }
            checked += 1;
            let diff = (g.data[i] as f64 - b).abs();
            if b.abs() > 10.0 * NOISE {
                worst = worst.max(diff / b.abs());
            }
            assert!(
                diff <= 0.02 * b.abs() + 0.005 * gmax + NOISE,
                "{name} {:?} occlusion {occlusion} pixel {i}: vjp {} vs fd {b} (fd 4h {a})",
                s.profile,
                g.data[i]
            );
        }
    }
    eprintln!("span VJP vs central differences: {checked} pixels checked, {skipped} not smooth, worst relative error {worst:.1e}");
    assert!(skipped * 5 < checked, "{skipped} of {} skipped", checked + skipped);
}

/// The colour, focus and K gradients are the derivatives of the span render's own function:
/// central differences of `<cot, image>` in 12 pixels' colour channels (the render is linear in
/// colour: one step, 1e-2), in the focus and in K (steps 5e-4 and 2e-3 as above, skipped where
/// the two disagree: a depth bin's kink crossed by some pixel), both occlusion settings, both
/// profiles.
#[test]
fn colour_focus_and_k_gradients_match_central_differences() {
    let mut checked = 0;
    for (name, l, s) in fd_cases() {
        let occlusion = s.occlusion;
        let (w, h) = (l.width(), l.height());
        let cot = cotangent(w, h, 17);
        let g = SpanTape::record(&l, &s, SMOOTH).unwrap().vjp(&cot).unwrap();
        let loss = |layer: &Layer, s: &RenderSettings| dot_loss(layer, s, &cot);
        let what = format!("{name} {:?} occlusion {occlusion}", s.profile);
        for i in (0..w * h).step_by(w * h / 12) {
            for c in 0..3 {
                let at = |dv: f32| {
                    let mut img = l.image().to_image();
                    img.data[i * CHANNELS + c] += dv;
                    loss(&Layer::new(img, "fd").unwrap(), &s)
                };
                let fd = (at(1e-2) - at(-1e-2)) / 2e-2;
                let got = g.colour.data[i * 3 + c] as f64;
                assert!((got - fd).abs() <= 1e-3 * fd.abs() + 2e-4, "{what} pixel {i} channel {c}: vjp {got} vs fd {fd}");
                checked += 1;
            }
        }
        for (which, got) in [("focus", g.focus), ("K", g.blur)] {
            let at = |dv: f32| {
                let mut s2 = s;
                if which == "focus" {
                    s2.focus += dv
                } else {
                    s2.blur += dv
                }
                loss(&l, &s2)
            };
            let fd = |hh: f32| (at(hh) - at(-hh)) / (2.0 * hh as f64);
            let (a, b) = (fd(2e-3), fd(5e-4));
            if (a - b).abs() > 0.02 * a.abs().max(b.abs()) + NOISE {
                eprintln!("{what} {which}: not smooth here (fd {a} vs {b})");
                continue;
            }
            let got = got as f64;
            eprintln!("{what} {which}: vjp {got:.5} fd {b:.5}");
            // The official footprint is truncated (1 within σ - 4, nothing beyond σ + 2.5):
            // as K or the focus moves every radius, taps cross those edges and the function
            // jumps by up to 6e-5 of a tap's weight, which central differences pick up and
            // the VJP (of the smooth pieces) does not.
            let tol = if s.profile == Profile::Official { 0.02 * b.abs() + 5.0 * NOISE } else { 0.02 * b.abs() + NOISE };
            assert!((got - b).abs() <= tol, "{what} {which}: vjp {got} vs fd {b} (fd 4h {a})");
            checked += 1;
        }
    }
    assert!(checked >= 16 * 36 + 24, "{checked} checks");
}

/// Finite images and gradients on the extreme grid: K up to 1e4, HDR colours 1e4 beside 0,
/// disparity steps 0/1, focus on a plane and outside [0, 1], hard cotangents; both profiles.
#[test]
fn extreme_inputs_give_finite_gradients() {
    let (w, h) = (9, 8);
    let mut n = 0;
    for blur in [0.0f32, 1.0, 30.0, 1e4] {
        for gain in [1.0f32, 1e4] {
            for focus in [1.0f32, 0.0, -3.0] {
                for (occlusion, profile) in [true, false].into_iter().flat_map(|o| [(o, Profile::Physical), (o, Profile::Official)]) {
                    let l = layer(w, h, 21, gain, |x, y| if (x / 3 + y / 3) % 2 == 0 { 1.0 } else { 0.0 });
                    let s = RenderSettings { blur, focus, lens: 15, occlusion, profile, aperture: drbokeh::render::Aperture::DISC };
                    let span = SpanTape::record(&l, &s, SMOOTH).unwrap();
                    assert!(span.image().all_finite());
                    let mut cot = cotangent(w, h, 5);
                    cot.data.iter_mut().for_each(|v| *v *= 1e20);
                    let g = span.vjp(&cot).unwrap();
                    let what = format!("K {blur} gain {gain} focus {focus} occlusion {occlusion} {profile:?}");
                    assert!(g.disparity.all_finite() && g.colour.all_finite(), "{what}");
                    assert!(g.focus.is_finite() && g.blur.is_finite(), "{what}");
                    n += 1;
                }
            }
        }
    }
    assert_eq!(n, 96);
}

/// The span render refuses what it does not model: a layer with alpha below 1, a cotangent of
/// the wrong size.
#[test]
fn refuses_what_it_does_not_model() {
    let l = layer(6, 5, 1, 1.0, |_, _| 0.5);
    let mut img = l.image().to_image();
    img.data[3] = 0.5;
    let half = Layer::new(img, "half").unwrap();
    assert!(SpanTape::record(&half, &settings(4.0, 1.0, true), SMOOTH).err().unwrap().to_string().contains("opaque"));
    let t = SpanTape::record(&l, &settings(4.0, 1.0, true), SMOOTH).unwrap();
    assert!(t.disparity_vjp(&Image::new(5, 5, 3)).unwrap_err().to_string().contains("5x5"));
}
