//! Guided against plain upsampling of a reduced plan's depth-from-defocus map (issue 38): for
//! generated bench cases (`drbokeh bench --dfd`'s generator and traced targets), one default
//! estimate (`drbokeh dfd`'s plan) per case; its map at the optimised size brought to full size
//! by a bilinear resize and by `diff::dfd_upsample`, each scored as the bench scores a method
//! (disparity MAE inside the border; the re-render at the far focus against the traced truth).
//!
//! `cargo run --release --example dfd_upsample_check -- SEED SCENES WxH`

use drbokeh::bench::dfd_eval::{DfdBenchOptions, DfdMethod, load_case, mae, rerender};
use drbokeh::bench::run::score;
use drbokeh::diff::dfd::{self, DfdOptions};

fn main() -> drbokeh::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let scenes: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(4);
    let (w, h) = args.get(3).and_then(|s| s.split_once('x')).map_or((256, 192), |(a, b)| (a.parse().unwrap(), b.parse().unwrap()));
    let opts = DfdBenchOptions { scenes, width: w, height: h, seed, ..DfdBenchOptions::default() };
    let mut sums = [0f64; 4];
    for i in 0..scenes {
        let case = load_case(&opts, &[], i, &mut |_| {})?;
        let (s, loss, renderer) = DfdMethod::Physical.setup(case.blur, case.focus);
        let o = DfdOptions { weights: loss.weights(), renderer, kernel: DfdMethod::Physical.kernel(), ..DfdOptions::default() };
        let est = dfd::estimate_with(&case.aif, &case.target, &s, &o, |_| {})?;
        let plain = est.optimised.resized(w, h);
        let mut row = Vec::new();
        for d in [&plain, &est.disparity] {
            let img = rerender(&case.aif, d, case.blur, case.other_focus)?;
            row.push((mae(d, &case.truth, case.border, |_| true), score(&img, &case.other, case.border).psnr));
        }
        println!(
            "{} (K {:.1}, optimised at {}x{}): plain MAE {:.4} re-render {:.2} dB linear; guided MAE {:.4} re-render {:.2} dB",
            case.scene, case.blur, est.plan.width, est.plan.height, row[0].0, row[0].1, row[1].0, row[1].1
        );
        for (k, v) in [row[0].0, row[0].1, row[1].0, row[1].1].into_iter().enumerate() {
            sums[k] += v;
        }
    }
    let n = scenes as f64;
    println!(
        "mean of {scenes} (seed {seed}, {w}x{h}): plain MAE {:.4} re-render {:.2} dB; guided MAE {:.4} re-render {:.2} dB",
        sums[0] / n,
        sums[1] / n,
        sums[2] / n,
        sums[3] / n
    );
    Ok(())
}
