//! `drbokeh batch`: every photo of a folder through the pipeline, safely and resumably.
//!
//! - Pairing: `NAME.ext` with its depth map and optional matte by the `[batch]` name patterns.
//! - Deterministic order (sorted relative paths) and sharding (`--shard I/N` takes every N-th
//!   item starting at I), so external schedulers can split a collection without coordination.
//! - Resumable: an output is skipped (unless `force`) when the [`Fingerprint`] of its inputs
//!   and parameters recorded beside it matches and the file still is what was written.
//! - Each image is one [`crate::job::Job`] (atomic output); a failure is recorded, not fatal.
//!   Values the user set (focus, manifest entries, config) are checked for every image before
//!   any renders: a bad one is a usage error, not a failure of every image.
//! - Writes stay inside the output folder, and nothing it writes is read back as a photo.
//! - Bounded memory: images in flight stay under a budget estimated from their pixel counts.
//! - Every core busy: images in flight each run on their own share of the cores
//!   ([`schedule`]).
//! - Cancellable: once `cancel` is set, no new image starts; images in flight finish.
//! - Safe beside other runs on the same folder: only temporary files whose writer is gone are
//!   removed (see [`crate::io::atomic`]).

use crate::config::{Config, stays_inside};
use crate::error::{Error, Result};
use crate::job::{self, Job};
use crate::pipeline::{Focus, Pipeline};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Condvar, Mutex};
use std::time::{Instant, SystemTime};

pub mod schedule;

/// Extensions of photos a batch picks up.
pub const IMAGE_EXTENSIONS: [&str; 10] = ["png", "jpg", "jpeg", "tif", "tiff", "exr", "heic", "heif", "hif", "avif"];
const DEPTH_EXTENSIONS: [&str; 5] = ["exr", "png", "tif", "tiff", "npy"];
const MATTE_EXTENSIONS: [&str; 5] = ["png", "tif", "tiff", "exr", "npy"];
/// Estimated peak memory per pixel of one render (inputs, layers, kernel buffers).
const BYTES_PER_PIXEL: u64 = 200;

/// Options of a batch run (the CLI's flags).
#[derive(Clone, Debug)]
pub struct BatchOptions {
    /// The folder the photos are found in (`INPUT_DIR`); item paths are relative to it.
    pub input_dir: PathBuf,
    /// The folder outputs, fingerprints and the summary go to (created if missing).
    pub output_dir: PathBuf,
    /// Also process subfolders, mirrored in the output folder.
    pub recursive: bool,
    /// Render every item again, even when its output is up to date.
    pub force: bool,
    /// `(i, n)`: process items `i, i + n, i + 2n, …` (0-based).
    pub shard: Option<(usize, usize)>,
    /// Images rendered at the same time; `None`: as many as the memory budget holds, up to
    /// one per core ([`schedule::schedule`]).
    pub jobs: Option<usize>,
    /// Threads each image's stages and render use; `None`: the cores split evenly among the
    /// images in flight.
    pub threads_per_image: Option<usize>,
    /// Focus for images the manifest does not set.
    pub focus: Option<Focus>,
    /// Per-image overrides (see [`read_manifest`]), if any.
    pub manifest: Option<PathBuf>,
    /// The manifest's `focus` values are keyframes: an image without its own focus gets one
    /// interpolated in the batch's order ([`crate::focus_pull::interpolate_keyframes`]).
    pub keyframes: bool,
    /// `(seconds, frames per second)`: the images' focus values, in the batch's order, smoothed
    /// over time by a Gaussian of that width ([`crate::focus_pull::smooth_foci`]), so a video's focus does not
    /// jitter from frame to frame.
    pub focus_smoothing: Option<(f32, f32)>,
}

