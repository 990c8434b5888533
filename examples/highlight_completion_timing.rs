//! Cost of completing cut highlights (`stages::highlight_completion`) when many lights sit
//! on the subject's outline: a W×H grey frame whose mask is vertical stripes, with a disc of
//! radius 2.5 (radiance 20) centred on every stripe edge every 12 px.
//!
//! `cargo run --release --example highlight_completion_timing -- [W H STRIPE REPEATS]`
//! (defaults 4032 3024 200 5). Prints the discs found and the median time of `complete`.
use drbokeh::Image;
use drbokeh::stages::background::{BandReach, FillRegion, InpaintOptions, fill_region};
use drbokeh::stages::highlight_completion::{Disc, complete};
use std::time::Instant;

fn main() {
    let args: Vec<usize> = std::env::args().skip(1).map(|s| s.parse().expect("a number")).collect();
    let (w, h, stripe, repeats) = (
        args.first().copied().unwrap_or(4032),
        args.get(1).copied().unwrap_or(3024),
        args.get(2).copied().unwrap_or(200),
        args.get(3).copied().unwrap_or(5),
    );
    let covered = |x: usize| (x / stripe) % 2 == 1;
    let alpha = Image::from_vec(w, h, 1, (0..w * h).map(|i| if covered(i % w) { 1.0 } else { 0.0 }).collect()).expect("size");
    let mut photo = Image::filled(w, h, 3, 0.3);
    let mut lights = 0;
    for edge in (stripe..w).step_by(stripe) {
        for cy in (6..h.saturating_sub(6)).step_by(12) {
            let d = Disc { cx: edge as f32 + 0.3, cy: cy as f32 + 0.4, r: 2.5, rgb: [20.0; 3] };
            lights += 1;
            for y in cy - 4..cy + 5 {
                for x in edge.saturating_sub(4)..(edge + 5).min(w) {
                    let a = d.coverage(x, y);
                    if covered(x) {
                        continue;
                    }
                    photo.pixel_mut(x, y).iter_mut().for_each(|v| *v += (20.0 - *v) * a);
                }
            }
        }
    }
    let region: FillRegion = fill_region(&photo, &alpha, &InpaintOptions::default(), 0.0, BandReach::Any);
    let mut times = Vec::new();
    let mut found = 0;
    for _ in 0..repeats {
        let mut filled = photo.clone();
        let t = Instant::now();
        found = complete(&mut filled, &photo, &region).len();
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    println!(
        "{w}x{h}: {lights} lights on the outline, {} kept highlight px, {found} discs completed; complete() median {:.1} ms (of {repeats}; {} threads)",
        region.highlights_kept,
        times[times.len() / 2],
        rayon::current_num_threads()
    );
}
