//! Generates the bundled example scene in `examples/scene/`: a synthetic photo (`image.png`,
//! 8-bit sRGB), its depth (`depth.exr`, z distances) and the subject's matte (`matte.png`).
//!
//! The scene is built to show what Dr.Bokeh is for: a near subject with soft and thin edges
//! (a flower with a stem and leaves) in front of a far, textured wall with small bright lights
//! that turn into bokeh discs, some of them right behind the subject's edge.
//!
//! Run: `cargo run --release --example make_scene` (deterministic; rewrites the files).
//! `cargo run --release --example make_scene -- DIR WIDTH HEIGHT` draws the same scene at
//! another size into DIR (the end-to-end timing script uses it for a 12 MP photo), and
//! `... -- DIR WIDTH HEIGHT night` at night: a dim wall whose string lights are 6 to 20 times
//! brighter than white, clipped by the 8-bit PNG, plus `image.exr`, the same photo linear and
//! unclipped (the highlights stage's before/after, `scripts/highlights_before_after.sh`).

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{write_exr, write_png};

const W: usize = 480;
const H: usize = 320;
/// Supersampling per axis for antialiased edges.
const SS: usize = 4;
/// Supersampling per axis of the pixels a light touches. A light 20 times white clips every
/// pixel it covers more than 5%: its radiance shows only in pixels it covers less, which 4x4
/// samples draw as 0 or 6.25% (the night scene's `auto` read its lights at up to 3 times
/// their radiance from such a fringe).
const SS_LIGHT: usize = 16;
/// String lights: count and radius (scene pixels).
const LIGHTS: usize = 14;
const LIGHT_RADIUS: f32 = 4.0;

/// Centre of string light `k` (scene pixels).
fn light_centre(k: usize) -> (f32, f32) {
    (20.0 + k as f32 * 34.0, 60.0 + 18.0 * (k as f32 * 0.9).sin())
}

/// Coverage of the subject at a point (continuous coordinates in pixels) and its colour.
fn subject(x: f32, y: f32) -> Option<[f32; 3]> {
    // Flower head: petals as a polar wave around (300, 120).
    let (cx, cy) = (300.0, 118.0);
    let (dx, dy) = (x - cx, y - cy);
    let r = (dx * dx + dy * dy).sqrt();
    let th = dy.atan2(dx);
    let petal = 52.0 + 14.0 * (6.0 * th).cos();
    if r < 18.0 {
        return Some([0.95, 0.72, 0.12]); // centre
    }
    if r < petal {
        let t = r / petal;
        return Some([0.85 - 0.25 * t, 0.18 + 0.1 * t, 0.42 + 0.2 * t]);
    }
    // Stem: a thin curved line, ~3 px wide.
    let stem_x = cx - 10.0 * ((y - cy) / 80.0).sin() * 3.0;
    if y > cy + 40.0 && (x - stem_x).abs() < 1.6 {
        return Some([0.2, 0.5, 0.15]);
    }
    // Two leaves: ellipses along the stem.
    for (lx, ly, a, sgn) in [(262.0f32, 250.0f32, 0.5f32, 1.0f32), (335.0, 215.0, -0.6, -1.0)] {
        let (ux, uy) = (x - lx, y - ly);
        let (c, s) = (a.cos(), a.sin());
        let (px, py) = (c * ux + s * uy, -s * ux + c * uy);
        if (px / 34.0).powi(2) + (py / 10.0).powi(2) < 1.0 {
            return Some([0.16 + 0.05 * sgn, 0.46, 0.12]);
        }
    }
    // Fine hairs on the petals: 1 px lines radiating out of the head.
    for k in 0..9 {
        let a = k as f32 * 0.7 + 0.3;
        let (ex, ey) = (a.cos(), a.sin());
        let along = dx * ex + dy * ey;
        let across = (-dx * ey + dy * ex).abs();
        if along > petal * 0.9 && along < 92.0 && across < 0.5 {
            return Some([0.9, 0.85, 0.8]);
        }
    }
    None
}