/// Per-image overrides from a manifest (CSV with a header row, or TOML `[[image]]` tables).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ManifestEntry {
    /// The image, relative to the input folder.
    pub image: String,
    /// Focal plane as normalized disparity (0 far … 1 near), finite; wins over `focus_at`.
    #[serde(default)]
    pub focus: Option<f32>,
    /// "X,Y"
    #[serde(default)]
    pub focus_at: Option<String>,
    /// Blur strength K for this image (pixels of CoC radius per unit of disparity, >= 0).
    #[serde(default)]
    pub blur: Option<f32>,
    /// The image's matte, relative to the image's folder (overrides the pattern's match).
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
        Some("toml") => {
            toml::from_str::<TomlManifest>(&text).map_err(|e| Error::input(path, format!("invalid manifest: {}", e.message())))?.image
        }
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
    /// The photo's path (input folder joined with `rel`).
    pub image: PathBuf,
    /// Its depth map, found by `batch.depth_patterns`; None makes the item fail.
    pub depth: Option<PathBuf>,
    /// Its optional matte, found by `batch.matte_patterns` (or set by the manifest).
    pub matte: Option<PathBuf>,
    /// Where its result goes, inside the output folder.
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
        // In the folder this folder's outputs go to (`-o` = the input folder), files named like
        // outputs are earlier results, not photos (their photo may even be gone).
        let outputs_here = same_dir(&dir, &opts.output_dir.join(&rel_dir));
        let images: Vec<&String> = names
            .iter()
            .filter(|n| ext_of(Path::new(n)).is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.as_str())))
            .filter(|n| !(outputs_here && is_output_name(n, &cfg.batch) && output_name(n, &cfg.batch) != **n))
            .collect();
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
            let out_name = output_name(n, &cfg.batch);
            if !stays_inside(Path::new(&out_name)) {
                return Err(Error::usage(format!("batch.output_pattern makes '{out_name}' of {n}, outside the output folder")));
            }
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

/// The output's path, relative to the output folder's counterpart of the photo's folder.
fn output_name(photo: &str, batch: &crate::config::BatchConfig) -> String {
    let stem = Path::new(photo).file_stem().unwrap_or_default().to_string_lossy();
    format!("{}.{}", batch.output_pattern.replace("{stem}", &stem), batch.output_format.extension())
}

/// True if the file name `name` is what `batch.output_pattern` and `batch.output_format` make
/// of some stem. A pattern with folders is never matched here (its outputs are recognized by
/// their exact paths, see `drop_outputs`). O(name length).
fn is_output_name(name: &str, batch: &crate::config::BatchConfig) -> bool {
    const STEM: &str = "{stem}";
    let pattern = &batch.output_pattern;
    let Some(base) = name.strip_suffix(&format!(".{}", batch.output_format.extension())) else { return false };
    let (n, Some(first)) = (pattern.matches(STEM).count(), pattern.find(STEM)) else { return false };
    if pattern.contains('/') || pattern.contains('\\') {
        return false;
    }
    // Every {stem} stands for the same text, so its length follows from the name's.
    let fixed = pattern.len() - n * STEM.len();
    if base.len() < fixed || !(base.len() - fixed).is_multiple_of(n) {
        return false;
    }
    let len = (base.len() - fixed) / n;
    base.get(first..first + len).is_some_and(|stem| pattern.replace(STEM, stem) == base)
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

/// What happened to one item (serialized lowercase: "ok", "skipped", "failed", "cancelled").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Rendered and written.
    Ok,
    /// Its output is up to date (same inputs and parameters, valid file).
    Skipped,
    /// Could not be rendered; `reason` says why.
    Failed,
    /// Not started because the batch was interrupted.
    Cancelled,
}

impl Status {
    /// The name used in the JSON summary and in progress lines.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Skipped => "skipped",
            Status::Failed => "failed",
            Status::Cancelled => "cancelled",
        }
    }
}

/// What happened to one item.
#[derive(Clone, Debug, Serialize)]
pub struct ItemResult {
    /// The item's path relative to the input folder.
    pub image: String,
    /// What happened to it.
    pub status: Status,
    /// Why it was skipped or failed; for "ok", why an existing output was made again.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// The output path (as given: the output folder joined with the item's output name).
    pub output: String,
    /// Wall-clock time spent on the item, seconds (0 for cancelled items).
    pub seconds: f64,
    /// The focus as normalized disparity, when it was given as one (by `--focus`, the
    /// manifest, keyframes or smoothing); absent for a focus given by `focus_at`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub focus: Option<f32>,
    /// The fingerprint the output was (or is) made with: 16 hex digits of the inputs' hash,
    /// then 16 of the parameters' hash (see [`Fingerprint`]); absent when the item did not get
    /// that far.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fingerprint: Option<String>,
}

