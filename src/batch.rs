//! `drbokeh batch`: every photo of a folder through the pipeline, safely and resumably.
//!
//! - Pairing: `NAME.ext` with its depth map and optional matte by the `[batch]` name patterns.
//! - Deterministic order (sorted relative paths) and sharding (`--shard I/N` takes every N-th
//!   item starting at I), so external schedulers can split a collection without coordination.
//! - Resumable: an output newer than all its inputs is skipped unless `force`.
//! - Each image is one [`crate::job::Job`] (atomic output); a failure is recorded, not fatal.
//! - Bounded memory: images in flight stay under a budget estimated from their pixel counts.
//! - Cancellable: once `cancel` is set, no new image starts; images in flight finish.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::job::{self, Job};
use crate::pipeline::{Focus, Pipeline};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::{Instant, SystemTime};

/// Extensions of photos a batch picks up.
pub const IMAGE_EXTENSIONS: [&str; 6] = ["png", "jpg", "jpeg", "tif", "tiff", "exr"];
const DEPTH_EXTENSIONS: [&str; 5] = ["exr", "png", "tif", "tiff", "npy"];
const MATTE_EXTENSIONS: [&str; 5] = ["png", "tif", "tiff", "exr", "npy"];
/// Estimated peak memory per pixel of one render (inputs, layers, kernel buffers).
const BYTES_PER_PIXEL: u64 = 200;

/// Options of a batch run (the CLI's flags).
#[derive(Clone, Debug)]
pub struct BatchOptions {
    pub input_dir: PathBuf,
    pub output_dir: PathBuf,
    pub recursive: bool,
    pub force: bool,
    /// `(i, n)`: process items `i, i + n, i + 2n, …` (0-based).
    pub shard: Option<(usize, usize)>,
    /// Images rendered at the same time (each render is itself multithreaded).
    pub jobs: usize,
    /// Focus for images the manifest does not set.
    pub focus: Option<Focus>,
    pub manifest: Option<PathBuf>,
}

/// Per-image overrides from a manifest (CSV with a header row, or TOML `[[image]]` tables).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestEntry {
    /// The image, relative to the input folder.
    pub image: String,
    #[serde(default)]
    pub focus: Option<f32>,
    /// "X,Y"
    #[serde(default)]
    pub focus_at: Option<String>,
    #[serde(default)]
    pub blur: Option<f32>,
    #[serde(default)]
    pub matte: Option<String>,
    /// Output path, relative to the output folder.
    #[serde(default)]
    pub output: Option<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TomlManifest {
    image: Vec<ManifestEntry>,
}

/// Reads a manifest: `.csv` (columns image, focus, focus_at, blur, matte, output; empty cells
/// allowed) or `.toml` (`[[image]]` tables with the same keys).
pub fn read_manifest(path: &Path) -> Result<BTreeMap<String, ManifestEntry>> {
    let text = crate::io::read_input_text(path)?;
    let entries: Vec<ManifestEntry> = match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("toml") => toml::from_str::<TomlManifest>(&text).map_err(|e| Error::input(path, format!("invalid manifest: {}", e.message())))?.image,
        Some("csv") => {
            let mut rdr = csv::ReaderBuilder::new().trim(csv::Trim::All).from_reader(text.as_bytes());
            let mut v = Vec::new();
            for (n, rec) in rdr.deserialize::<ManifestEntry>().enumerate() {
                v.push(rec.map_err(|e| Error::input(path, format!("invalid manifest row {}: {e}", n + 2)))?);
            }
            v
        }
        _ => return Err(Error::input(path, "a manifest must be a .csv or .toml file")),
    };
    let mut map = BTreeMap::new();
    for e in entries {
        let key = e.image.replace('\\', "/");
        if map.insert(key.clone(), e).is_some() {
            return Err(Error::input(path, format!("image '{key}' is listed twice")));
        }
    }
    Ok(map)
}

/// One image of the batch with its companions and output.
#[derive(Clone, Debug, Serialize)]
pub struct Item {
    /// Path relative to the input folder (the sort key and the manifest key).
    pub rel: String,
    pub image: PathBuf,
    pub depth: Option<PathBuf>,
    pub matte: Option<PathBuf>,
    pub output: PathBuf,
}

