//! `drbokeh batch`: pairing, resumability, sharding, manifests, failures and exit codes.

use drbokeh::color::Transfer;
use drbokeh::io::{write_exr, write_png};
use drbokeh::Image;
use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drbokeh"))
}

/// A 32x24 photo with a near square, its depth (EXR) and optionally a matte.
fn scene(dir: &Path, stem: &str, depth_name: Option<&str>, matte_name: Option<&str>) {
    let (w, h) = (32, 24);
    let inside = |x: usize, y: usize| (10..22).contains(&x) && (6..18).contains(&y);
    let rgb = Image::from_vec(w, h, 3, (0..w * h).flat_map(|i| if inside(i % w, i / w) { [0.8, 0.2, 0.1] } else { [0.1, 0.3, 0.7] }).collect()).unwrap();
    write_png(&dir.join(format!("{stem}.png")), &rgb, 8, Transfer::Srgb).unwrap();
    let depth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if inside(i % w, i / w) { 1.0 } else { 4.0 }).collect()).unwrap();
    if let Some(d) = depth_name {
        write_exr(&dir.join(d), &depth, &["Y"]).unwrap();
    }
    if let Some(m) = matte_name {
        let matte = Image::from_vec(w, h, 1, (0..w * h).map(|i| inside(i % w, i / w) as u8 as f32).collect()).unwrap();
        write_png(&dir.join(m), &matte, 8, Transfer::Linear).unwrap();
    }
}

fn summary(out: &Path, name: &str) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join(name)).unwrap()).unwrap()
}

fn files(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = walk(dir).into_iter().map(|p| p.strip_prefix(dir).unwrap().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

fn walk(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        if e.path().is_dir() {
            v.extend(walk(&e.path()));
        } else {
            v.push(e.path());
        }
    }
    v
}

#[test]
fn pairs_renders_resumes_and_reports_failures() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(inp.join("sub")).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), Some("a.matte.png"));
    scene(&inp, "b", Some("b_depth.exr"), None);
    scene(&inp, "nodepth", None, None);
    scene(&inp.join("sub"), "c", Some("c_depth.exr"), Some("c_matte.png"));
    std::fs::write(inp.join("broken.png"), b"\x89PNG\r\n\x1a\n garbage").unwrap();
    write_exr(&inp.join("broken.depth.exr"), &Image::filled(32, 24, 1, 2.0), &["Y"]).unwrap();

    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--recursive"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("nodepth.png") && err.contains("no depth map"), "{err}");
    assert!(err.contains("broken.png") && err.contains("PNG"), "{err}");
    assert_eq!(files(&out), vec!["a_bokeh.png", "b_bokeh.png", "drbokeh-batch.json", "sub/c_bokeh.png"]);
    let s = summary(&out, "drbokeh-batch.json");
    assert_eq!((s["ok"].as_u64(), s["failed"].as_u64()), (Some(3), Some(2)));

    // Second run: everything done is skipped; --force redoes it.
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--recursive", "--json"]).output().unwrap();
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((s["skipped"].as_u64(), s["ok"].as_u64()), (Some(3), Some(0)));
    // A newer input makes its image stale again.
    std::thread::sleep(std::time::Duration::from_millis(20));
    scene(&inp, "a", Some("a.depth.exr"), Some("a.matte.png"));
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--json"]).output().unwrap();
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((s["ok"].as_u64(), s["skipped"].as_u64()), (Some(1), Some(1)), "{s}");
    // No temporary files anywhere.
    assert!(walk(&out).iter().all(|p| !p.to_string_lossy().ends_with(".drbokeh-tmp")));
}

#[test]
fn shards_partition_the_collection() {
    let t = tempfile::tempdir().unwrap();
    let inp = t.path().join("in");
    std::fs::create_dir_all(&inp).unwrap();
    for k in 0..5 {
        scene(&inp, &format!("img{k}"), Some(&format!("img{k}.depth.exr")), None);
    }
    let mut seen = Vec::new();
    for i in 0..3 {
        let out = t.path().join("out");
        let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "0", "--blur", "4", "--shard", &format!("{i}/3")]).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let s = summary(&out, &format!("drbokeh-batch.shard-{i}-of-3.json"));
        seen.extend(s["items"].as_array().unwrap().iter().map(|it| it["image"].as_str().unwrap().to_string()));
    }
    seen.sort();
    assert_eq!(seen, (0..5).map(|k| format!("img{k}.png")).collect::<Vec<_>>());
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", "x", "--focus", "0", "--shard", "3/3"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--shard"));
}

#[test]
fn manifest_overrides_focus_blur_and_output() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    scene(&inp, "b", Some("b.depth.exr"), None);
    let csv = t.path().join("m.csv");
    std::fs::write(&csv, "image,focus,focus_at,blur,matte,output\na.png,0,,0,,custom_a.exr\nb.png,,\"5,5\",3,,\n").unwrap();
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--manifest", csv.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("custom_a.exr").exists() && out.join("b_bokeh.png").exists());
    // blur 0 → nothing to render → the EXR output is the decoded input.
    let a = drbokeh::io::read_photo(&out.join("custom_a.exr"), Transfer::Linear, &Default::default()).unwrap();
    let src = drbokeh::io::read_photo(&inp.join("a.png"), Transfer::Srgb, &Default::default()).unwrap();
    assert_eq!(a.data, src.data);

    let toml = t.path().join("m.toml");
    std::fs::write(&toml, "[[image]]\nimage = \"a.png\"\nfocus = 1.0\n[[image]]\nimage = \"missing.png\"\nfocus = 0.0\n").unwrap();
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--manifest", toml.to_str().unwrap()]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.png"));
    // Without a focus anywhere, images fail (and say why).
    let o = bin().args(["batch", inp.to_str().unwrap(), "-o", t.path().join("o2").to_str().unwrap()]).output().unwrap();
    assert_eq!(o.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no focus"));
}

#[test]
fn bad_input_folder_is_a_usage_error() {
    let o = bin().args(["batch", "/nonexistent/folder", "-o", "/tmp/x", "--focus", "0"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/folder"));
}