/// The batch summary (also written to `OUTPUT_DIR/drbokeh-batch.json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Summary {
    /// Items rendered and written by this run.
    pub ok: usize,
    /// Items whose output was already up to date.
    pub skipped: usize,
    /// Items that could not be rendered (each has a `reason`).
    pub failed: usize,
    /// Items not started because the run was interrupted.
    pub cancelled: usize,
    /// `"I/N"` when the run processed one shard only.
    pub shard: Option<String>,
    /// Wall-clock time of the whole run, seconds.
    pub seconds: f64,
    /// Threads of each image in flight, one entry per worker (its length is the number of
    /// images in flight at most).
    pub threads_per_image: Vec<usize>,
    /// One result per item of this run (or shard), in sorted path order.
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

/// An item with everything resolved before any image runs (manifest applied, values checked),
/// so that a bad value stops the batch with a usage error instead of failing every image.
struct Plan {
    item: Item,
    /// The run's configuration with the manifest's blur applied.
    cfg: Config,
    focus: Focus,
}

/// The names were checked to stay inside the output folder; this checks where they lead: a
/// symbolic link under the output folder may point anywhere, and a batch must not write there.
fn check_contained(dir: &Path, output_dir: &Path) -> Result<()> {
    let real = std::fs::canonicalize(dir).map_err(|e| Error::io(dir, e))?;
    let root = std::fs::canonicalize(output_dir).map_err(|e| Error::io(output_dir, e))?;
    if real.starts_with(&root) {
        return Ok(());
    }
    Err(Error::input(
        dir,
        format!("leads to {}, outside the output folder {} (through a symbolic link): not written", real.display(), root.display()),
    ))
}

/// Sets each item's output from the manifest; an output that would leave the output folder
/// (`..`, an absolute path) is an error naming the manifest entry.
fn apply_manifest_outputs(
    items: &mut [Item],
    manifest: &BTreeMap<String, ManifestEntry>,
    manifest_path: &Path,
    output_dir: &Path,
) -> Result<()> {
    for item in items {
        if let Some(o) = manifest.get(&item.rel).and_then(|e| e.output.as_ref()) {
            if !stays_inside(Path::new(o)) {
                return Err(Error::input(
                    manifest_path,
                    format!(
                        "image '{}': output '{o}' is outside the output folder {} (give a path relative to it, without '..')",
                        item.rel,
                        output_dir.display()
                    ),
                ));
            }
            item.output = output_dir.join(o);
        }
    }
    Ok(())
}

/// `path` with its folder resolved (symlinks, `..`), to compare files that may not exist yet.
fn file_key(path: &Path) -> Option<PathBuf> {
    let dir = crate::io::folder_of(path);
    Some(std::fs::canonicalize(dir).ok()?.join(path.file_name()?))
}

/// Drops the items that are another item's earlier output (`-o` equal to the input folder with
/// a manifest `output` or a pattern with folders; plain pattern names are already left out by
/// [`discover`]): what the batch writes is never read back as a photo. An output that would
/// overwrite a photo (one without a fingerprint record beside it) is a usage error.
fn drop_outputs(items: Vec<Item>) -> Result<Vec<Item>> {
    let outputs: BTreeMap<PathBuf, String> = items.iter().filter_map(|i| Some((file_key(&i.output)?, i.rel.clone()))).collect();
    let mut kept = Vec::with_capacity(items.len());
    for item in items {
        match file_key(&item.image).and_then(|k| outputs.get(&k)) {
            Some(_) if record_path(&item.image).exists() => {}
            Some(writer) => {
                let photo = &item.rel;
                return Err(Error::usage(format!(
                    "the output of {writer} would overwrite the photo {photo}; choose another -o, batch.output_pattern or manifest output (or delete {photo} if it is an earlier output)"
                )));
            }
            None => kept.push(item),
        }
    }
    Ok(kept)
}

