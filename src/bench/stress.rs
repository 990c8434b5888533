//! Deterministic synthetic layer stacks for benchmarks and stress tests: a textured
//! background plane tilted in depth behind a soft-edged foreground disk with thin bars, sized
//! so that the largest circle of confusion is a chosen radius.

use crate::image::Image;
use crate::render::{Layer, Profile, RenderSettings, auto_lens};

/// Two layers (foreground disk + bars, opaque background) of `width × height` and render
/// settings whose largest CoC radius is `max_coc` px, focused on the foreground
/// (`focus_fg`) or on the background's near edge.
pub fn two_layer_scene(width: usize, height: usize, max_coc: f32, focus_fg: bool) -> (Vec<Layer<'static>>, RenderSettings) {
    let (w, h) = (width, height);
    let mut fg = Vec::with_capacity(w * h * 5);
    let mut bg = Vec::with_capacity(w * h * 5);
    let (cx, cy, r) = (w as f32 * 0.5, h as f32 * 0.5, w.min(h) as f32 * 0.3);
    for y in 0..h {
        for x in 0..w {
            let (u, v) = (x as f32 / w as f32, y as f32 / h as f32);
            let dist = ((x as f32 - cx).powi(2) + (y as f32 - cy).powi(2)).sqrt();
            let disk = (r - dist + 0.5).clamp(0.0, 1.0);
            let bar = if (x % (w / 7).max(8)) < 2 && v > 0.6 { 1.0 } else { 0.0 };
            let a = f32::max(disk, bar);
            fg.extend_from_slice(&[0.8, 0.35 + 0.3 * u, 0.2 + 0.2 * v, a, 1.0]);
            // Brick-like texture with sparse highlights.
            let tex = (((x / 9) + (y / 6)) % 4) as f32 * 0.2;
            let light = if x % 97 == 13 && y % 83 == 7 { 1.0 } else { 0.0 };
            bg.extend_from_slice(&[(tex + light).min(1.0), 0.3 + 0.4 * v, (1.0 - tex).max(light), 1.0, 0.5 * u]);
        }
    }
    let layers = vec![
        Layer::new(Image::from_vec(w, h, 5, fg).expect("size"), "stress fg").expect("finite"),
        Layer::new(Image::from_vec(w, h, 5, bg).expect("size"), "stress bg").expect("finite"),
    ];
    // Largest |d| over the scene: focus 1 → background at d ∈ [-1, -0.5]; focus 0.5 → fg at +0.5.
    let (focus, dmax) = if focus_fg { (1.0, 1.0) } else { (0.5, 0.5) };
    let blur = (max_coc / dmax).max(0.0);
    let lens = auto_lens(&layers, blur, focus);
    (
        layers,
        RenderSettings {
            blur,
            focus,
            lens,
            occlusion: true,
            profile: crate::render::Profile::Official,
            aperture: crate::render::Aperture::DISC,
        },
    )
}

/// One opaque `width × height` layer: a textured ground in focus (disparity 1) with 2-pixel
/// bars at disparity 0.5 over its lower 40%, blurred to a CoC of `max_coc` px: the stress
/// scene's bars in the ground's own layer, where the physical profile's in-layer depth groups
/// decide what the ground next to a bar receives. Settings: focus 1, official profile.
pub fn bars_in_one_layer(width: usize, height: usize, max_coc: f32) -> (Vec<Layer<'static>>, RenderSettings) {
    let (w, h) = (width, height);
    let mut px = Vec::with_capacity(w * h * 5);
    for y in 0..h {
        for x in 0..w {
            let bar = (x % (w / 7).max(8)) < 2 && y as f32 / h as f32 > 0.6;
            let tex = (((x / 9) + (y / 6)) % 4) as f32 * 0.2;
            px.extend_from_slice(&if bar { [0.9, 0.2, 0.1, 1.0, 0.5] } else { [tex, 0.5, 1.0 - tex, 1.0, 1.0] });
        }
    }
    let layers = vec![Layer::new(Image::from_vec(w, h, 5, px).expect("size"), "bars in one layer").expect("finite")];
    let blur = (max_coc / 0.5).max(0.0);
    let lens = auto_lens(&layers, blur, 1.0);
    (
        layers,
        RenderSettings {
            blur,
            focus: 1.0,
            lens,
            occlusion: true,
            profile: crate::render::Profile::Official,
            aperture: crate::render::Aperture::DISC,
        },
    )
}

/// A depth-from-defocus scene of `n × n` pixels: a seeded noise texture over blocks of 32 px
/// at seeded disparities in [0, 1] plus a gentle slant, opaque, and the target it is compared
/// with (seeded noise: only the cost matters). For timing the depth-from-defocus step.
pub fn dfd_scene(n: usize) -> (Layer<'static>, Image) {
    let mut x = 0x2545_F491_4F6C_DD1Du64;
    let mut rnd = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        (x >> 40) as f32 / (1u64 << 24) as f32
    };
    let blocks: Vec<f32> = (0..(n / 32 + 1) * (n / 32 + 1)).map(|_| rnd()).collect();
    let mut px = Vec::with_capacity(n * n * 5);
    for i in 0..n * n {
        let (cx, cy) = (i % n, i / n);
        let d = (0.8 * blocks[(cy / 32) * (n / 32 + 1) + cx / 32] + 0.2 * cx as f32 / n as f32).clamp(0.0, 1.0);
        px.extend_from_slice(&[rnd(), rnd(), rnd(), 1.0, d]);
    }
    let layer = Layer::new(Image::from_vec(n, n, 5, px).unwrap(), "dfd bench").unwrap();
    let mut target = Image::new(n, n, 3);
    target.data.iter_mut().for_each(|v| *v = rnd());
    (layer, target)
}

/// The settings `diff::dfd::estimate` uses at full size: focus 1 (the nearest plane), blur
/// `k`, the window the disparity range [0, 1] needs.
pub fn dfd_settings(k: f32, occlusion: bool) -> RenderSettings {
    let reach = k.ceil() as usize + 3;
    RenderSettings {
        blur: k,
        focus: 1.0,
        lens: 2 * reach + 1,
        occlusion,
        profile: Profile::Physical,
        aperture: crate::render::Aperture::DISC,
    }
}
