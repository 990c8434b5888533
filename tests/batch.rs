//! `drbokeh batch`: pairing, resumability, sharding, manifests, failures and exit codes.

use crate::common;

use drbokeh::Image;
use drbokeh::color::Transfer;
use drbokeh::io::{write_exr, write_png};
use std::path::Path;
use std::process::Command;

fn bin() -> Command {
    common::drbokeh_bin()
}

/// A 32x24 photo with a near square, its depth (EXR) and optionally a matte.
fn scene(dir: &Path, stem: &str, depth_name: Option<&str>, matte_name: Option<&str>) {
    let (w, h) = (32, 24);
    let inside = |x: usize, y: usize| (10..22).contains(&x) && (6..18).contains(&y);
    let rgb =
        Image::from_vec(w, h, 3, (0..w * h).flat_map(|i| if inside(i % w, i / w) { [0.8, 0.2, 0.1] } else { [0.1, 0.3, 0.7] }).collect())
            .unwrap();
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

/// Every file under `dir` (recursive), sorted relative paths.
fn files(dir: &Path) -> Vec<String> {
    common::list_files(dir).into_iter().collect()
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

    let o = bin()
        .args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--recursive"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("nodepth.png") && err.contains("no depth map"), "{err}");
    assert!(err.contains("broken.png") && err.contains("PNG"), "{err}");
    // Each output has its fingerprint beside it (hidden).
    let fp = |n: &str| format!("{n}.drbokeh-fingerprint");
    assert_eq!(
        files(&out),
        [
            fp(".a_bokeh.png"),
            fp(".b_bokeh.png"),
            "a_bokeh.png".into(),
            "b_bokeh.png".into(),
            "drbokeh-batch.json".into(),
            fp("sub/.c_bokeh.png"),
            "sub/c_bokeh.png".into()
        ]
    );
    let s = summary(&out, "drbokeh-batch.json");
    assert_eq!((s["ok"].as_u64(), s["failed"].as_u64()), (Some(3), Some(2)));

    // Second run: everything done is skipped; --force redoes it.
    let o = bin()
        .args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--recursive", "--json"])
        .output()
        .unwrap();
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((s["skipped"].as_u64(), s["ok"].as_u64()), (Some(3), Some(0)));
    // A newer input makes its image stale again.
    std::thread::sleep(std::time::Duration::from_millis(20));
    scene(&inp, "a", Some("a.depth.exr"), Some("a.matte.png"));
    let o = bin()
        .args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--focus", "1", "--blur", "6", "--json"])
        .output()
        .unwrap();
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((s["ok"].as_u64(), s["skipped"].as_u64()), (Some(1), Some(1)), "{s}");
    // No temporary files anywhere.
    assert!(files(&out).iter().all(|p| !p.ends_with(".drbokeh-tmp")));
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
        let o = bin()
            .args([
                "batch",
                inp.to_str().unwrap(),
                "-o",
                out.to_str().unwrap(),
                "--focus",
                "0",
                "--blur",
                "4",
                "--shard",
                &format!("{i}/3"),
            ])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let s = summary(&out, &format!("drbokeh-batch.shard-{i}-of-3.json"));
        let mine: Vec<String> = s["items"].as_array().unwrap().iter().map(|it| it["image"].as_str().unwrap().to_string()).collect();
        // The guide's rule: shard I takes every N-th image of the sorted list (I, I + N, ...),
        // not a contiguous run, which would also partition the collection.
        assert_eq!(mine, (i..5).step_by(3).map(|k| format!("img{k}.png")).collect::<Vec<_>>(), "shard {i}/3");
        seen.extend(mine);
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
    let o =
        bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--manifest", csv.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.join("custom_a.exr").exists() && out.join("b_bokeh.png").exists());
    // blur 0 → nothing to render → the EXR output is the decoded input.
    let a = drbokeh::io::read_photo(&out.join("custom_a.exr"), Transfer::Linear, &Default::default()).unwrap();
    let src = drbokeh::io::read_photo(&inp.join("a.png"), Transfer::Srgb, &Default::default()).unwrap();
    assert_eq!(a.data, src.data);
    // Resume reads the size of an EXR output from its header: both outputs are up to date.
    let (code, s, err) = batch_json(&inp, &out, &["--manifest", csv.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    assert!(statuses(&s).iter().all(|(_, st, _)| st == "skipped"), "{s}");

    let toml = t.path().join("m.toml");
    std::fs::write(&toml, "[[image]]\nimage = \"a.png\"\nfocus = 1.0\n[[image]]\nimage = \"missing.png\"\nfocus = 0.0\n").unwrap();
    let o =
        bin().args(["batch", inp.to_str().unwrap(), "-o", out.to_str().unwrap(), "--manifest", toml.to_str().unwrap()]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("missing.png"));
}

#[test]
fn bad_input_folder_is_a_usage_error() {
    let o = bin().args(["batch", "/nonexistent/folder", "-o", "/tmp/x", "--focus", "0"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("/nonexistent/folder"));
}

/// Runs `drbokeh batch IN -o OUT ARGS --json` and returns (exit code, summary or Null, stderr).
fn batch_json(inp: &Path, out: &Path, args: &[&str]) -> (Option<i32>, serde_json::Value, String) {
    let o = batch_json_output(inp, out, args);
    let s = serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null);
    (o.status.code(), s, String::from_utf8_lossy(&o.stderr).into_owned())
}

/// The raw output of `drbokeh batch IN -o OUT ARGS --json`.
fn batch_json_output(inp: &Path, out: &Path, args: &[&str]) -> std::process::Output {
    common::run({
        let mut c = bin();
        c.arg("batch").arg(inp).arg("-o").arg(out).args(args).arg("--json").env("RAYON_NUM_THREADS", "2");
        c
    })
}

/// (status, reason) of each item of a summary, by image.
fn statuses(s: &serde_json::Value) -> Vec<(String, String, String)> {
    s["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|it| (it["image"].as_str().unwrap().into(), it["status"].as_str().unwrap().into(), it["reason"].as_str().unwrap_or("").into()))
        .collect()
}

/// Asserts a usage error: exit 2, stderr naming every needle, no panic, and no file written
/// under `root` (the test's temporary folder).
fn assert_usage_error(root: &Path, inp: &Path, out: &Path, args: &[&str], needles: &[&str]) {
    common::assert_usage_error(root, &format!("batch {args:?}"), needles, || batch_json_output(inp, out, args));
}

/// Issue 10: a second run's cleanup removed the first run's temporary file. Only files whose
/// writer is gone (no lock held) may go.
#[test]
fn cleanup_keeps_live_temps_and_removes_stale_ones() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    std::fs::create_dir_all(&out).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    // A writer that is alive (this test holds the lock, as write_atomic does) …
    let live = out.join(format!(".a_bokeh.png.{}-1.drbokeh-tmp", std::process::id()));
    let held = std::fs::File::create(&live).unwrap();
    held.try_lock().unwrap();
    // … and one that died (nobody holds its lock), for this output and another.
    let stale = [out.join(".a_bokeh.png.4000000-2.drbokeh-tmp"), out.join(".gone_bokeh.png.4000000-3.drbokeh-tmp")];
    for p in &stale {
        std::fs::write(p, b"half").unwrap();
    }
    let (code, s, err) = batch_json(&inp, &out, &["--focus", "1", "--blur", "4"]);
    assert_eq!((code, s["ok"].as_u64()), (Some(0), Some(1)), "{err}");
    assert!(live.exists(), "a live writer's temporary file was removed");
    assert!(stale.iter().all(|p| !p.exists()), "stale temporary files were kept: {:?}", files(&out));
    drop(held);

    // Two runs on one folder at once: neither may break the other (3 of 10 trials failed).
    for k in 0..4 {
        scene(&inp, &format!("img{k}"), Some(&format!("img{k}.depth.exr")), None);
    }
    for _ in 0..3 {
        let spawn = || {
            bin()
                .arg("batch")
                .arg(&inp)
                .arg("-o")
                .arg(&out)
                .args(["--focus", "1", "--blur", "4", "--force"])
                .env("RAYON_NUM_THREADS", "1")
                .output()
        };
        let (a, b) = std::thread::scope(|sc| {
            let a = sc.spawn(spawn);
            let b = sc.spawn(spawn);
            (a.join().unwrap().unwrap(), b.join().unwrap().unwrap())
        });
        for o in [a, b] {
            assert!(o.status.success(), "concurrent run failed: {}", String::from_utf8_lossy(&o.stderr));
        }
    }
    assert!(files(&out).iter().all(|f| !f.ends_with(".drbokeh-tmp")), "{:?}", files(&out));
}

/// Issue 10: `output_pattern` or a manifest `output` must not write outside `-o`.
#[test]
fn outputs_stay_inside_the_output_folder() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("a/b/in"), t.path().join("a/b/out"));
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "x", Some("x.depth.exr"), None);
    let cfg = t.path().join("escape.toml");
    std::fs::write(&cfg, "[batch]\noutput_pattern = \"../../escape_{stem}\"\n").unwrap();
    assert_usage_error(
        t.path(),
        &inp,
        &out,
        &["--focus", "1", "--config", cfg.to_str().unwrap()],
        &["batch.output_pattern", "escape.toml"],
    );
    for bad in ["../x_out.png", "sub/../../x_out.png", "/tmp/drbokeh_escape_x.png"] {
        let m = t.path().join("m.csv");
        std::fs::write(&m, format!("image,focus,output\nx.png,1,{bad}\n")).unwrap();
        assert_usage_error(t.path(), &inp, &out, &["--manifest", m.to_str().unwrap()], &["x.png", bad, "m.csv"]);
        std::fs::remove_file(&m).unwrap();
    }
    assert!(!Path::new("/tmp/drbokeh_escape_x.png").exists());
    // Inside is fine, subfolders included.
    let m = t.path().join("m.toml");
    std::fs::write(&m, "[[image]]\nimage = \"x.png\"\nfocus = 1.0\noutput = \"deep/er/x.png\"\n").unwrap();
    let (code, _, err) = batch_json(&inp, &out, &["--manifest", m.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    assert!(out.join("deep/er/x.png").exists());
    // A name inside `-o` that leads outside it through a symbolic link is not written either.
    #[cfg(unix)]
    {
        let elsewhere = t.path().join("elsewhere");
        std::fs::create_dir_all(&elsewhere).unwrap();
        std::os::unix::fs::symlink(&elsewhere, out.join("link")).unwrap();
        std::fs::write(&m, "[[image]]\nimage = \"x.png\"\nfocus = 1.0\noutput = \"link/x.png\"\n").unwrap();
        let (code, s, err) = batch_json(&inp, &out, &["--manifest", m.to_str().unwrap()]);
        assert_ne!(code, Some(0), "{err}");
        let st = statuses(&s);
        assert!(st.iter().any(|(_, status, why)| status == "failed" && why.contains("outside the output folder")), "{st:?}");
        assert_eq!(std::fs::read_dir(&elsewhere).unwrap().count(), 0, "nothing written through the link");
    }
}

/// Issue 10: resume compared modification times only. A rerun with other parameters, a
/// 0-byte, truncated or corrupt output, or a lost fingerprint must redo the image.
#[test]
fn resume_redoes_what_changed() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    scene(&inp, "b", Some("b.depth.exr"), None);
    let run = |args: &[&str]| {
        let (code, s, err) = batch_json(&inp, &out, args);
        assert_eq!(code, Some(0), "{err}");
        statuses(&s)
    };
    let blur4 = ["--focus", "1", "--blur", "4"];
    assert!(run(&blur4).iter().all(|(_, st, _)| st == "ok"));
    let (_, s, _) = batch_json(&inp, &out, &blur4);
    assert!(statuses(&s).iter().all(|(_, st, _)| st == "skipped"), "{s}");
    assert!(s["items"][0]["fingerprint"].as_str().is_some_and(|f| f.len() == 32), "{s}");

    // Another blur, another focus: everything is redone, and says why.
    for args in [["--focus", "1", "--blur", "6"], ["--focus", "0", "--blur", "6"]] {
        let st = run(&args);
        assert!(st.iter().all(|(_, st, why)| st == "ok" && why.contains("parameters changed")), "{args:?}: {st:?}");
        assert!(run(&args).iter().all(|(_, st, _)| st == "skipped"));
    }
    let now = ["--focus", "0", "--blur", "6"];
    let out_a = out.join("a_bokeh.png");
    let good = std::fs::read(&out_a).unwrap();
    let expect_redo = |why: &str| {
        let st = run(&now);
        assert_eq!(st[0], ("a.png".into(), "ok".into(), st[0].2.clone()), "{st:?}");
        assert!(st[0].2.contains(why), "expected a reason with {why:?}: {st:?}");
        assert_eq!(st[1].1, "skipped", "{st:?}");
        assert_eq!(std::fs::read(&out_a).unwrap().len(), good.len());
    };
    std::fs::write(&out_a, b"").unwrap();
    expect_redo("0 bytes");
    std::fs::write(&out_a, &good[..good.len() / 2]).unwrap();
    expect_redo("bytes");
    // Same size, garbage header.
    std::fs::write(&out_a, vec![7u8; good.len()]).unwrap();
    expect_redo("header");
    // Same size, a valid PNG of other dimensions (a text chunk pads it to the byte).
    std::fs::write(&out_a, png_of_length(8, 6, good.len())).unwrap();
    assert_eq!(drbokeh::io::read_decoded(&out_a, &Default::default()).unwrap().image.width, 8);
    expect_redo("the image 32x24");
    let sidecar = out.join(".a_bokeh.png.drbokeh-fingerprint");
    assert!(sidecar.exists(), "{:?}", files(&out));
    std::fs::remove_file(&sidecar).unwrap();
    expect_redo("no fingerprint");
    // Same content, new modification time: the inputs' fingerprint changed.
    std::thread::sleep(std::time::Duration::from_millis(20));
    scene(&inp, "a", Some("a.depth.exr"), None);
    expect_redo("inputs changed");
    // A manifest's blur is a parameter too.
    let m = t.path().join("m.csv");
    std::fs::write(&m, "image,blur\na.png,3\n").unwrap();
    let (code, s, err) = batch_json(&inp, &out, &["--focus", "0", "--blur", "6", "--manifest", m.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    let st = statuses(&s);
    assert_eq!((st[0].1.as_str(), st[1].1.as_str()), ("ok", "skipped"), "{st:?}");
    assert!(st[0].2.contains("parameters changed"), "{st:?}");
}

/// A valid `w` x `h` grey PNG of exactly `len` bytes: a `tEXt` chunk before `IEND` pads it.
fn png_of_length(w: usize, h: usize, len: usize) -> Vec<u8> {
    let mut png = Vec::new();
    drbokeh::io::encode_png(&mut png, &Image::filled(w, h, 1, 0.5), 8, Transfer::Linear).unwrap();
    let pad = len.checked_sub(png.len() + 12).expect("the target length leaves room for a chunk");
    let mut chunk = b"tEXt".to_vec();
    chunk.extend(b"k\0");
    chunk.resize(4 + pad, b'x');
    let mut out = png[..png.len() - 12].to_vec();
    out.extend((pad as u32).to_be_bytes());
    out.extend(&chunk);
    out.extend(common::crc32(&chunk).to_be_bytes());
    out.extend(&png[png.len() - 12..]);
    assert_eq!(out.len(), len);
    out
}

/// Issue 10: bad values the user set stop the batch with exit 2 before any image runs.
#[test]
fn usage_errors_stop_before_any_image() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    scene(&inp, "b", Some("b.depth.exr"), None);
    let root = t.path();
    assert_usage_error(root, &inp, &out, &[], &["no focus", "a.png", "--focus"]);
    assert_usage_error(root, &inp, &out, &["--focus", "NaN"], &["--focus", "NaN"]);
    assert_usage_error(root, &inp, &out, &["--focus", "inf"], &["--focus"]);
    // A manifest that sets some images only: the others have no focus.
    let m = root.join("m.csv");
    std::fs::write(&m, "image,focus\na.png,0.5\n").unwrap();
    assert_usage_error(root, &inp, &out, &["--manifest", m.to_str().unwrap()], &["no focus", "b.png"]);
    for (row, needle) in [("a.png,NaN,,", "focus"), ("a.png,,\"1;2\",", "focus_at"), ("a.png,0.5,,-1", "blur")] {
        std::fs::write(&m, format!("image,focus,focus_at,blur\n{row}\n")).unwrap();
        assert_usage_error(root, &inp, &out, &["--focus", "1", "--manifest", m.to_str().unwrap()], &["a.png", needle, "m.csv"]);
    }
    std::fs::remove_file(&m).unwrap();
    let cfg = root.join("c.toml");
    std::fs::write(&cfg, "[batch]\ndepth_patterns = []\n").unwrap();
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--config", cfg.to_str().unwrap()], &["batch.depth_patterns", "c.toml"]);
    // Unbounded counts are refused too.
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--jobs", "100000"], &["--jobs", "100000"]);
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--jobs", "many"], &["--jobs", "many", "auto"]);
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--threads-per-image", "0"], &["--threads-per-image", "0"]);
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--threads-per-image", "x"], &["--threads-per-image", "auto"]);
    // Each count within bounds, their product not: refused before a thread starts.
    assert_usage_error(
        root,
        &inp,
        &out,
        &["--focus", "1", "--jobs", "64", "--threads-per-image", "64"],
        &["--jobs", "--threads-per-image", "threads in all"],
    );
    assert_usage_error(root, &inp, &out, &["--focus", "1", "--threads", "100000"], &["--threads"]);
}

/// Issue 10: with `-o` equal to the input folder, outputs (even of photos since removed) and the
/// summary are never taken for photos.
#[test]
fn output_folder_equal_to_input_folder() {
    let t = tempfile::tempdir().unwrap();
    let inp = t.path().join("in");
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    scene(&inp, "b", Some("b_depth.exr"), None);
    let images = |s: &serde_json::Value| statuses(s).into_iter().map(|(i, st, _)| format!("{i} {st}")).collect::<Vec<_>>();
    let (code, s, err) = batch_json(&inp, &inp, &["--focus", "1", "--blur", "4"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(images(&s), ["a.png ok", "b.png ok"]);
    let (code, s, err) = batch_json(&inp, &inp, &["--focus", "1", "--blur", "4", "--force"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(images(&s), ["a.png ok", "b.png ok"]);
    // The photo of b_bokeh.png is gone: its output is still not a photo.
    for f in ["b.png", "b_depth.exr"] {
        std::fs::remove_file(inp.join(f)).unwrap();
    }
    let (code, s, err) = batch_json(&inp, &inp, &["--focus", "1", "--blur", "4"]);
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(images(&s), ["a.png skipped"]);
    // A manifest output in the input folder: made, then not taken for a photo on the rerun.
    let m = t.path().join("m.csv");
    std::fs::write(&m, "image,focus,output\na.png,1,custom_a.png\n").unwrap();
    for expect in ["a.png ok", "a.png skipped"] {
        let (code, s, err) = batch_json(&inp, &inp, &["--blur", "4", "--manifest", m.to_str().unwrap()]);
        assert_eq!(code, Some(0), "{err}");
        assert_eq!(images(&s), [expect]);
    }
    // An output that would overwrite another photo is refused.
    scene(&inp, "c", Some("c.depth.exr"), None);
    std::fs::write(&m, "image,focus,output\na.png,1,c.png\n").unwrap();
    let (code, _, err) = batch_json(&inp, &inp, &["--focus", "1", "--manifest", m.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("overwrite the photo c.png"), "{err}");
    // An output pattern that would overwrite the photos is refused.
    let cfg = t.path().join("same.toml");
    std::fs::write(&cfg, "[batch]\noutput_pattern = \"{stem}\"\n").unwrap();
    let before = std::fs::read(inp.join("a.png")).unwrap();
    let (code, _, err) = batch_json(&inp, &inp, &["--focus", "1", "--config", cfg.to_str().unwrap()]);
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("overwrite") && err.contains("a.png"), "{err}");
    assert_eq!(std::fs::read(inp.join("a.png")).unwrap(), before);
}

/// Issue 10: an output name near the 255-byte limit made the temporary name too long.
#[test]
fn output_names_near_the_length_limit() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    // 240 + "_bokeh.png" = 250 bytes; "é" makes the shortening cut between bytes of a character.
    let stem = format!("{}{}", "é".repeat(100), "s".repeat(40));
    scene(&inp, &stem, Some(&format!("{stem}_depth.exr")), None);
    let (code, s, err) = batch_json(&inp, &out, &["--focus", "1", "--blur", "4"]);
    assert_eq!((code, s["ok"].as_u64()), (Some(0), Some(1)), "{err}");
    assert!(out.join(format!("{stem}_bokeh.png")).exists());
    let names = files(&out);
    assert!(names.iter().all(|n| n.len() <= 255 && !n.ends_with(".drbokeh-tmp")), "{names:?}");
    let (code, s, err) = batch_json(&inp, &out, &["--focus", "1", "--blur", "4"]);
    assert_eq!((code, s["skipped"].as_u64()), (Some(0), Some(1)), "{err}");
}

/// Issues 14 and 43: images in flight at once (`--jobs`) and the threads each gets
/// (`--threads-per-image`) change nothing but the time: the outputs are byte-identical to one
/// at a time, and the summary lists the images in plan order. The summary says the schedule
/// each asked for (the tests' binary sees 2 threads: `RAYON_NUM_THREADS`).
#[test]
fn jobs_and_threads_per_image_change_only_the_time() {
    let t = tempfile::tempdir().unwrap();
    let inp = t.path().join("in");
    std::fs::create_dir_all(&inp).unwrap();
    for stem in ["a", "b", "c", "d", "e"] {
        scene(&inp, stem, Some(&format!("{stem}.depth.exr")), Some(&format!("{stem}.matte.png")));
    }
    let mut runs = Vec::new();
    let cases: [(&[&str], &[u64]); 5] = [
        // One image on both threads; three on one each (more than the cores, as asked); auto:
        // one per core; one per two threads; both given.
        (&["--jobs", "1"], &[2]),
        (&["--jobs", "3"], &[1, 1, 1]),
        (&["--jobs", "auto"], &[1, 1]),
        (&["--threads-per-image", "2"], &[2]),
        (&["--jobs", "2", "--threads-per-image", "3"], &[3, 3]),
    ];
    for (i, (flags, schedule)) in cases.iter().enumerate() {
        let out = t.path().join(format!("out-{i}"));
        let mut args = vec!["--focus", "1", "--blur", "6"];
        args.extend_from_slice(flags);
        let (code, s, err) = batch_json(&inp, &out, &args);
        assert_eq!(code, Some(0), "{flags:?}: {err}");
        let got: Vec<u64> = s["threads_per_image"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
        assert_eq!(&got, schedule, "{flags:?}: threads per image in flight");
        let order: Vec<String> = statuses(&s).into_iter().map(|(image, status, _)| format!("{image} {status}")).collect();
        let outputs: Vec<Vec<u8>> =
            ["a", "b", "c", "d", "e"].iter().map(|n| std::fs::read(out.join(format!("{n}_bokeh.png"))).unwrap()).collect();
        runs.push((flags, order, outputs));
    }
    for (flags, order, outputs) in &runs[1..] {
        assert_eq!(order, &runs[0].1, "{flags:?}: summary order");
        assert!(outputs == &runs[0].2, "{flags:?}: outputs differ from --jobs 1");
    }
}

/// SIGINT or SIGTERM during a batch: the images in flight finish (complete, with their
/// fingerprints), no new one starts, the summary counts the rest as cancelled, exit 130, no
/// temporary file is left, and a second run does the rest. A second signal aborts at once:
/// still exit 130, no temporary file, and every output present is whole.
#[test]
fn signals_stop_a_batch_cleanly() {
    use std::time::{Duration, Instant};
    let (w, h, n) = (128, 96, 10);
    for (signal, twice) in [("TERM", false), ("INT", false), ("TERM", true)] {
        let t = tempfile::tempdir().unwrap();
        let (inp, out) = (t.path().join("in"), t.path().join("out"));
        std::fs::create_dir_all(&inp).unwrap();
        let mut rng = common::Rng::new(7);
        // Below white: noise that touches it sends every speck through the highlights stage
        // (~2.5 s per image, issue 35), where this test wants the render to take the time.
        let rgb = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| 0.9 * rng.next_f32()).collect()).unwrap();
        let depth = Image::from_vec(w, h, 1, (0..w * h).map(|i| if (i % w) < w / 2 { 1.0 } else { 4.0 }).collect()).unwrap();
        for i in 0..n {
            write_png(&inp.join(format!("p{i:02}.png")), &rgb, 8, Transfer::Srgb).unwrap();
            write_exr(&inp.join(format!("p{i:02}.depth.exr")), &depth, &["Y"]).unwrap();
        }
        // The exact kernel at a wide blur: a few tenths of a second per image.
        let args = ["--focus", "1", "--blur", "20", "--kernel", "exact", "--jobs", "1"];
        let mut child = bin()
            .arg("batch")
            .arg(&inp)
            .arg("-o")
            .arg(&out)
            .args(args)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap();
        let outputs = || -> Vec<std::path::PathBuf> {
            let mut v: Vec<_> = std::fs::read_dir(&out).map(|d| d.flatten().map(|e| e.path()).collect()).unwrap_or_default();
            v.sort();
            v
        };
        let t0 = Instant::now();
        while !outputs().iter().any(|p| p.extension().is_some_and(|e| e == "png")) {
            assert!(t0.elapsed() < Duration::from_secs(60), "no output after 60 s");
            std::thread::sleep(Duration::from_millis(5));
        }
        let kill = || assert!(Command::new("kill").arg(format!("-{signal}")).arg(child.id().to_string()).status().unwrap().success());
        kill();
        if twice {
            std::thread::sleep(Duration::from_millis(30));
            kill();
        }
        let t0 = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().unwrap() {
                break s;
            }
            assert!(t0.elapsed() < Duration::from_secs(60), "the batch did not stop within 60 s of SIG{signal}");
            std::thread::sleep(Duration::from_millis(10));
        };
        assert_eq!(status.code(), Some(130), "SIG{signal} (twice: {twice})");
        let left = outputs();
        let names: Vec<String> = left.iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
        assert!(!names.iter().any(|n| n.ends_with(".drbokeh-tmp")), "temporary files left: {names:?}");
        let pngs: Vec<_> = left.iter().filter(|p| p.extension().is_some_and(|e| e == "png")).collect();
        assert!(!pngs.is_empty() && pngs.len() < n, "SIG{signal}: {} of {n} outputs", pngs.len());
        for p in &pngs {
            let img = drbokeh::io::read_decoded(p, &Default::default()).unwrap_or_else(|e| panic!("{} is not whole: {e}", p.display()));
            assert_eq!((img.image.width, img.image.height), (w, h));
            if !twice {
                let record = format!(".{}.drbokeh-fingerprint", p.file_name().unwrap().to_string_lossy());
                assert!(names.contains(&record), "{} finished without its fingerprint: {names:?}", p.display());
            }
        }
        if !twice {
            let s = summary(&out, "drbokeh-batch.json");
            let (ok, cancelled) = (s["ok"].as_u64().unwrap(), s["cancelled"].as_u64().unwrap());
            assert_eq!((ok as usize, ok + cancelled), (pngs.len(), n as u64), "{s}");
        }
        if signal != "TERM" || twice {
            continue;
        }
        // A second run does the rest and skips what is done.
        let (code, s, err) = batch_json(&inp, &out, &args);
        assert_eq!(code, Some(0), "{err}");
        let done = statuses(&s).iter().filter(|(_, st, _)| st == "skipped").count();
        assert_eq!(done, pngs.len(), "{s}");
    }
}

/// Issue 40: the manifest's focus values as keyframes of a frame sequence (interpolated in
/// sorted order, held at the ends), and the focus smoothed over time; each frame equals a
/// single render at the focus the summary reports.
#[test]
fn keyframes_interpolate_the_focus_and_smoothing_steadies_it() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    for k in 0..6 {
        scene(&inp, &format!("f{k}"), Some(&format!("f{k}.depth.exr")), None);
    }
    let m = t.path().join("keys.csv");
    std::fs::write(&m, "image,focus\nf1.png,0.2\nf4.png,0.8\n").unwrap();
    let foci =
        |s: &serde_json::Value| -> Vec<f64> { s["items"].as_array().unwrap().iter().map(|i| i["focus"].as_f64().unwrap()).collect() };
    let (code, s, err) = batch_json(&inp, &out, &["--manifest", m.to_str().unwrap(), "--keyframes", "--blur", "4"]);
    assert_eq!(code, Some(0), "{err}");
    let got = foci(&s);
    let want = [0.2, 0.2, 0.4, 0.6, 0.8, 0.8];
    assert!(got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{got:?}");
    // Each frame is the render at its focus.
    for (k, f) in got.iter().enumerate() {
        let one = t.path().join("one.png");
        let o = bin()
            .current_dir(&inp)
            .args(["render", &format!("f{k}.png"), "--depth", &format!("f{k}.depth.exr"), "--focus", &f.to_string(), "--blur", "4", "-o"])
            .arg(&one)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(std::fs::read(&one).unwrap() == std::fs::read(out.join(format!("f{k}_bokeh.png"))).unwrap(), "frame {k}");
    }
    // Smoothing over 0.1 s at 30 fps (σ = 3 frames): the same sequence, steadier, as the
    // library's smoothing of the interpolated foci.
    let (code, s, err) =
        batch_json(&inp, &out, &["--manifest", m.to_str().unwrap(), "--keyframes", "--blur", "4", "--focus-smoothing", "0.1"]);
    assert_eq!(code, Some(0), "{err}");
    let smooth = foci(&s);
    let lib = drbokeh::focus_pull::smooth_foci(&want.map(|v| v as f32), 3.0);
    assert!(smooth.iter().zip(&lib).all(|(a, b)| (a - *b as f64).abs() < 1e-6), "{smooth:?} vs {lib:?}");
    assert!(smooth[0] > 0.2 && smooth[5] < 0.8 && smooth.windows(2).all(|w| w[1] >= w[0]), "{smooth:?}");
    // σ is seconds × --fps frames: 0.2 s at 15 fps is the same σ of 3 frames (the default of
    // 30 fps alone would not show a batch that ignores --fps).
    let (code, s, err) = batch_json(
        &inp,
        &out,
        &["--manifest", m.to_str().unwrap(), "--keyframes", "--blur", "4", "--focus-smoothing", "0.2", "--fps", "15"],
    );
    assert_eq!(code, Some(0), "{err}");
    let at15 = foci(&s);
    assert!(at15.iter().zip(&lib).all(|(a, b)| (a - *b as f64).abs() < 1e-6), "--fps 15: {at15:?} vs {lib:?}");
    // Without a focus value to interpolate from, or smoothing focus_at: exit 2 naming why.
    let bad = t.path().join("bad.csv");
    std::fs::write(&bad, "image,focus_at\nf1.png,\"3,4\"\n").unwrap();
    let o = batch_json_output(&inp, &out, &["--manifest", bad.to_str().unwrap(), "--keyframes"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--keyframes"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = batch_json_output(&inp, &out, &["--focus-at", "3,4", "--focus-smoothing", "0.5"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("focus_at"), "{}", String::from_utf8_lossy(&o.stderr));
}

/// A 32x24 matte of the left half of `scene`'s square only: a foreground the depth map alone
/// would not give, so a render that ignores it is another picture.
fn half_matte(path: &Path) {
    let (w, h) = (32, 24);
    let inside = |x: usize, y: usize| (10..16).contains(&x) && (6..18).contains(&y);
    let m = Image::from_vec(w, h, 1, (0..w * h).map(|i| inside(i % w, i / w) as u8 as f32).collect()).unwrap();
    write_png(path, &m, 8, Transfer::Linear).unwrap();
}

/// The guide's pairing rules for mattes: a photo's `NAME_matte.*` is its matte, and a
/// manifest's `matte` cell (relative to INPUT_DIR) gives one to a photo that has none by name.
/// Each output must equal a single `drbokeh render` with that `--matte`, and differ from the
/// render without it: the other batch tests pair mattes but never look at what they did.
#[test]
fn mattes_by_name_and_by_manifest_are_used() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(inp.join("mattes")).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), None);
    scene(&inp, "b", Some("b_depth.exr"), None);
    half_matte(&inp.join("a_matte.png"));
    half_matte(&inp.join("mattes/half.png"));
    let m = t.path().join("m.csv");
    std::fs::write(&m, "image,matte\nb.png,mattes/half.png\n").unwrap();
    let (code, s, err) = batch_json(&inp, &out, &["--focus", "0", "--blur", "6", "--manifest", m.to_str().unwrap()]);
    assert_eq!(code, Some(0), "{err}");
    assert!(statuses(&s).iter().all(|(_, st, _)| st == "ok"), "{s}");
    let render = |args: &[&str]| {
        let one = t.path().join("one.png");
        let o = bin().current_dir(&inp).arg("render").args(args).args(["--focus", "0", "--blur", "6", "-o"]).arg(&one).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read(&one).unwrap()
    };
    for (stem, depth, matte) in [("a", "a.depth.exr", "a_matte.png"), ("b", "b_depth.exr", "mattes/half.png")] {
        let got = std::fs::read(out.join(format!("{stem}_bokeh.png"))).unwrap();
        let photo = format!("{stem}.png");
        assert!(got == render(&[&photo, "--depth", depth, "--matte", matte]), "{stem}: not the render with --matte {matte}");
        assert!(got != render(&[&photo, "--depth", depth]), "{stem}: the matte changes nothing here; the test proves nothing");
    }
}

/// The guide's resume rules beyond blur and focus: the matte is one of the inputs (a newer
/// one redoes its image only, "inputs changed"); the parameters' hash takes the configuration
/// without `[batch]`, so a `[batch]` setting (the memory budget) redoes nothing while a
/// rendering setting (`[render] quality`) redoes everything.
#[test]
fn resume_follows_the_matte_and_the_configuration_but_not_batch_settings() {
    let t = tempfile::tempdir().unwrap();
    let (inp, out) = (t.path().join("in"), t.path().join("out"));
    std::fs::create_dir_all(&inp).unwrap();
    scene(&inp, "a", Some("a.depth.exr"), Some("a.matte.png"));
    scene(&inp, "b", Some("b.depth.exr"), None);
    let (batch_cfg, render_cfg) = (t.path().join("batch.toml"), t.path().join("render.toml"));
    std::fs::write(&batch_cfg, "[batch]\nmemory_budget_mb = 512\n").unwrap();
    std::fs::write(&render_cfg, "[render]\nquality = 3\n").unwrap();
    let run = |cfg: Option<&Path>| {
        let mut args = vec!["--focus", "1", "--blur", "4"];
        if let Some(c) = cfg {
            args.extend(["--config", c.to_str().unwrap()]);
        }
        let (code, s, err) = batch_json(&inp, &out, &args);
        assert_eq!(code, Some(0), "{err}");
        statuses(&s)
    };
    assert!(run(None).iter().all(|(_, st, _)| st == "ok"));
    let st = run(Some(&batch_cfg));
    assert!(st.iter().all(|(_, st, _)| st == "skipped"), "a [batch] setting redid outputs: {st:?}");
    let st = run(Some(&render_cfg));
    assert!(st.iter().all(|(_, st, why)| st == "ok" && why.contains("parameters changed")), "{st:?}");
    // A newer matte, same content: its image is redone, the other one is not.
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(inp.join("a.matte.png"), std::fs::read(inp.join("a.matte.png")).unwrap()).unwrap();
    let st = run(Some(&render_cfg));
    assert_eq!((st[0].0.as_str(), st[0].1.as_str()), ("a.png", "ok"), "{st:?}");
    assert!(st[0].2.contains("inputs changed"), "{st:?}");
    assert_eq!(st[1].1, "skipped", "{st:?}");
}