/// The far wall: a brick-like texture with a colour gradient, linear radiance.
fn wall(x: f32, y: f32) -> [f32; 3] {
    // Offset so that no mortar line runs along the frame border (replicate padding would
    // smear it into a band).
    let (x, y) = (x + 13.0, y + 11.0);
    let row = (y / 22.0).floor();
    let off = if row as i32 % 2 == 0 { 0.0 } else { 24.0 };
    let mortar = (y % 22.0) < 2.0 || ((x + off) % 48.0) < 2.0;
    let n = ((x * 0.37).sin() * (y * 0.53).cos() * 0.5 + 0.5) * 0.08;
    let g = (x / W as f32).min(1.0);
    let n = n * 0.5;
    if mortar { [0.12, 0.12, 0.11] } else { [0.16 + 0.14 * g + n, 0.06 + 0.06 * (1.0 - g) + n, 0.04 + 0.08 * g + n] }
}

/// Small bright lights on the wall (string lights): white by day; at night (`night`) 6 to 20
/// times brighter than white, which the 8-bit PNG clips.
fn lights(x: f32, y: f32, night: bool) -> Option<[f32; 3]> {
    for k in 0..LIGHTS {
        let (lx, ly) = light_centre(k);
        if (x - lx).powi(2) + (y - ly).powi(2) < LIGHT_RADIUS.powi(2) {
            let gain = if night { 6.0 + 14.0 * (0.5 + 0.5 * (k as f32 * 2.3).sin()) } else { 1.0 };
            return Some([1.0 * gain, 0.92 * gain, 0.7 * gain]);
        }
    }
    None
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (dir, w, h, night) = match &args[..] {
        [] => (std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/scene"), W, H, false),
        [d, w, h] => (d.into(), w.parse()?, h.parse()?, false),
        [d, w, h, n] if n == "night" => (d.into(), w.parse()?, h.parse()?, true),
        _ => return Err("usage: make_scene [DIR WIDTH HEIGHT [night]]".into()),
    };
    // At night the wall gets a quarter of the daylight.
    let wall_at = |x: f32, y: f32| wall(x, y).map(|v| if night { 0.25 * v } else { v });
    std::fs::create_dir_all(&dir)?;
    // Scene coordinates are those of the 480 x 320 original, stretched to the requested size.
    let (kx, ky) = (W as f32 / w as f32, H as f32 / h as f32);
    let mut rgb = Image::new(w, h, 3);
    let mut matte = Image::new(w, h, 1);
    let mut depth = Image::new(w, h, 1);
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0f32; 3];
            let mut cover = 0f32;
            let (px, py) = ((x as f32 + 0.5) * kx, (y as f32 + 0.5) * ky);
            let reach = LIGHT_RADIUS + kx.max(ky);
            let ss = if (0..LIGHTS).any(|k| (px - light_centre(k).0).hypot(py - light_centre(k).1) < reach) { SS_LIGHT } else { SS };
            for sy in 0..ss {
                for sx in 0..ss {
                    let (fx, fy) = ((x as f32 + (sx as f32 + 0.5) / ss as f32) * kx, (y as f32 + (sy as f32 + 0.5) / ss as f32) * ky);
                    let c = match subject(fx, fy) {
                        Some(c) => {
                            cover += 1.0;
                            c
                        }
                        None => lights(fx, fy, night).unwrap_or_else(|| wall_at(fx, fy)),
                    };
                    for i in 0..3 {
                        acc[i] += c[i];
                    }
                }
            }
            let n = (ss * ss) as f32;
            rgb.pixel_mut(x, y).copy_from_slice(&[acc[0] / n, acc[1] / n, acc[2] / n]);
            matte.data[y * w + x] = cover / n;
            // Depth at the pixel centre: subject at 1.2 m, wall at 6 m receding to the right.
            let centre = subject((x as f32 + 0.5) * kx, (y as f32 + 0.5) * ky).is_some();
            depth.data[y * w + x] = if centre { 1.2 } else { 6.0 + 2.0 * x as f32 / w as f32 };
        }
    }
    write_png(&dir.join("image.png"), &rgb, 8, Transfer::Srgb)?;
    if night {
        // The light the PNG clips, for comparison: the same photo, linear, unclipped.
        write_exr(&dir.join("image.exr"), &rgb, &["R", "G", "B"])?;
    }
    write_png(&dir.join("matte.png"), &matte, 8, Transfer::Linear)?;
    write_exr(&dir.join("depth.exr"), &depth, &["Y"])?;
    println!("wrote {}", dir.display());
    Ok(())
}
