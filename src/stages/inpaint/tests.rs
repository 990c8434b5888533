use super::*;

/// Deterministic pseudo-random values in 0..255 (integer codes), any channel count.
fn noise_image(w: usize, h: usize, ch: usize, seed: u64) -> Image {
    let mut s = seed;
    let data = (0..w * h * ch)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 33) % 256) as f32
        })
        .collect();
    Image::from_vec(w, h, ch, data).unwrap()
}

/// Buckets pop in order of T rounded down to 1/16 px, first-in first-out within one, and a
/// push below the current bucket joins the current one.
#[test]
fn buckets_pop_by_rounded_t_then_fifo() {
    let mut b = Buckets::new();
    for (t, c) in [(0.0f32, 1usize), (0.5, 2), (0.03, 3), (0.51, 4), (0.0, 5), (2.0, 6)] {
        b.push(t, c);
    }
    let mut got = Vec::new();
    while let Some(c) = b.pop() {
        got.push(c);
        if c == 2 {
            // Below the current bucket (0.5): popped next, before 6.
            b.push(0.1, 7);
        }
    }
    assert_eq!(got, vec![1, 3, 5, 2, 4, 7, 6]);
    assert!(b.pop().is_none());
}

fn all_modes() -> [Option<OpenCvCompat>; 4] {
    [None, Some(OpenCvCompat::u8(1.0)), Some(OpenCvCompat::u16(1.0)), Some(OpenCvCompat::f32())]
}

fn opts(radius: f32, compat: Option<OpenCvCompat>) -> TeleaOptions {
    TeleaOptions { compat, ..TeleaOptions::new(radius) }
}

/// Fills and checks the invariants every fill must keep: known pixels untouched, output
/// finite, count = masked pixels when something is known.
fn fill_checked(img: &Image, mask: &[bool], o: TeleaOptions) -> Image {
    let mut out = img.clone();
    let filled = inpaint_telea(&mut out, mask, o).unwrap();
    let masked = mask.iter().filter(|&&m| m).count();
    let expect = if masked == mask.len() { 0 } else { masked };
    assert_eq!(filled, expect, "{}x{} {:?}", img.width, img.height, o);
    let c = img.channels;
    for (i, &m) in mask.iter().enumerate() {
        for k in 0..c {
            let (a, b) = (img.data[i * c + k], out.data[i * c + k]);
            assert!(b.is_finite(), "non-finite output at {i}");
            if !m || masked == mask.len() {
                assert_eq!(a.to_bits(), b.to_bits(), "pixel {i} changed");
            }
        }
    }
    out
}

#[test]
fn empty_mask_is_a_no_op() {
    let img = noise_image(7, 5, 3, 1);
    for compat in all_modes() {
        let mut out = img.clone();
        assert_eq!(inpaint_telea(&mut out, &[false; 35], opts(3.0, compat)).unwrap(), 0);
        assert_eq!(out, img);
    }
}

#[test]
fn full_mask_leaves_the_image_unchanged() {
    let img = noise_image(6, 4, 1, 2);
    for compat in all_modes() {
        let mut out = img.clone();
        assert_eq!(inpaint_telea(&mut out, &[true; 24], opts(3.0, compat)).unwrap(), 0);
        assert_eq!(out, img);
    }
}

#[test]
fn empty_and_single_pixel_images() {
    let mut empty = Image::new(0, 3, 2);
    assert_eq!(inpaint_telea(&mut empty, &[], TeleaOptions::new(3.0)).unwrap(), 0);
    for m in [false, true] {
        for compat in all_modes() {
            let img = Image::filled(1, 1, 3, 7.0);
            fill_checked(&img, &[m], opts(5.0, compat));
        }
    }
}

#[test]
fn one_row_and_one_column_images() {
    for (w, h) in [(1, 9), (9, 1), (2, 7), (7, 2)] {
        let img = noise_image(w, h, 2, 3);
        let masks: [Vec<bool>; 4] = [
            (0..w * h).map(|i| i % 3 == 1).collect(),
            (0..w * h).map(|i| i != 0).collect(),
            (0..w * h).map(|i| i + 1 != w * h).collect(),
            (0..w * h).map(|i| i == 0 || i + 1 == w * h).collect(),
        ];
        for mask in &masks {
            for compat in all_modes() {
                for r in [1.0, 3.0, 7.0] {
                    fill_checked(&img, mask, opts(r, compat));
                }
            }
        }
    }
}

