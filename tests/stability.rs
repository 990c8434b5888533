//! Numerical stability on stiff and extreme inputs (property-based): every kernel gives finite
//! output, inside the per-channel range of the input colours when the back layer is opaque,
//! and a uniform colour stays that colour, for extreme K, focus, disparity, alpha and HDR
//! colour, on both profiles (README's reliability table promises every kernel and quality; the
//! physical profile is the default). Also: the f32 accumulation error of the largest windows
//! against f64.

use drbokeh::Image;
use drbokeh::render::{self, Kernel, Layer, Profile, RenderSettings};
use proptest::prelude::*;

/// Every profile a render can use: each property below runs on both.
const PROFILES: [Profile; 2] = [Profile::Physical, Profile::Official];

const BLURS: [f32; 5] = [0.0, 1e-6, 1.0, 1e3, 1e6];
const FOCI: [f32; 5] = [-10.0, 0.0, 0.5, 1.0, 10.0];

#[derive(Clone, Copy, Debug)]
enum DispKind {
    Step,
    Spike,
    Constant,
    Zero,
    One,
    Random,
}

#[derive(Clone, Copy, Debug)]
enum AlphaKind {
    Zero,
    One,
    Random,
    Speck,
}

fn disparity(kind: DispKind, x: usize, y: usize, w: usize, r: f32) -> f32 {
    match kind {
        DispKind::Step => (x * 2 >= w) as u8 as f32,
        DispKind::Spike => ((x + y) % 7 == 3) as u8 as f32,
        DispKind::Constant => 0.37,
        DispKind::Zero => 0.0,
        DispKind::One => 1.0,
        DispKind::Random => r,
    }
}

/// A seeded generator of uniform numbers in [0, 1) (xorshift64).
fn uniform01(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed | 1;
    move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 40) as f32 / (1u64 << 24) as f32
    }
}

/// The colour of every pixel of [`make_layers`]'s uniform scenes: 0.25, or 0.25e6 with HDR.
fn uniform_colour(hdr: bool) -> f32 {
    0.25 * if hdr { 1e6 } else { 1.0 }
}

fn make_layers(w: usize, h: usize, d: DispKind, a: AlphaKind, hdr: bool, seed: u64, uniform: bool) -> Vec<Layer<'static>> {
    let mut rnd = uniform01(seed);
    let scale = if hdr { 1e6 } else { 1.0 };
    let mut fg = Vec::new();
    let mut bg = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let c = |v: f32| {
                if uniform {
                    uniform_colour(hdr)
                } else if v < 0.1 {
                    0.0
                } else {
                    v * scale
                }
            };
            let alpha = match a {
                AlphaKind::Zero => 0.0,
                AlphaKind::One => 1.0,
                AlphaKind::Random => rnd(),
                AlphaKind::Speck => ((x * 31 + y * 17) % 13 == 0) as u8 as f32,
            };
            let (r1, r2, r3, r4) = (rnd(), rnd(), rnd(), rnd());
            fg.extend_from_slice(&[c(r1), c(r2), c(r3), alpha, disparity(d, x, y, w, r4)]);
            let (r1, r2, r3, r4) = (rnd(), rnd(), rnd(), rnd());
            bg.extend_from_slice(&[c(r1), c(r2), c(r3), 1.0, disparity(d, y, x, h, r4) * 0.5]);
        }
    }
    vec![Layer::new(Image::from_vec(w, h, 5, fg).unwrap(), "fg").unwrap(), Layer::new(Image::from_vec(w, h, 5, bg).unwrap(), "bg").unwrap()]
}

/// What [`check`] asks of a render besides finite output inside the input colours' range.
#[derive(Clone, Copy, Debug)]
enum Expect {
    /// Nothing more.
    InRange,
    /// Every channel of every pixel is this colour (relative 1e-4): the scene is one colour.
    Uniform(f32),
}

