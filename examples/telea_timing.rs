//! Telea inpainting time against OpenCV on the same input, one process after the other:
//! `cargo run --release --example telea_timing -- WIDTH HEIGHT RADIUS [DIR]`
//! writes DIR/telea_img.npy (8-bit RGB values as float) and DIR/telea_mask.npy (an ellipse
//! covering ~31% of the frame), times drbokeh's Telea (median of 3), and prints the command
//! that times cv2.inpaint on the same files (scripts/telea_cv_timing.py).

use drbokeh::Image;
use drbokeh::io::npy::save_npy;
use drbokeh::stages::inpaint::{TeleaOptions, inpaint_telea};
use std::time::Instant;

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let (w, h, r): (usize, usize, f32) = (a[0].parse().unwrap(), a[1].parse().unwrap(), a[2].parse().unwrap());
    let dir = std::path::PathBuf::from(a.get(3).cloned().unwrap_or_else(|| "/tmp".into()));
    let mut img = Image::new(w, h, 3);
    for y in 0..h {
        for x in 0..w {
            let v = [((x / 7 + y / 5) % 255) as f32, ((x * 3 + y) % 255) as f32, ((x ^ y) % 255) as f32];
            img.pixel_mut(x, y).copy_from_slice(&v);
        }
    }
    let (ea, eb) = (w as f32 * 0.30, h as f32 * 0.33);
    let mask: Vec<bool> = (0..w * h)
        .map(|i| (((i % w) as f32 - w as f32 / 2.0) / ea).powi(2) + (((i / w) as f32 - h as f32 / 2.0) / eb).powi(2) < 1.0)
        .collect();
    println!("mask covers {:.1}%", 100.0 * mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64);
    save_npy(&dir.join("telea_img.npy"), &img).unwrap();
    save_npy(&dir.join("telea_mask.npy"), &Image::from_vec(w, h, 1, mask.iter().map(|&m| m as u8 as f32).collect()).unwrap()).unwrap();
    let mut times = Vec::new();
    for _ in 0..3 {
        let mut im = img.clone();
        let t = Instant::now();
        inpaint_telea(&mut im, &mask, TeleaOptions::new(r)).unwrap();
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    println!("drbokeh Telea r={r}: {:.3} s (median of 3, {} threads available)", times[1], rayon::current_num_threads());
}