/// Resolves focus, blur and matte of every item and checks them: a non-finite focus, a bad
/// manifest value or an image without any focus is an error before anything renders. With
/// `keyframes`, an image the manifest does not focus gets its focus from the manifest's focus
/// values around it; with `focus_smoothing`, every focus is then smoothed over the sequence.
fn plan(
    cfg: &Config,
    opts: &BatchOptions,
    items: Vec<Item>,
    manifest: &BTreeMap<String, ManifestEntry>,
    manifest_path: &Path,
) -> Result<Vec<Plan>> {
    if let Some(Focus::Disparity(f)) = opts.focus {
        crate::render::check_focus("render.focus", f)?;
    }
    let entry_error = |rel: &str, msg: String| Error::input(manifest_path, format!("image '{rel}': {msg}"));
    let mut plans = Vec::with_capacity(items.len());
    let mut unfocused = Vec::new();
    for mut item in items {
        let mut cfg = cfg.clone();
        let mut focus = opts.focus;
        if let Some(e) = manifest.get(&item.rel) {
            if let Some(b) = e.blur {
                cfg.render.blur = Some(b);
                cfg.validate().map_err(|err| entry_error(&item.rel, err.to_string().replace("render.blur", "blur")))?;
            }
            if let Some(m) = &e.matte {
                item.matte = Some(item.image.parent().unwrap_or(Path::new(".")).join(m));
            }
            if let Some(f) = e.focus {
                crate::render::check_focus("focus", f).map_err(|e| entry_error(&item.rel, e.to_string()))?;
                focus = Some(Focus::Disparity(f));
            } else if let Some(xy) = &e.focus_at {
                let (x, y) = xy
                    .split_once(',')
                    .and_then(|(x, y)| Some((x.trim().parse().ok()?, y.trim().parse().ok()?)))
                    .ok_or_else(|| entry_error(&item.rel, format!("focus_at '{xy}' is not X,Y (two integers)")))?;
                focus = Some(Focus::At(x, y));
            }
        }
        if opts.keyframes && !manifest.get(&item.rel).is_some_and(|e| e.focus.is_some() || e.focus_at.is_some()) {
            // Filled in below from the keyframes around it.
            focus = Some(Focus::Disparity(f32::NAN));
        }
        match focus {
            Some(focus) => plans.push(Plan { item, cfg, focus }),
            None => unfocused.push(item.rel),
        }
    }
    if opts.keyframes {
        let keys: Vec<Option<f32>> = plans.iter().map(|p| manifest.get(&p.item.rel).and_then(|e| e.focus)).collect();
        let foci = crate::focus_pull::interpolate_keyframes(&keys).ok_or_else(|| {
            Error::usage("--keyframes: the manifest gives no image a focus value to interpolate from (focus_at entries are not keyframes)")
        })?;
        for (p, f) in plans.iter_mut().zip(foci) {
            // An image the manifest focuses (a keyframe, or by focus_at) keeps its own.
            if !manifest.get(&p.item.rel).is_some_and(|e| e.focus.is_some() || e.focus_at.is_some()) {
                p.focus = Focus::Disparity(f);
            }
        }
    }
    if let Some((seconds, fps)) = opts.focus_smoothing {
        if !(seconds.is_finite() && seconds >= 0.0 && fps.is_finite() && fps > 0.0) {
            return Err(Error::usage(format!("--focus-smoothing {seconds} at --fps {fps}: give seconds >= 0 and frames per second > 0")));
        }
        let foci: Vec<f32> = plans
            .iter()
            .map(|p| match p.focus {
                Focus::Disparity(f) => Ok(f),
                _ => Err(Error::usage(format!(
                    "--focus-smoothing smooths focus values; image '{}' is focused by focus_at (give focus values, or --keyframes)",
                    p.item.rel
                ))),
            })
            .collect::<Result<_>>()?;
        for (p, f) in plans.iter_mut().zip(crate::focus_pull::smooth_foci(&foci, seconds * fps)) {
            p.focus = Focus::Disparity(f);
        }
    }
    if !unfocused.is_empty() {
        let some = unfocused.iter().take(3).map(String::as_str).collect::<Vec<_>>().join(", ");
        let more = if unfocused.len() > 3 { format!(" and {} more", unfocused.len() - 3) } else { String::new() };
        return Err(Error::usage(format!(
            "no focus for {some}{more}: give render.focus or render.focus_at, or focus/focus_at in a batch.manifest entry"
        )));
    }
    Ok(plans)
}