fn ext_of(p: &Path) -> Option<String> {
    p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase)
}

fn companion(dir: &Path, names: &BTreeSet<String>, stem: &str, patterns: &[String], exts: &[&str]) -> Option<PathBuf> {
    for pat in patterns {
        let base = pat.replace("{stem}", stem);
        for ext in exts {
            for cand in [format!("{base}.{ext}"), format!("{base}.{}", ext.to_ascii_uppercase())] {
                if names.contains(&cand) {
                    return Some(dir.join(cand));
                }
            }
        }
    }
    None
}

/// Finds the images of `opts.input_dir` (and its subfolders with `recursive`), sorted by
/// relative path, with their depth maps, mattes and output paths (subfolders mirrored).
pub fn discover(opts: &BatchOptions, cfg: &Config) -> Result<Vec<Item>> {
    if !opts.input_dir.is_dir() {
        return Err(Error::input(&opts.input_dir, "input folder does not exist or is not a folder"));
    }
    let mut dirs = vec![PathBuf::new()];
    let mut items = Vec::new();
    while let Some(rel_dir) = dirs.pop() {
        let dir = opts.input_dir.join(&rel_dir);
        let mut names = BTreeSet::new();
        for entry in std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))? {
            let entry = entry.map_err(|e| Error::io(&dir, e))?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let ft = entry.file_type().map_err(|e| Error::io(entry.path(), e))?;
            if ft.is_dir() {
                // Never descend into the output folder if it lives inside the input folder.
                if opts.recursive && !name.starts_with('.') && !same_dir(&entry.path(), &opts.output_dir) {
                    dirs.push(rel_dir.join(&name));
                }
            } else if !name.starts_with('.') {
                names.insert(name);
            }
        }
        let images: Vec<&String> = names.iter().filter(|n| ext_of(Path::new(n)).is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.as_str()))).collect();
        // A file that is another image's depth map or matte is not an image itself.
        let mut companions = BTreeSet::new();
        for n in &images {
            let stem = Path::new(n).file_stem().unwrap_or_default().to_string_lossy();
            for (pats, exts) in [(&cfg.batch.depth_patterns, &DEPTH_EXTENSIONS[..]), (&cfg.batch.matte_patterns, &MATTE_EXTENSIONS[..])] {
                if let Some(c) = companion(&dir, &names, &stem, pats, exts) {
                    companions.insert(c.file_name().unwrap_or_default().to_string_lossy().into_owned());
                }
            }
        }
        for n in images.into_iter().filter(|n| !companions.contains(*n)) {
            let stem = Path::new(n).file_stem().unwrap_or_default().to_string_lossy().into_owned();
            let out_name = format!("{}.{}", cfg.batch.output_pattern.replace("{stem}", &stem), cfg.batch.output_format);
            items.push(Item {
                rel: rel_dir.join(n).to_string_lossy().replace('\\', "/"),
                image: dir.join(n),
                depth: companion(&dir, &names, &stem, &cfg.batch.depth_patterns, &DEPTH_EXTENSIONS),
                matte: companion(&dir, &names, &stem, &cfg.batch.matte_patterns, &MATTE_EXTENSIONS),
                output: opts.output_dir.join(&rel_dir).join(out_name),
            });
        }
    }
    items.sort_by(|a, b| a.rel.cmp(&b.rel));
    Ok(items)
}

fn same_dir(a: &Path, b: &Path) -> bool {
    match (std::fs::canonicalize(a), std::fs::canonicalize(b)) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// Parses `I/N` (0-based shard index I of N shards).
pub fn parse_shard(s: &str) -> std::result::Result<(usize, usize), String> {
    let err = || format!("--shard must be I/N with 0 <= I < N (0-based), got '{s}'");
    let (i, n) = s.split_once('/').ok_or_else(err)?;
    let (i, n) = (i.trim().parse::<usize>().map_err(|_| err())?, n.trim().parse::<usize>().map_err(|_| err())?);
    if n == 0 || i >= n {
        return Err(err());
    }
    Ok((i, n))
}

/// What happened to one item.
#[derive(Clone, Debug, Serialize)]
pub struct ItemResult {
    pub image: String,
    /// "ok", "skipped", "failed" or "cancelled".
    pub status: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    pub output: String,
    pub seconds: f64,
}

/// The batch summary (also written to `OUTPUT_DIR/drbokeh-batch.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    pub ok: usize,
    pub skipped: usize,
    pub failed: usize,
    pub cancelled: usize,
    pub shard: Option<String>,
    pub seconds: f64,
    pub items: Vec<ItemResult>,
}

