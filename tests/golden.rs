//! Golden vectors from the official implementation (../shared/reference): the exact kernel
//! must reproduce every per-layer raw channel and the composited output.

use crate::common;

use drbokeh::Image;
use drbokeh::io::npy::read_npy;
use drbokeh::render::{self, Kernel};
use std::path::Path;

/// Largest absolute error allowed on every raw channel and on the composited output.
const TOL: f32 = 1e-4;

fn load(path: &Path) -> Image {
    read_npy(path, u64::MAX).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn exact_kernel_matches_official_renderer() {
    let root = common::shared_dir().join("reference");
    let cases = common::case_dirs(&root);
    assert!(cases.len() >= 6, "expected the golden cases in {}", root.display());
    let mut worst = (0f32, 0f32);
    let mut failures = Vec::new();
    for dir in cases {
        let name = dir.file_name().unwrap().to_string_lossy().into_owned();
        let (layers, s, names, gamma) = common::golden_case(&dir);
        let raws = render::render_raw(&layers, &s, Kernel::Exact);
        let mut raw_err = 0f32;
        for (n, raw) in names.iter().zip(&raws) {
            let want = load(&dir.join(format!("{n}_raw.npy")));
            let err = common::max_abs_diff(&raw.image().data, &want.data);
            if err > TOL {
                let saved = common::save_failure(&format!("golden-{name}-{n}_raw"), raw.image());
                failures.push(format!("{name}: layer {n} raw max abs err {err:.3e} > {TOL:.0e} (render saved to {})", saved.display()));
            }
            raw_err = raw_err.max(err);
        }
        let mut out = render::render(&layers, &s, Kernel::Exact).unwrap();
        if gamma != 1.0 {
            out.map_inplace(|v| v.powf(1.0 / gamma as f32));
        }
        let want = load(&dir.join("out.npy"));
        let out_err = common::max_abs_diff(&out.data, &want.data);
        println!("golden {name:14} raw max abs err {raw_err:.3e}  output max abs err {out_err:.3e}");
        if out_err > TOL {
            let saved = common::save_failure(&format!("golden-{name}-out"), &out);
            failures.push(format!("{name}: output max abs err {out_err:.3e} > {TOL:.0e} (render saved to {})", saved.display()));
        }
        worst = (worst.0.max(raw_err), worst.1.max(out_err));
    }
    println!("golden worst: raw {:.3e} output {:.3e}", worst.0, worst.1);
    common::assert_no_failures("exact kernel vs the official renderer", &failures);
}
