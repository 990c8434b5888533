//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The `shared/` data folder (golden vectors, ground truth): `$DRBOKEH_SHARED`, else `../shared`.
pub fn shared_dir() -> PathBuf {
    let dir = std::env::var_os("DRBOKEH_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared"));
    assert!(dir.is_dir(), "shared data folder {} not found (set DRBOKEH_SHARED)", dir.display());
    dir
}

/// Sorted sub-folders of `dir`.
pub fn case_dirs(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_dir()).collect();
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
pub fn golden_case(dir: &std::path::Path) -> (Vec<drbokeh::render::Layer>, drbokeh::render::RenderSettings, Vec<String>, f64) {
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