#[test]
fn masks_on_the_border() {
    let (w, h) = (11, 8);
    let img = noise_image(w, h, 3, 4);
    let frame: Vec<bool> = (0..w * h).map(|i| i % w == 0 || i % w == w - 1 || i / w == 0 || i / w == h - 1).collect();
    let corner: Vec<bool> = (0..w * h).map(|i| i % w < 3 && i / w < 3).collect();
    let last_row: Vec<bool> = (0..w * h).map(|i| i / w == h - 1).collect();
    let all_but_one: Vec<bool> = (0..w * h).map(|i| i != w * h / 2).collect();
    for mask in [&frame, &corner, &last_row, &all_but_one] {
        for compat in all_modes() {
            for r in [1.0, 2.0, 5.0] {
                fill_checked(&img, mask, opts(r, compat));
            }
        }
    }
}

#[test]
fn plain_fill_stays_within_the_known_range_and_keeps_constants() {
    let (w, h) = (20, 16);
    let img = noise_image(w, h, 1, 5);
    let mask: Vec<bool> = (0..w * h).map(|i| (4..12).contains(&(i % w)) && (3..13).contains(&(i / w))).collect();
    let out = fill_checked(&img, &mask, TeleaOptions::new(4.0));
    let known = img.data.iter().zip(&mask).filter(|(_, m)| !**m).map(|(v, _)| *v);
    let (lo, hi) = known.fold((f32::MAX, f32::MIN), |(a, b), v| (a.min(v), b.max(v)));
    assert!(out.data.iter().all(|&v| v >= lo - 1e-3 && v <= hi + 1e-3));
    let flat = fill_checked(&Image::filled(w, h, 1, 0.25), &mask, TeleaOptions::new(4.0));
    assert!(flat.data.iter().all(|&v| (v - 0.25).abs() < 1e-6));
}

#[test]
fn channels_are_filled_independently() {
    let (w, h) = (15, 12);
    for chans in [3, 5] {
        channels_independent(w, h, chans);
    }
}

fn channels_independent(w: usize, h: usize, chans: usize) {
    let img = noise_image(w, h, chans, 6);
    let mask: Vec<bool> = (0..w * h).map(|i| (i % w + i / w) % 5 < 2 && i % w > 2).collect();
    for compat in all_modes() {
        let whole = fill_checked(&img, &mask, opts(3.0, compat));
        for c in 0..chans {
            let single = fill_checked(&img.channel(c), &mask, opts(3.0, compat));
            assert_eq!(
                whole.channel(c).data.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                single.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
            );
        }
    }
}

#[test]
fn unknown_values_are_never_read_by_the_plain_fill() {
    let (w, h) = (12, 10);
    let mut img = noise_image(w, h, 1, 7);
    let mask: Vec<bool> = (0..w * h).map(|i| (2..9).contains(&(i % w)) && i / w < 6).collect();
    for (v, &m) in img.data.iter_mut().zip(&mask) {
        if m {
            *v = f32::NAN;
        }
    }
    let mut out = img.clone();
    inpaint_telea(&mut out, &mask, TeleaOptions::new(3.0)).unwrap();
    assert!(out.data.iter().all(|v| v.is_finite()));
}

#[test]
fn max_distance_limits_the_fill() {
    let (w, h) = (30, 9);
    let img = noise_image(w, h, 1, 8);
    // A band of 20 columns: hole pixels are at most 10 from the known columns on either side.
    let mask: Vec<bool> = (0..w * h).map(|i| (5..25).contains(&(i % w))).collect();
    let mut out = img.clone();
    let o = TeleaOptions { max_distance: Some(3.0), ..TeleaOptions::new(3.0) };
    let filled = inpaint_telea(&mut out, &mask, o).unwrap();
    assert_eq!(filled, 6 * h);
    for y in 0..h {
        for x in 8..22 {
            assert_eq!(out.pixel(x, y)[0].to_bits(), img.pixel(x, y)[0].to_bits(), "({x}, {y}) was filled");
        }
    }
    let mut all = img.clone();
    let o = TeleaOptions { max_distance: Some(10.0), ..TeleaOptions::new(3.0) };
    assert_eq!(inpaint_telea(&mut all, &mask, o).unwrap(), 20 * h);
}