fn check(layers: &[Layer], s: &RenderSettings, kernel: Kernel, expect: Expect) -> Result<(), TestCaseError> {
    let out = render::render(layers, s, kernel).unwrap();
    let what = format!("{kernel:?}, {:?}", s.profile);
    prop_assert!(out.all_finite(), "{what}: non-finite output");
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for l in layers {
        for px in l.image().data.chunks_exact(5) {
            for c in 0..3 {
                lo[c] = lo[c].min(px[c]);
                hi[c] = hi[c].max(px[c]);
            }
        }
    }
    for px in out.data.chunks_exact(3) {
        for c in 0..3 {
            let tol = 1e-5 * hi[c].abs().max(1.0);
            // The back layer is opaque, so the composite is a convex combination... of the
            // layers' colours, up to the non-focal terms summing to at most 1.
            prop_assert!(px[c] <= hi[c] + tol, "{what}: {} above the input range [{}, {}]", px[c], lo[c], hi[c]);
            prop_assert!(px[c] >= 0.0f32.min(lo[c]) - tol, "{what}: {} below the input range", px[c]);
            if let Expect::Uniform(want) = expect {
                // The colour is known: black, or any other colour, is a failure.
                prop_assert!((px[c] - want).abs() <= 1e-4 * want, "{what}: uniform colour changed: {} vs {want}", px[c]);
            }
        }
    }
    Ok(())
}

fn disp_kind() -> impl Strategy<Value = DispKind> {
    prop_oneof![
        Just(DispKind::Step),
        Just(DispKind::Spike),
        Just(DispKind::Constant),
        Just(DispKind::Zero),
        Just(DispKind::One),
        Just(DispKind::Random)
    ]
}

fn alpha_kind() -> impl Strategy<Value = AlphaKind> {
    prop_oneof![Just(AlphaKind::Zero), Just(AlphaKind::One), Just(AlphaKind::Random), Just(AlphaKind::Speck)]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(9), ..ProptestConfig::default() })]

    #[test]
    fn every_kernel_is_finite_and_in_range(
        shape in prop_oneof![Just((1usize, 1usize)), Just((1, 9)), Just((9, 1)), (2usize..12, 2usize..10)],
        k in 0usize..5, f in 0usize..5, d in disp_kind(), a in alpha_kind(), hdr in any::<bool>(), seed in any::<u64>(),
    ) {
        let (w, h) = shape;
        let layers = make_layers(w, h, d, a, hdr, seed, false);
        let (blur, focus) = (BLURS[k], FOCI[f]);
        let lens = render::auto_lens(&layers, blur, focus);
        for profile in PROFILES {
            let s = RenderSettings { blur, focus, lens, occlusion: true, profile, aperture: drbokeh::render::Aperture::DISC };
            check(&layers, &s, Kernel::Exact, Expect::InRange)?;
            check(&layers, &s, Kernel::Fast { quality: 2 }, Expect::InRange)?;
            check(&layers, &RenderSettings { occlusion: false, ..s }, Kernel::Fast { quality: 2 }, Expect::InRange)?;
        }
    }

    #[test]
    fn uniform_colour_stays_uniform(
        shape in prop_oneof![Just((1usize, 1usize)), Just((1, 7)), Just((7, 1)), (2usize..10, 2usize..8)],
        k in 0usize..5, f in 0usize..5, d in disp_kind(), hdr in any::<bool>(), seed in any::<u64>(),
    ) {
        let (w, h) = shape;
        let layers = make_layers(w, h, d, AlphaKind::One, hdr, seed, true);
        let (blur, focus) = (BLURS[k], FOCI[f]);
        let want = Expect::Uniform(uniform_colour(hdr));
        for profile in PROFILES {
            let s = RenderSettings { blur, focus, lens: render::auto_lens(&layers, blur, focus), occlusion: true, profile, aperture: drbokeh::render::Aperture::DISC };
            check(&layers, &s, Kernel::Exact, want)?;
            check(&layers, &s, Kernel::Fast { quality: 2 }, want)?;
        }
    }
}

#[test]
fn long_thin_image_with_huge_blur_is_finite() {
    let layers = make_layers(1000, 3, DispKind::Random, AlphaKind::Random, true, 7, false);
    for profile in PROFILES {
        for k in [1e3f32, 1e6] {
            let s = RenderSettings {
                blur: k,
                focus: 0.5,
                lens: render::auto_lens(&layers, k, 0.5),
                occlusion: true,
                profile,
                aperture: drbokeh::render::Aperture::DISC,
            };
            let out = render::render(&layers, &s, Kernel::Fast { quality: 2 }).unwrap();
            assert!(out.all_finite(), "{profile:?}, K {k}");
        }
    }
}