/// Limits the estimated memory of the images in flight.
struct Budget {
    limit: u64,
    used: Mutex<u64>,
    freed: Condvar,
}

impl Budget {
    fn acquire(&self, bytes: u64) {
        let mut used = self.used.lock().expect("budget");
        // One image is always allowed, however large.
        while *used > 0 && *used + bytes > self.limit {
            used = self.freed.wait(used).expect("budget");
        }
        *used += bytes;
    }
    fn release(&self, bytes: u64) {
        *self.used.lock().expect("budget") -= bytes;
        self.freed.notify_all();
    }
}

/// Pixel count from the file header, without decoding (0 when unknown).
fn probe_pixels(path: &Path) -> u64 {
    image::ImageReader::open(path)
        .ok()
        .and_then(|r| r.with_guessed_format().ok())
        .and_then(|r| r.into_dimensions().ok())
        .map(|(w, h)| w as u64 * h as u64)
        .unwrap_or(0)
}

fn mtime(p: &Path) -> Option<SystemTime> {
    std::fs::metadata(p).and_then(|m| m.modified()).ok()
}

/// True if `out` exists and is newer than every input.
fn up_to_date(out: &Path, inputs: &[PathBuf]) -> bool {
    let Some(t) = mtime(out) else { return false };
    inputs.iter().all(|i| mtime(i).is_some_and(|ti| ti <= t))
}

/// Removes temporary files left next to `output` by an interrupted earlier run.
fn remove_stale_temps(output: &Path) {
    let (Some(dir), Some(name)) = (output.parent(), output.file_name()) else { return };
    let prefix = format!(".{}.", name.to_string_lossy());
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let n = e.file_name().to_string_lossy().into_owned();
            if n.starts_with(&prefix) && n.ends_with(".drbokeh-tmp") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }
}

/// Runs the batch. `progress` is called after each item with (done, total, result).
pub fn run(cfg: &Config, opts: &BatchOptions, cancel: &AtomicBool, progress: &(dyn Fn(usize, usize, &ItemResult) + Sync)) -> Result<Summary> {
    let t0 = Instant::now();
    let manifest = match &opts.manifest {
        Some(p) => read_manifest(p)?,
        None => BTreeMap::new(),
    };
    let mut items = discover(opts, cfg)?;
    for key in manifest.keys() {
        if !items.iter().any(|i| &i.rel == key) {
            return Err(Error::input(opts.manifest.as_deref().unwrap_or(Path::new("manifest")), format!("image '{key}' is not in {}", opts.input_dir.display())));
        }
    }
    if let Some((i, n)) = opts.shard {
        items = items.into_iter().enumerate().filter(|(k, _)| k % n == i).map(|(_, it)| it).collect();
    }
    std::fs::create_dir_all(&opts.output_dir).map_err(|e| Error::io(&opts.output_dir, e))?;
    let total = items.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let budget = Budget { limit: cfg.batch.memory_budget_mb.saturating_mul(1 << 20), used: Mutex::new(0), freed: Condvar::new() };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(opts.jobs.max(1)).build().map_err(|e| Error::Internal(e.to_string()))?;
    let results: Vec<ItemResult> = pool.install(|| {
        use rayon::prelude::*;
        items
            .par_iter()
            .with_max_len(1)
            .map(|item| {
                let entry = manifest.get(&item.rel);
                let r = if cancel.load(Ordering::SeqCst) {
                    result(item, "cancelled", Some("interrupted before it started".into()), 0.0)
                } else {
                    process(cfg, opts, item, entry, &budget)
                };
                let k = done.fetch_add(1, Ordering::SeqCst) + 1;
                progress(k, total, &r);
                r
            })
            .collect()
    });
    let mut summary = Summary { shard: opts.shard.map(|(i, n)| format!("{i}/{n}")), ..Default::default() };
    for r in &results {
        match r.status {
            "ok" => summary.ok += 1,
            "skipped" => summary.skipped += 1,
            "cancelled" => summary.cancelled += 1,
            _ => summary.failed += 1,
        }
    }
    summary.items = results;
    summary.seconds = t0.elapsed().as_secs_f64();
    let path = summary_path(&opts.output_dir, opts.shard);
    let text = serde_json::to_string_pretty(&summary).map_err(|e| Error::Internal(e.to_string()))?;
    crate::io::atomic::write_atomic(&path, |w| std::io::Write::write_all(w, text.as_bytes()).map_err(|e| Error::io(&path, e)))?;
    Ok(summary)
}