#[test]
fn invalid_arguments_are_errors_and_leave_the_image_alone() {
    let img = noise_image(4, 3, 1, 9);
    let mask = vec![true, false, false, false, false, false, false, false, false, false, false, true];
    let bad = |mask: &[bool], o: TeleaOptions| {
        let mut out = img.clone();
        let r = inpaint_telea(&mut out, mask, o);
        assert!(matches!(r, Err(Error::Usage(_))), "{o:?}: {r:?}");
        assert_eq!(out, img);
    };
    bad(&mask[..11], TeleaOptions::new(3.0));
    bad(&[mask.clone(), vec![false]].concat(), TeleaOptions::new(3.0));
    bad(&mask, TeleaOptions::new(f32::NAN));
    bad(&mask, TeleaOptions::new(-1.0));
    bad(&mask, TeleaOptions { max_distance: Some(f32::NAN), ..TeleaOptions::new(3.0) });
    bad(&mask, opts(3.0, Some(OpenCvCompat::u8(0.0))));
    bad(&mask, opts(3.0, Some(OpenCvCompat { unit: 1.0, max_code: Some(f32::NAN) })));
    let mut wrong = img.clone();
    wrong.data.pop();
    assert!(inpaint_telea(&mut wrong, &mask, TeleaOptions::new(3.0)).is_err());
    // Out-of-range radii are clamped like OpenCV's, not refused.
    for r in [0.0, 0.4, f32::INFINITY, 1e9] {
        fill_checked(&img, &mask, TeleaOptions::new(r));
    }
}

/// The window the fill runs on gives the whole-image march's result, bit for bit, in every
/// mode: small holes far from the border, holes at the border, and the complement of a
/// small known region with a distance limit (the depth fill's case).
#[test]
fn the_window_fill_is_the_whole_image_fill() {
    let (w, h) = (64, 48);
    let img = noise_image(w, h, 3, 11);
    let disc = |cx: f32, cy: f32, r: f32| move |i: usize| ((i % w) as f32 - cx).powi(2) + ((i / w) as f32 - cy).powi(2) < r * r;
    let masks: Vec<Vec<bool>> = vec![
        (0..w * h).map(disc(30.0, 20.0, 6.0)).collect(),
        (0..w * h).map(|i| disc(3.0, 40.0, 7.0)(i) || disc(50.0, 10.0, 3.0)(i)).collect(),
        (0..w * h).map(|i| !disc(32.0, 24.0, 8.0)(i)).collect(),
        (0..w * h).map(|i| !(disc(20.0, 20.0, 4.0)(i) || disc(45.0, 30.0, 2.0)(i))).collect(),
    ];
    for mask in &masks {
        for compat in all_modes() {
            for (r, md) in [(3.0, None), (5.0, Some(4.0)), (2.0, Some(0.5)), (4.0, Some(9.0))] {
                let o = TeleaOptions { max_distance: md, ..opts(r, compat) };
                let mut windowed = img.clone();
                let n = inpaint_telea(&mut windowed, mask, o).unwrap();
                let mut whole = img.clone();
                let radius = (r as i64).clamp(1, 100) as usize;
                let m = fill_all(&mut [&mut whole], mask, (0, 0, w, h), radius, md.unwrap_or(f32::INFINITY), compat);
                assert_eq!(n, m, "{compat:?} r {r} md {md:?}");
                let bits = |im: &Image| im.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&windowed), bits(&whole), "{compat:?} r {r} md {md:?}");
            }
        }
    }
}