/// Colours beyond `render::SAFE_COLOUR` are rendered scaled by a power of two: the render is
/// linear in colour, so layers whose colours are 2^110 (about 1.3e33) times another's render to
/// 2^110 times its render, on every profile and kernel, occluding layers included.
#[test]
fn colours_beyond_the_safe_range_render_as_scaled_copies() {
    let layers = make_layers(24, 18, DispKind::Random, AlphaKind::Random, false, 11, false);
    let up = 2f32.powi(110);
    assert!(up > render::SAFE_COLOUR);
    let huge: Vec<Layer<'static>> = layers
        .iter()
        .map(|l| {
            let mut img = l.image().to_image();
            img.data.chunks_exact_mut(5).for_each(|px| px[..3].iter_mut().for_each(|c| *c *= up));
            Layer::new(img, "huge").unwrap()
        })
        .collect();
    for profile in PROFILES {
        for kernel in [Kernel::Exact, Kernel::Fast { quality: 2 }] {
            let s = RenderSettings {
                blur: 6.0,
                focus: 0.5,
                lens: render::auto_lens(&layers, 6.0, 0.5),
                occlusion: true,
                profile,
                aperture: drbokeh::render::Aperture::DISC,
            };
            let (a, b) = (render::render(&layers, &s, kernel).unwrap(), render::render(&huge, &s, kernel).unwrap());
            let peak = a.data.iter().fold(0f32, |m, v| m.max(v.abs()));
            for (x, y) in a.data.iter().zip(&b.data) {
                assert!((y / up - x).abs() <= 1e-6 * peak, "{profile:?} {kernel:?}: {x} vs {}", y / up);
            }
        }
    }
}

/// The largest windows' weight sums, accumulated in f32 as the official code does, against
/// f64: the relative error is reported; the exact kernel accumulates in f64 for this reason.
#[test]
fn f32_accumulation_error_of_large_windows() {
    use drbokeh::render::lens::{energy, focal_defocus, occlusion};
    for p in [16i32, 64, 128] {
        let (mut s32, mut s64) = (0f32, 0f64);
        let (mut c32, mut c64) = (0f32, 0f64);
        let q = focal_defocus(0.3, 30.0);
        for di in -p..=p {
            for dj in -p..=p {
                let r = ((di * di + dj * dj) as f32).sqrt();
                if r >= p as f32 {
                    continue;
                }
                let sigma = 1.0 + ((di * 7 + dj * 13).rem_euclid(97)) as f32 * (p as f32 / 97.0);
                let wt = energy(sigma, r, 1.0) * occlusion(q, 0.1, 0.3);
                let c = 0.1 + ((di * 3 + dj * 5).rem_euclid(11)) as f32 / 11.0;
                s32 += wt;
                s64 += wt as f64;
                c32 += wt * c;
                c64 += (wt * c) as f64;
            }
        }
        let rel = ((c32 / s32) as f64 - c64 / s64).abs() / (c64 / s64);
        let rel_w = (s32 as f64 - s64).abs() / s64;
        println!("window radius {p}: f32 relative error of W {rel_w:.2e}, of C = ΣcW/ΣW {rel:.2e}");
        assert!(rel < 1e-3);
    }
}

/// Mean of each RGB channel.
fn channel_means(img: &Image) -> [f64; 3] {
    let mut m = [0f64; 3];
    for px in img.data.chunks_exact(3) {
        for c in 0..3 {
            m[c] += px[c] as f64;
        }
    }
    m.map(|v| v / (img.width * img.height) as f64)
}

/// A textured opaque background and a soft-edged textured foreground disk, each with its own
/// depth variation, `w × h`.
fn disk_scene(w: usize, h: usize, seed: u64, fg_d: f32, bg_d: f32) -> Vec<Layer<'static>> {
    let mut rnd = uniform01(seed);
    let (cx, cy, rad) = (w as f32 * 0.45, h as f32 * 0.55, w.min(h) as f32 * 0.3);
    let (mut fg, mut bg) = (Vec::new(), Vec::new());
    for y in 0..h {
        for x in 0..w {
            let r = ((x as f32 + 0.5 - cx).powi(2) + (y as f32 + 0.5 - cy).powi(2)).sqrt();
            let a = (rad + 0.5 - r).clamp(0.0, 1.0);
            fg.extend_from_slice(&[0.2 + 0.6 * rnd(), 0.1 + 0.3 * rnd(), 0.7 * rnd(), a, fg_d + 0.05 * rnd()]);
            bg.extend_from_slice(&[0.3 + 0.5 * rnd(), 0.2 + 0.6 * rnd(), 0.4 + 0.2 * rnd(), 1.0, bg_d + 0.05 * rnd()]);
        }
    }
    vec![Layer::new(Image::from_vec(w, h, 5, fg).unwrap(), "fg").unwrap(), Layer::new(Image::from_vec(w, h, 5, bg).unwrap(), "bg").unwrap()]
}