/// Runs the batch. `progress` is called after each item with (done, total, result).
///
/// Steps: read the manifest, discover the images, resolve their outputs and settings (every
/// usage error surfaces here, before any image runs), take this shard, remove temporary files
/// of dead writers, render, write the summary.
pub fn run(
    cfg: &Config,
    opts: &BatchOptions,
    cancel: &AtomicBool,
    progress: &(dyn Fn(usize, usize, &ItemResult) + Sync),
) -> Result<Summary> {
    let t0 = Instant::now();
    let manifest_path = opts.manifest.as_deref().unwrap_or(Path::new("manifest"));
    let manifest = match &opts.manifest {
        Some(p) => read_manifest(p)?,
        None => BTreeMap::new(),
    };
    let mut items = discover(opts, cfg)?;
    apply_manifest_outputs(&mut items, &manifest, manifest_path, &opts.output_dir)?;
    let items = drop_outputs(items)?;
    for key in manifest.keys() {
        if !items.iter().any(|i| &i.rel == key) {
            return Err(Error::input(manifest_path, format!("image '{key}' is not in {}", opts.input_dir.display())));
        }
    }
    let mut plans = plan(cfg, opts, items, &manifest, manifest_path)?;
    if let Some((i, n)) = opts.shard {
        plans = plans.into_iter().enumerate().filter(|(k, _)| k % n == i).map(|(_, p)| p).collect();
    }
    // The schedule (a usage error surfaces before anything is written).
    let limit = cfg.batch.memory_budget_bytes();
    let budget = Budget { limit, used: Mutex::new(0), freed: Condvar::new() };
    let machine = schedule::Machine {
        cores: rayon::current_num_threads(),
        items: plans.len(),
        image_bytes: typical_image_bytes(plans.len(), |i| image_bytes(&plans[i].item.image)),
        budget: limit,
    };
    let schedule = schedule::schedule(machine, opts.jobs, opts.threads_per_image);
    let (max, cores) = crate::resources::max_threads();
    let threads: usize = schedule.threads.iter().sum();
    if threads > max {
        return Err(Error::usage(format!(
            "{} images at a time (--jobs, at most one per image) with --threads-per-image {} each asks for {threads} threads in all: at most {max} ({cores} cores here)",
            schedule.threads.len(),
            schedule.threads[0]
        )));
    }
    std::fs::create_dir_all(&opts.output_dir).map_err(|e| Error::io(&opts.output_dir, e))?;
    // Once per folder, not per image: one read_dir each.
    let out_dirs: BTreeSet<&Path> = plans.iter().filter_map(|p| p.item.output.parent()).chain([opts.output_dir.as_path()]).collect();
    for dir in out_dirs {
        crate::io::atomic::remove_stale_temps(dir);
    }
    let total = plans.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let pools = schedule
        .threads
        .iter()
        .enumerate()
        .map(|(w, &n)| rayon::ThreadPoolBuilder::new().num_threads(n).thread_name(move |k| format!("drbokeh-batch-{w}-{k}")).build())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|e| Error::Internal(format!("cannot start the batch's threads: {e}")))?;
    // Each worker takes the next image in plan order and runs it on its own pool: the image's
    // stages and render use that pool's threads only (`schedule` says why).
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<ItemResult> = std::thread::scope(|scope| {
        let workers: Vec<_> = pools
            .iter()
            .map(|pool| {
                scope.spawn(|| {
                    pool.install(|| {
                        let mut mine = Vec::new();
                        loop {
                            let i = next.fetch_add(1, Ordering::SeqCst);
                            let Some(plan) = plans.get(i) else { break };
                            let r = if cancel.load(Ordering::SeqCst) {
                                result(&plan.item, Status::Cancelled, Some("interrupted before it started".into()), 0.0, None)
                            } else {
                                process(opts, plan, &budget)
                            };
                            let k = done.fetch_add(1, Ordering::SeqCst) + 1;
                            progress(k, total, &r);
                            mine.push((i, r));
                        }
                        mine
                    })
                })
            })
            .collect();
        let mut all: Vec<(usize, ItemResult)> =
            workers.into_iter().flat_map(|w| w.join().unwrap_or_else(|e| std::panic::resume_unwind(e))).collect();
        all.sort_by_key(|(i, _)| *i);
        all.into_iter().map(|(_, r)| r).collect()
    });
    let mut results = results;
    for (r, p) in results.iter_mut().zip(&plans) {
        if let Focus::Disparity(f) = p.focus {
            r.focus = Some(f);
        }
    }
    let mut summary =
        Summary { shard: opts.shard.map(|(i, n)| format!("{i}/{n}")), threads_per_image: schedule.threads, ..Default::default() };
    for r in &results {
        match r.status {
            Status::Ok => summary.ok += 1,
            Status::Skipped => summary.skipped += 1,
            Status::Cancelled => summary.cancelled += 1,
            Status::Failed => summary.failed += 1,
        }
    }
    summary.items = results;
    summary.seconds = t0.elapsed().as_secs_f64();
    let path = summary_path(&opts.output_dir, opts.shard);
    let text = serde_json::to_string_pretty(&summary).map_err(|e| Error::Internal(e.to_string()))?;
    crate::io::atomic::write_atomic(&path, |w| std::io::Write::write_all(w, text.as_bytes()).map_err(|e| Error::io(&path, e)))?;
    Ok(summary)
}