/// One march over several images gives each the fill it gets alone, bit for bit, in every
/// mode, with 3-channel and other images side by side (their weights differ: see
/// `Disc::dst3`); images of different sizes are refused and left alone.
#[test]
fn a_shared_march_fills_each_image_as_alone() {
    let (w, h) = (40, 30);
    let disc = |cx: f32, cy: f32, r: f32| move |i: usize| ((i % w) as f32 - cx).powi(2) + ((i / w) as f32 - cy).powi(2) < r * r;
    let masks: Vec<Vec<bool>> = vec![
        (0..w * h).map(disc(18.0, 14.0, 9.0)).collect(),
        (0..w * h).map(|i| disc(2.0, 25.0, 6.0)(i) || disc(35.0, 5.0, 4.0)(i)).collect(),
        (0..w * h).map(|i| !disc(20.0, 15.0, 7.0)(i)).collect(),
    ];
    let images = [noise_image(w, h, 3, 21), noise_image(w, h, 1, 22), noise_image(w, h, 2, 23)];
    let bits = |im: &Image| im.data.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    for mask in &masks {
        for compat in all_modes() {
            for (r, md) in [(5.0, None), (3.0, Some(4.0)), (7.0, Some(2.5))] {
                let o = TeleaOptions { max_distance: md, ..opts(r, compat) };
                let mut shared = images.clone();
                let [a, b, c] = &mut shared;
                let n = inpaint_telea_many(&mut [a, b, c], mask, o).unwrap();
                for (alone, together) in images.iter().zip(&shared) {
                    let mut one = alone.clone();
                    assert_eq!(inpaint_telea(&mut one, mask, o).unwrap(), n, "{compat:?} r {r} md {md:?}");
                    assert_eq!(bits(&one), bits(together), "{} channels, {compat:?} r {r} md {md:?}", alone.channels);
                }
            }
        }
    }
    let (mut a, mut b) = (noise_image(w, h, 3, 1), noise_image(w, h - 1, 3, 2));
    let (a0, b0) = (a.clone(), b.clone());
    assert!(matches!(inpaint_telea_many(&mut [&mut a, &mut b], &masks[0], TeleaOptions::new(3.0)), Err(Error::Usage(_))));
    assert_eq!((a, b), (a0, b0));
}

/// The plain fill's values come out the same, bit for bit, on one thread and on several
/// (the cells of one level are filled in parallel) and with and without AVX2.
#[test]
fn the_plain_fill_does_not_depend_on_threads_or_simd() {
    let (w, h) = (230, 170);
    // A hole of many chunks of cells, with an island of known pixels inside it.
    let mask: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32, (i / w) as f32);
            let d = (x - 110.0).powi(2) / 90.0f32.powi(2) + (y - 80.0).powi(2) / 60.0f32.powi(2);
            d < 1.0 && (x - 100.0).abs() + (y - 70.0).abs() > 6.0
        })
        .collect();
    let images = [noise_image(w, h, 3, 5), noise_image(w, h, 1, 6)];
    let fill = |threads: usize, avx2: bool, md: f32| {
        let mut out = images.clone();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        let n = pool.install(|| {
            let [a, b] = &mut out;
            let win = fill_window(&mask, w, h, 5, md).unwrap();
            let mut m = March::new(&mask, w, win, 5);
            m.outside_distances(5);
            m.fill_plain(&mut [a, b], 5, md, avx2)
        });
        (n, out.iter().flat_map(|im| im.data.iter().map(|v| v.to_bits())).collect::<Vec<_>>())
    };
    for md in [f32::INFINITY, 12.0] {
        let one = fill(1, false, md);
        assert!(one.0 > 5000, "{} cells filled", one.0);
        assert_eq!(one, fill(3, false, md), "threads, max distance {md}");
        if crate::cpu::has_avx2() {
            assert_eq!(one, fill(1, true, md), "AVX2, max distance {md}");
            assert_eq!(one, fill(2, true, md), "AVX2 on 2 threads, max distance {md}");
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(200))]
    #[test]
    fn never_panics_and_keeps_the_invariants(
        w in 1usize..10, h in 1usize..10, ch in 1usize..5, bits in proptest::collection::vec(proptest::bool::ANY, 100),
        radius in 0.0f32..9.0, mode in 0usize..4, seed in 0u64..1000,
    ) {
        let img = noise_image(w, h, ch, seed);
        let mask: Vec<bool> = bits[..w * h].to_vec();
        fill_checked(&img, &mask, opts(radius, all_modes()[mode]));
    }
}