proptest! {
    // A fixed seed: the cases are the same on every run (CI must not depend on luck).
    #![proptest_config(ProptestConfig { cases: 6, failure_persistence: None, rng_seed: proptest::test_runner::RngSeed::Fixed(10), ..ProptestConfig::default() })]

    /// Issue 10: every quality level × circles of confusion from 0 to far beyond the image ×
    /// both kernels × both profiles, with and without occlusion: the output is finite and keeps
    /// the light. The
    /// exact kernel's mean stays near the input's (at huge blur it is the image's average);
    /// every fast quality's mean stays near the exact kernel's.
    #[test]
    fn light_is_conserved_at_every_quality_and_coc(
        shape in prop_oneof![Just((32usize, 24usize)), Just((17, 40)), Just((48, 9))],
        focus in prop_oneof![Just(0.85f32), Just(0.5), Just(0.05), Just(0.9), Just(0.1)], seed in any::<u64>(),
    ) {
        let (w, h) = shape;
        // Layers at disparities [0.9, 0.95] and [0.1, 0.15]. With the focus off both ranges,
        // every layer's radii vary by a bounded ratio, and the exact mean must stay near the
        // input's. With the focus on a layer's near edge, its few pixels right on the focal
        // plane outweigh the rest at a huge blur (weights ∝ 1/σ²), which moves the exact mean
        // legitimately: there only the fast kernel is compared (with the exact one).
        let layers = disk_scene(w, h, seed, 0.9, 0.1);
        let focus_off_layers = focus != 0.9 && focus != 0.1;
        let input = channel_means(&render::alpha_composite(&layers));
        // Every failing combination is listed, not only the first.
        let mut failures = Vec::new();
        // Largest CoC in pixels, about K·0.85 (the farthest layer's relative disparity).
        for coc in [0.0f32, 0.4, 1.0, 3.0, 8.0, 20.0, 35.0, 60.0, 150.0, 1e3, 5e3, 1e5, 1e8] {
            let blur = coc / 0.85;
            for (occlusion, profile) in [true, false].into_iter().flat_map(|o| PROFILES.map(|p| (o, p))) {
                let s = RenderSettings { blur, focus, lens: render::auto_lens(&layers, blur, focus), occlusion, profile, aperture: drbokeh::render::Aperture::DISC };
                let exact = render::render(&layers, &s, Kernel::Exact).unwrap();
                prop_assert!(exact.all_finite(), "{profile:?} exact: non-finite output at CoC {coc}");
                let me = channel_means(&exact);
                let worst = (0..3).map(|c| (me[c] - input[c]).abs() / input[c]).fold(0.0, f64::max);
                // Loose: eq. 4's visibility box reads replicate-padded alpha, so at a blur as wide
                // as the image it over-weights the border (16% off the input's mean seen here).
                // The physical profile's worst on these cases: 12.0% (official 11.9%), at CoC 1e3.
                if focus_off_layers && worst >= 0.25 {
                    failures.push(format!("{profile:?} exact, CoC {coc}, occlusion {occlusion}: mean {me:?} vs input {input:?} ({:.1}%)", worst * 100.0));
                }
                for quality in 1..=8 {
                    let fast = render::render(&layers, &s, Kernel::Fast { quality }).unwrap();
                    prop_assert!(fast.all_finite(), "{profile:?} fast q{quality}: non-finite output at CoC {coc}");
                    let mf = channel_means(&fast);
                    let worst = (0..3).map(|c| (mf[c] - me[c]).abs() / me[c]).fold(0.0, f64::max);
                    // With the focus on a layer's near edge and a blur beyond 1e5 px, the few
                    // pixels nearest the focal plane carry nearly all of the 1/σ² weight, and the
                    // coarse grids of quality 1–3 place their window-sized disks within a cell
                    // (6.8% at quality 1 seen here): a light loss would still be far beyond 10%.
                    let tol = if !focus_off_layers && coc >= 1e5 { 0.10 } else { 0.03 };
                    if worst >= tol {
                        failures.push(format!("{profile:?} fast q{quality}, CoC {coc}, occlusion {occlusion}: mean {mf:?} vs exact {me:?} ({:.1}%)", worst * 100.0));
                    }
                }
            }
        }
        prop_assert!(failures.is_empty(), "{} failing settings ({w}x{h}, focus {focus}):\n{}", failures.len(), failures.join("\n"));
    }
}