/// Where the summary of a run (or of one shard) is written.
pub fn summary_path(output_dir: &Path, shard: Option<(usize, usize)>) -> PathBuf {
    output_dir.join(match shard {
        Some((i, n)) => format!("drbokeh-batch.shard-{i}-of-{n}.json"),
        None => "drbokeh-batch.json".into(),
    })
}

fn result(item: &Item, status: &'static str, reason: Option<String>, seconds: f64) -> ItemResult {
    ItemResult { image: item.rel.clone(), status, reason, output: item.output.display().to_string(), seconds }
}

fn process(cfg: &Config, opts: &BatchOptions, item: &Item, entry: Option<&ManifestEntry>, budget: &Budget) -> ItemResult {
    let t = Instant::now();
    let outcome = (|| -> Result<Option<String>> {
        let mut cfg = cfg.clone();
        let mut matte = item.matte.clone();
        let mut output = item.output.clone();
        let mut focus = opts.focus;
        if let Some(e) = entry {
            if let Some(b) = e.blur {
                cfg.render.blur = Some(b);
            }
            if let Some(m) = &e.matte {
                matte = Some(item.image.parent().unwrap_or(Path::new(".")).join(m));
            }
            if let Some(o) = &e.output {
                output = opts.output_dir.join(o);
            }
            if let Some(f) = e.focus {
                focus = Some(Focus::Disparity(f));
            } else if let Some(xy) = &e.focus_at {
                let (x, y) = xy.split_once(',').and_then(|(x, y)| Some((x.trim().parse().ok()?, y.trim().parse().ok()?))).ok_or_else(|| Error::usage(format!("manifest focus_at '{xy}' is not X,Y")))?;
                focus = Some(Focus::At(x, y));
            }
        }
        let focus = focus.ok_or_else(|| Error::usage("no focus: give --focus/--focus-at or a manifest entry"))?;
        let depth = item.depth.clone().ok_or_else(|| {
            Error::input(&item.image, format!("no depth map found (looked for {} with .exr/.png/.tif/.tiff/.npy)", cfg.batch.depth_patterns.join(", ")))
        })?;
        let job = Job { image: Some(item.image.clone()), depth: Some(depth), matte, layers: Vec::new(), focus, output: output.clone(), save_layers: None };
        if !opts.force && up_to_date(&output, &job.inputs()) {
            return Ok(Some("output is newer than its inputs (use --force to redo)".into()));
        }
        if let Some(dir) = output.parent() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        }
        remove_stale_temps(&output);
        let bytes = probe_pixels(&item.image).saturating_mul(BYTES_PER_PIXEL);
        budget.acquire(bytes);
        // A bug in one image must not take the batch down with it.
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| Pipeline::from_config(cfg).and_then(|p| job::run(&p, &job))))
            .unwrap_or_else(|_| Err(Error::Internal("the renderer panicked on this image (a bug; please report it)".into())));
        budget.release(bytes);
        r.map(|_| None)
    })();
    let secs = t.elapsed().as_secs_f64();
    match outcome {
        Ok(None) => result(item, "ok", None, secs),
        Ok(Some(why)) => result(item, "skipped", Some(why), secs),
        Err(e) => result(item, "failed", Some(e.to_string()), secs),
    }
}