/// Estimated render memory of a typical image of the batch: the median over up to 31 of the
/// `n` images, spread through the plan (`bytes_of(i)` reads image i's header), so that one
/// outlier does not set the schedule and a long batch is not read twice.
fn typical_image_bytes(n: usize, bytes_of: impl Fn(usize) -> u64) -> u64 {
    let step = n.div_ceil(31).max(1);
    let mut sizes: Vec<u64> = (0..n).step_by(step).map(bytes_of).collect();
    sizes.sort_unstable();
    sizes.get(sizes.len() / 2).copied().unwrap_or(0)
}

/// Estimated render memory of one image, from its header (0 when unreadable: its render
/// reports why).
fn image_bytes(image: &Path) -> u64 {
    crate::io::inspect::probe_size(image).map_or(0, |(w, h)| w * h).saturating_mul(BYTES_PER_PIXEL)
}

/// Where the summary of a run (or of one shard) is written.
pub fn summary_path(output_dir: &Path, shard: Option<(usize, usize)>) -> PathBuf {
    output_dir.join(match shard {
        Some((i, n)) => format!("drbokeh-batch.shard-{i}-of-{n}.json"),
        None => "drbokeh-batch.json".into(),
    })
}

fn result(item: &Item, status: Status, reason: Option<String>, seconds: f64, fingerprint: Option<&Fingerprint>) -> ItemResult {
    ItemResult {
        image: item.rel.clone(),
        status,
        reason,
        output: item.output.display().to_string(),
        seconds,
        focus: None,
        fingerprint: fingerprint.map(Fingerprint::hex),
    }
}

/// What an output is made from: a hash of its inputs (path relative to the input folder, size
/// and modification time of each: no file is read) and a hash of its effective parameters
/// (the configuration without `[batch]`, the manifest's blur, the focus, the output format).
/// Equal fingerprints and a valid output file mean the output is up to date.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fingerprint {
    /// 64-bit FNV-1a of the inputs' list, 16 hex digits.
    pub inputs: String,
    /// 64-bit FNV-1a of the parameters' JSON, 16 hex digits.
    pub params: String,
}

