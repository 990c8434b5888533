//! Helpers shared by the integration tests: the shared data folder, a seeded generator, the
//! `drbokeh` executable and its usage-error contract ([`assert_usage_error`]), and a place
//! for failing renders ([`save_failure`]).
#![allow(dead_code)]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// The `shared/` data folder (golden vectors, ground truth): `$DRBOKEH_SHARED`, else `../shared`.
pub fn shared_dir() -> PathBuf {
    let dir = std::env::var_os("DRBOKEH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    assert!(dir.is_dir(), "shared data folder {} not found (set DRBOKEH_SHARED)", dir.display());
    dir
}

/// Sorted sub-folders of `dir`; at least one (a test looping over none would pass on nothing).
pub fn case_dirs(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_dir()).collect();
    assert!(!v.is_empty(), "no case folders in {}: the data the test checks is missing", dir.display());
    v.sort();
    v
}

pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Small deterministic generator (xorshift64*), so tests need no extra crate.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }
    pub fn next_f32(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32) / (1u64 << 24) as f32
    }
}

/// A golden-vector case of ../shared/reference: its layers (colours raised to the case's
/// gamma as the official inference does), settings, layer names and gamma.
pub fn golden_case(dir: &std::path::Path) -> (Vec<drbokeh::render::Layer<'static>>, drbokeh::render::RenderSettings, Vec<String>, f64) {
    use drbokeh::render::{Layer, RenderSettings};
    let params: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("params.json")).unwrap()).unwrap();
    let gamma = params["gamma"].as_f64().unwrap();
    let names: Vec<String> = params["layers"].as_array().unwrap().iter().map(|v| v.as_str().unwrap().to_owned()).collect();
    let layers = names
        .iter()
        .map(|n| {
            let img = drbokeh::io::npy::read_npy(&dir.join(format!("{n}.npy")), u64::MAX).unwrap_or_else(|e| panic!("{e}"));
            let mut l = Layer::new(img, n).unwrap();
            // The official inference raises colours to gamma in double precision.
            if gamma != 1.0 {
                l.map_colors(|c| (c as f64).powf(gamma) as f32);
            }
            l
        })
        .collect();
    let s = RenderSettings {
        blur: params["K"].as_f64().unwrap() as f32,
        focus: params["focus"].as_f64().unwrap() as f32,
        lens: params["lens"].as_u64().unwrap() as usize,
        occlusion: true,
        profile: drbokeh::render::Profile::Official,
        aperture: drbokeh::render::Aperture::DISC,
    };
    (layers, s, names, gamma)
}

/// CRC-32 (IEEE), for crafting PNG chunks in tests.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// The `drbokeh` executable this test binary was built with, as a plain command (the test
/// process's folder and environment). Add the subcommand and its arguments.
pub fn drbokeh_bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drbokeh"))
}

/// [`drbokeh_bin`] run in `dir` (its working directory), with two rayon threads so runs are
/// alike on any machine.
pub fn drbokeh(dir: &Path) -> Command {
    let mut c = drbokeh_bin();
    c.current_dir(dir).env("RAYON_NUM_THREADS", "2");
    c
}

/// Runs `cmd` to completion and returns its output.
pub fn run(mut cmd: Command) -> Output {
    cmd.output().unwrap_or_else(|e| panic!("cannot run {cmd:?}: {e}"))
}