impl Fingerprint {
    fn of(plan: &Plan, job: &Job, input_dir: &Path) -> Fingerprint {
        let mut inputs = String::new();
        for p in job.inputs() {
            let rel = p.strip_prefix(input_dir).unwrap_or(&p).to_string_lossy().replace('\\', "/");
            let meta = std::fs::metadata(&p).ok();
            let nanos = meta
                .as_ref()
                .and_then(|m| m.modified().ok())
                .and_then(|t| t.duration_since(SystemTime::UNIX_EPOCH).ok())
                .map(|d| d.as_nanos());
            inputs.push_str(&format!("{rel}\t{:?}\t{nanos:?}\n", meta.map(|m| m.len())));
        }
        let mut cfg = plan.cfg.clone();
        // How files are paired and memory is budgeted does not change an output.
        cfg.batch = Default::default();
        let focus = match plan.focus {
            Focus::Disparity(f) => serde_json::json!({ "disparity": f }),
            Focus::At(x, y) => serde_json::json!({ "at": [x, y] }),
            Focus::Depth(z) => serde_json::json!({ "depth": z }),
        };
        let params = serde_json::json!({ "config": cfg, "focus": focus, "format": ext_of(&job.output) }).to_string();
        let hex = |t: &str| format!("{:016x}", crate::io::atomic::fnv1a64(t.as_bytes()));
        Fingerprint { inputs: hex(&inputs), params: hex(&params) }
    }

    fn hex(&self) -> String {
        format!("{}{}", self.inputs, self.params)
    }
}

/// The sidecar `.NAME.drbokeh-fingerprint` written beside an output once it is complete.
#[derive(Serialize, Deserialize)]
struct Record {
    fingerprint: Fingerprint,
    /// Size of the output file when it was written: a truncated or replaced file differs.
    output_bytes: u64,
    /// The drbokeh version that wrote it (information only; not compared).
    drbokeh: String,
}

fn record_path(output: &Path) -> PathBuf {
    crate::io::atomic::hidden_sibling(output, "drbokeh-fingerprint")
}

/// Why the existing `output` must be made again, or None if it is up to date: a missing or
/// different fingerprint, or a file that is not what was written (size, readable header, the
/// image's width and height). Reads the sidecar and the headers only.
fn stale_reason(output: &Path, image: &Path, fp: &Fingerprint) -> Option<String> {
    let record = std::fs::read(record_path(output)).ok().and_then(|b| serde_json::from_slice::<Record>(&b).ok());
    let Some(record) = record else {
        return Some("the existing output has no fingerprint (made by an older drbokeh, or interrupted); made again".into());
    };
    if record.fingerprint.params != fp.params {
        return Some("parameters changed since the existing output was made; made again".into());
    }
    if record.fingerprint.inputs != fp.inputs {
        return Some("inputs changed since the existing output was made; made again".into());
    }
    let bytes = std::fs::metadata(output).map(|m| m.len()).unwrap_or(0);
    if bytes == 0 || bytes != record.output_bytes {
        return Some(format!("the existing output is {bytes} bytes, {} were written; made again", record.output_bytes));
    }
    match (crate::io::inspect::probe_size(output), crate::io::inspect::probe_size(image)) {
        (None, _) => Some("the existing output's header is unreadable; made again".into()),
        (Some(o), Some(i)) if o != i => Some(format!("the existing output is {}x{}, the image {}x{}; made again", o.0, o.1, i.0, i.1)),
        _ => None,
    }
}

fn process(opts: &BatchOptions, plan: &Plan, budget: &Budget) -> ItemResult {
    let t = Instant::now();
    let item = &plan.item;
    let mut fingerprint = None;
    let outcome = (|| -> Result<(Status, Option<String>)> {
        let output = item.output.clone();
        // Without a depth companion the photo's embedded depth map is used (a portrait JPEG or
        // HEIC), else the configured depth model, as `render` does.
        let job = Job {
            image: Some(item.image.clone()),
            depth: item.depth.clone(),
            matte: item.matte.clone(),
            layers: Vec::new(),
            focus: plan.focus,
            output: output.clone(),
            save_layers: None,
            pull: None,
        };
        let fp = fingerprint.insert(Fingerprint::of(plan, &job, &opts.input_dir)).clone();
        let redo = match (output.exists(), opts.force) {
            (false, _) => None,
            (true, true) => Some("--force: made again".to_string()),
            (true, false) => match stale_reason(&output, &item.image, &fp) {
                None => return Ok((Status::Skipped, Some("up to date: same inputs and parameters (use --force to redo)".into()))),
                why => why,
            },
        };
        if let Some(dir) = output.parent() {
            std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
            check_contained(dir, &opts.output_dir)?;
        }
        // A stale record must not vouch for the new output if this render is interrupted.
        let record = record_path(&output);
        match std::fs::remove_file(&record) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(Error::io(&record, e)),
            _ => {}
        }
        let bytes = image_bytes(&item.image);
        budget.acquire(bytes);
        // A bug in one image must not take the batch down with it.
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            Pipeline::from_config(plan.cfg.clone()).and_then(|p| job::run(&p, &job))
        }))
        .unwrap_or_else(|_| Err(Error::Internal("the renderer panicked on this image (a bug; please report it)".into())));
        budget.release(bytes);
        r.map_err(|e| match e {
            // With nothing to give depth (the job's usage error names the ways forward), say
            // which companions were looked for.
            Error::Usage(msg) if item.depth.is_none() => Error::input(
                &item.image,
                format!(
                    "no depth map found (looked for {} with .exr/.png/.tif/.tiff/.npy): {msg}",
                    plan.cfg.batch.depth_patterns.join(", ")
                ),
            ),
            e => e,
        })?;
        let output_bytes = std::fs::metadata(&output).map_err(|e| Error::io(&output, e))?.len();
        let text = serde_json::to_string_pretty(&Record { fingerprint: fp, output_bytes, drbokeh: env!("CARGO_PKG_VERSION").into() })
            .map_err(|e| Error::Internal(e.to_string()))?;
        crate::io::atomic::write_atomic(&record, |w| std::io::Write::write_all(w, text.as_bytes()).map_err(|e| Error::io(&record, e)))?;
        Ok((Status::Ok, redo))
    })();
    let secs = t.elapsed().as_secs_f64();
    match outcome {
        Ok((status, why)) => result(item, status, why, secs, fingerprint.as_ref()),
        Err(e) => result(item, Status::Failed, Some(e.to_string()), secs, None),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::AtomicU64;

    /// The most bytes in flight at once when images of `sizes` bytes each hold a budget of
    /// 100 for 30 ms, all started together.
    fn most_in_flight(sizes: &[u64]) -> u64 {
        let budget = Budget { limit: 100, used: Mutex::new(0), freed: Condvar::new() };
        let (now, most) = (AtomicU64::new(0), AtomicU64::new(0));
        std::thread::scope(|s| {
            for &bytes in sizes {
                let (budget, now, most) = (&budget, &now, &most);
                s.spawn(move || {
                    budget.acquire(bytes);
                    let held = now.fetch_add(bytes, Ordering::SeqCst) + bytes;
                    most.fetch_max(held, Ordering::SeqCst);
                    std::thread::sleep(std::time::Duration::from_millis(30));
                    now.fetch_sub(bytes, Ordering::SeqCst);
                    budget.release(bytes);
                });
            }
        });
        most.into_inner()
    }

    /// The schedule's typical image: the median of a sample spread through the batch, read
    /// once each; an outlier does not move it.
    #[test]
    fn the_typical_image_is_the_median_of_a_spread_sample() {
        let reads = std::sync::atomic::AtomicUsize::new(0);
        let size = |i: usize| {
            reads.fetch_add(1, Ordering::SeqCst);
            if i == 0 { 1_000_000 } else { 100 + i as u64 }
        };
        assert_eq!(typical_image_bytes(5, size), 103);
        assert_eq!(reads.swap(0, Ordering::SeqCst), 5);
        // 100 images: every 4th (25 read: 0, 4, ..., 96), the outlier among them; the median
        // is the 13th of the sorted 25.
        assert_eq!(typical_image_bytes(100, size), 100 + 52);
        assert_eq!(reads.load(Ordering::SeqCst), 25);
        assert_eq!(typical_image_bytes(0, size), 0);
    }

    /// `[batch] memory_budget_mb`: images whose estimates together exceed the budget never run
    /// at the same time, and one image larger than the whole budget still runs (alone).
    #[test]
    fn the_memory_budget_bounds_the_images_in_flight() {
        let m = most_in_flight(&[60, 60, 30, 30, 60]);
        assert!((60..=100).contains(&m), "{m} bytes were in flight at once against a budget of 100");
        assert_eq!(most_in_flight(&[500]), 500);
        assert_eq!(most_in_flight(&[500, 500, 500]), 500);
    }
}