/// Runs `cmd` to completion, or kills it and fails the test after `limit`. Output is read
/// after exit, so it suits commands that print little (error cases), not a pipe-filling log.
pub fn run_within(mut cmd: Command, limit: Duration) -> Output {
    let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().expect("cannot run drbokeh");
    let t0 = Instant::now();
    while child.try_wait().expect("wait").is_none() {
        if t0.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!("{cmd:?} still running after {limit:?} (blocked on an input?)");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.wait_with_output().expect("output")
}

/// A command's stderr, as text.
pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Every file under `dir` (recursive) with its content, sorted by relative path.
pub fn snapshot(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                out.push((rel, std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Every file under `dir` (recursive), as relative paths.
pub fn list_files(dir: &Path) -> BTreeSet<String> {
    snapshot(dir).into_iter().map(|(p, _)| p).collect()
}

/// The usage-error contract of every `drbokeh` command: `run` (described as `what` in
/// messages) exits 2, its stderr names every entry of `needles` (the file or flag at fault),
/// nothing panicked, and no file under `root` was created or changed. Returns stderr.
pub fn assert_usage_error(root: &Path, what: &str, needles: &[&str], run: impl FnOnce() -> Output) -> String {
    let before = snapshot(root);
    let out = run();
    let err = stderr(&out);
    assert_eq!(out.status.code(), Some(2), "{what} should exit 2; stderr: {err}");
    for n in needles {
        assert!(err.contains(n), "{what}: the message should name {n:?}; got: {err}");
    }
    assert!(!err.contains("panicked"), "{what}: panic on user input: {err}");
    let after = snapshot(root);
    if before != after {
        let names = |s: &[(String, Vec<u8>)]| s.iter().map(|(p, _)| p.clone()).collect::<Vec<_>>();
        panic!("{what} changed the folder (wrote output?): before {:?}, after {:?}", names(&before), names(&after));
    }
    err
}

/// Where a failing test leaves its evidence: `target/test-failures/` (created).
pub fn failure_dir() -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target").join("test-failures");
    std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
    dir
}

/// Saves a failing render as `target/test-failures/NAME.npy` (NAME made file-safe) and
/// returns the path, for the failure message.
pub fn save_failure(name: &str, img: &drbokeh::Image) -> PathBuf {
    let safe: String = name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' }).collect();
    let path = failure_dir().join(format!("{safe}.npy"));
    drbokeh::io::npy::save_npy(&path, img).unwrap_or_else(|e| panic!("cannot save {}: {e}", path.display()));
    path
}

/// Fails with every entry of `failures` (one per line) if there are any: a test checks every
/// case first, then asserts once.
pub fn assert_no_failures(what: &str, failures: &[String]) {
    assert!(failures.is_empty(), "{what}: {} failing case(s):\n{}", failures.len(), failures.join("\n"));
}

/// A five-pointed star (outer radius 1, inner 0.45), a point up: even-odd crossing test on
/// its ten vertices.
pub fn in_star(x: f64, y: f64) -> bool {
    let v: Vec<(f64, f64)> = (0..10)
        .map(|k| {
            let (r, t) = (if k % 2 == 0 { 1.0 } else { 0.45 }, std::f64::consts::PI / 2.0 + std::f64::consts::PI * k as f64 / 5.0);
            (r * t.cos(), r * t.sin())
        })
        .collect();
    let mut inside = false;
    for i in 0..10 {
        let ((x1, y1), (x2, y2)) = (v[i], v[(i + 1) % 10]);
        if (y1 > y) != (y2 > y) && x < x1 + (y - y1) * (x2 - x1) / (y2 - y1) {
            inside = !inside;
        }
    }
    inside
}

/// The star as a 128 × 128 grey image (supersampled 4 × 4 per cell, top row up).
pub fn star_mask() -> (usize, Vec<f32>) {
    let n = 128;
    let mut v = vec![0f32; n * n];
    for row in 0..n {
        for col in 0..n {
            let mut hit = 0;
            for i in 0..4 {
                for j in 0..4 {
                    let x = -1.0 + 2.0 * (col as f64 + (i as f64 + 0.5) / 4.0) / n as f64;
                    let y = 1.0 - 2.0 * (row as f64 + (j as f64 + 0.5) / 4.0) / n as f64;
                    hit += in_star(x, y) as usize;
                }
            }
            v[row * n + col] = hit as f32 / 16.0;
        }
    }
    (n, v)
}
