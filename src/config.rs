//! `pipeline.toml`: every option of a run in one typed struct, with defaults and validation.
//!
//! CLI flags override these values; a key the program does not know is an error that names
//! it (and the closest valid key), so a typo never silently falls back to a default.

use crate::error::{Error, Result};
use crate::io::{BitDepth, OutputFormat};
use crate::render;
use crate::stages::background::InpaintOptions;
use crate::stages::depth::DepthKind;
use crate::stages::fill_depth::FillDepthOptions;
use crate::stages::segment::SegmentOptions;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The whole `pipeline.toml`: one table per stage plus input, output, models and batch.
/// Every key has a default (`Config::default()` is the bundled file).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// `[input]`: what the depth file holds and the decoding limit.
    pub input: InputConfig,
    /// `[highlights]`: the light of clipped highlights (integer photos), or a boost.
    pub highlights: crate::stages::light_recovery::HighlightsOptions,
    /// `[segment]`: where the foreground layer comes from.
    pub segment: SegmentOptions,
    /// `[fill_depth]`: how the foreground's disparity is extended under its outline.
    pub fill_depth: FillDepthOptions,
    /// `[inpaint]`: how the background behind the foreground is filled.
    pub inpaint: InpaintOptions,
    /// `[render]`: kernel, blur strength, lens window, gamma, occlusion.
    pub render: RenderConfig,
    /// `[aperture]`: the shape of the bokeh. Left out of the config's JSON at its default
    /// (the disc), so batch fingerprints made before the table existed stay valid.
    #[serde(skip_serializing_if = "ApertureConfig::is_disc")]
    pub aperture: ApertureConfig,
    /// `[output]`: PNG bit depth.
    pub output: OutputConfig,
    /// `[depth]`: the optional depth-estimation model (used when no depth map is given).
    pub depth: crate::onnx::DepthConfig,
    /// `[onnx]`: ONNX Runtime location, threads, execution providers, model folder.
    pub onnx: crate::onnx::OnnxConfig,
    /// `[batch]`: how `drbokeh batch` pairs files and bounds memory.
    pub batch: BatchConfig,
}

/// `[batch]`: file pairing, output names and memory budget of `drbokeh batch`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BatchConfig {
    /// Name patterns of an image's depth map, `{stem}` = the image's name without extension;
    /// each is tried with the extensions exr, png, tif, tiff, npy.
    pub depth_patterns: Vec<String>,
    /// Name patterns of an image's (optional) matte; extensions png, tif, tiff, exr, npy.
    pub matte_patterns: Vec<String>,
    /// Output name pattern (`{stem}`), without extension.
    pub output_pattern: String,
    /// Output format, also the outputs' extension: "png", "exr" or "npy".
    pub output_format: OutputFormat,
    /// Images in flight never need more than this much memory (estimated from their size:
    /// about 200 bytes per pixel); one image is always allowed. Unset: half the memory
    /// available when the batch starts ([`BatchConfig::memory_budget_bytes`]).
    pub memory_budget_mb: Option<u64>,
}

impl BatchConfig {
    /// The budget in bytes: `memory_budget_mb`, else half of what the system says is available
    /// ([`crate::resources::available_bytes`]: memory, cgroup, address space), at least 1 GiB;
    /// 4 GiB where nothing says.
    pub fn memory_budget_bytes(&self) -> u64 {
        match self.memory_budget_mb {
            Some(mb) => mb.saturating_mul(1 << 20),
            None => crate::resources::available_bytes().map_or(4 << 30, |b| (b / 2).max(1 << 30)),
        }
    }
}

impl Default for BatchConfig {
    fn default() -> Self {
        BatchConfig {
            depth_patterns: vec!["{stem}.depth".into(), "{stem}_depth".into()],
            matte_patterns: vec!["{stem}.matte".into(), "{stem}_matte".into()],
            output_pattern: "{stem}_bokeh".into(),
            output_format: OutputFormat::Png,
            memory_budget_mb: None,
        }
    }
}

/// `[input]`: how input files are read.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InputConfig {
    /// What the depth file holds: "depth" (z distances) or "disparity" (larger = nearer).
    pub depth_kind: DepthKind,
    /// Images with more pixels are refused before decoding (decompression-bomb guard).
    pub max_pixels: u64,
    /// A photo given without a depth file uses the depth map it embeds (GDepth in a JPEG)
    /// before any depth model; false ignores it. Left out of the config's JSON at its default,
    /// so batch fingerprints made before the key existed stay valid.
    #[serde(skip_serializing_if = "is_true")]
    pub embedded_depth: bool,
    /// A photo given without a matte uses the matte it embeds (a HEIF portrait matte); false
    /// ignores it. Left out of the config's JSON at its default, as `embedded_depth`.
    #[serde(skip_serializing_if = "is_true")]
    pub embedded_matte: bool,
}

fn is_true(b: &bool) -> bool {
    *b
}

impl Default for InputConfig {
    fn default() -> Self {
        InputConfig { depth_kind: DepthKind::Depth, max_pixels: 200_000_000, embedded_depth: true, embedded_matte: true }
    }
}

/// `[aperture]`: the shape of the bokeh (see `render::aperture::shape`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ApertureConfig {
    /// `disc`, `blades:N[,rotation=DEG][,curvature=C]` or `image:PATH` (a grey mask, bright =
    /// open; a relative path is read from the working directory).
    pub shape: String,
    /// Aspect ratio of the bokeh: > 1 taller than wide, < 1 wider; 1 = none.
    pub anamorphic: f32,
    /// Radial intensity profile in [-1, 1]: > 0 a bright rim ("soap bubble"), < 0 a bright
    /// centre, 0 uniform.
    pub bubble: f32,
    /// Longitudinal chromatic aberration in [-0.5, 0.5]: red's circle of confusion scaled by
    /// `1 + C`, blue's by `1 − C`; 0 = none.
    pub chromatic: f32,
    /// Optical vignetting ("cat's eye") in [0, 1]: off axis, the bokeh is cut by a second
    /// circle displaced toward the frame's centre; 0 = off.
    pub cat_eye: f32,
}

impl Default for ApertureConfig {
    fn default() -> Self {
        ApertureConfig { shape: "disc".into(), anamorphic: 1.0, bubble: 0.0, chromatic: 0.0, cat_eye: 0.0 }
    }
}

impl ApertureConfig {
    /// The plain disc shape (the default; chromatic aberration aside, which any profile
    /// renders).
    pub fn is_disc(&self) -> bool {
        ApertureConfig { chromatic: 0.0, ..self.clone() } == ApertureConfig::default()
    }

    /// The aperture it names; reads an image aperture's file.
    pub fn resolve(&self) -> Result<render::Aperture> {
        render::Aperture::with_bubble(
            &render::ShapeSpec::parse(&self.shape, "aperture.shape")?,
            self.anamorphic,
            self.bubble,
            "aperture.shape",
        )?
        .with_cat_eye(self.cat_eye)?
        .with_chromatic(self.chromatic)
    }
}

/// Which kernel renders the layers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum KernelChoice {
    /// The best available kernel; skips rendering when nothing is out of focus.
    #[default]
    Auto,
    /// The official formula, always run (even at K = 0, where it slightly softens).
    Exact,
    /// The fast kernel at `render.quality`, always run.
    Fast,
}

/// `[render]`: the lens model's settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Which kernel renders the layers (see [`KernelChoice`]).
    pub kernel: KernelChoice,
    /// Fast-kernel quality, 1 (fastest) … 8 (converges to exact); 2 is the default.
    pub quality: u32,
    /// Blur strength K (pixels of CoC radius per unit of normalized disparity).
    /// Unset: 30 × sqrt(megapixels), the official 30 at 1 MP.
    pub blur: Option<f32>,
    /// Odd lens window side. Unset: sized from the largest CoC in the scene.
    pub lens: Option<usize>,
    /// Official "naive gamma" G (render on rgb^G). Unset: exact sRGB transfer.
    pub gamma: Option<f32>,
    /// false: classical scatter without occlusion (one layer), for comparison.
    pub occlusion: bool,
    /// Lens calibration: "physical" (the default: calibrated to the thin lens) or "official"
    /// (the Dr.Bokeh formula).
    pub profile: crate::render::Profile,
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            kernel: KernelChoice::Auto,
            quality: 2,
            blur: None,
            lens: None,
            gamma: None,
            occlusion: true,
            profile: crate::render::Profile::Physical,
        }
    }
}

/// `[output]`: how results are written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// PNG bit depth: 8 or 16 (EXR and NPY outputs are always 32-bit float).
    pub bit_depth: BitDepth,
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig { bit_depth: BitDepth::Eight }
    }
}

impl Config {
    /// Reads and validates a pipeline.toml.
    pub fn load(path: &Path) -> Result<Config> {
        let text = crate::io::read_input_text(path)?;
        let cfg = Config::parse(&text).map_err(|msg| Error::input(path, msg))?;
        cfg.validate().map_err(|e| match e {
            Error::Usage(msg) => Error::input(path, msg),
            other => other,
        })?;
        Ok(cfg)
    }

    /// Parses TOML text; the error message says which key is wrong and why.
    pub fn parse(text: &str) -> std::result::Result<Config, String> {
        toml::from_str::<Config>(text).map_err(|e| describe_toml_error(&e, text))
    }

    /// Checks value ranges that the types cannot express.
    pub fn validate(&self) -> Result<()> {
        let r = &self.render;
        if let Some(k) = r.blur {
            render::check_blur("render.blur", k)?;
        }
        if let Some(l) = r.lens {
            render::check_lens("render.lens", l)?;
        }
        if !(1..=8).contains(&r.quality) {
            return Err(Error::usage(format!("render.quality must be 1..=8, got {}", r.quality)));
        }
        if let Some(g) = r.gamma
            && !(g.is_finite() && g > 0.0)
        {
            return Err(Error::usage(format!("render.gamma must be a positive number, got {g}")));
        }
        if !self.batch.output_pattern.contains("{stem}") {
            return Err(Error::usage("batch.output_pattern must contain {stem}"));
        }
        if !stays_inside(Path::new(&self.batch.output_pattern)) {
            return Err(Error::usage(format!(
                "batch.output_pattern \"{}\" must stay inside the output folder (a relative path without '..')",
                self.batch.output_pattern
            )));
        }
        if self.batch.depth_patterns.is_empty() {
            return Err(Error::usage("batch.depth_patterns must list at least one pattern (e.g. \"{stem}.depth\")"));
        }
        self.highlights.validate("highlights")?;
        // The shape's syntax and ranges; an image is read when the pipeline is built.
        render::ShapeSpec::parse(&self.aperture.shape, "aperture.shape")?;
        let a = &self.aperture;
        render::Aperture::check_values(a.anamorphic, a.bubble, a.chromatic, a.cat_eye)?;
        if !self.aperture.is_disc() && self.render.profile == render::Profile::Official {
            let a = &self.aperture;
            return Err(Error::usage(format!(
                "aperture.shape {} (anamorphic {}, bubble {}, cat_eye {}): render.profile official renders the plain disc only; use the physical profile",
                a.shape, a.anamorphic, a.bubble, a.cat_eye
            )));
        }
        if self.input.max_pixels == 0 {
            return Err(Error::usage("input.max_pixels must be > 0"));
        }
        // Checks values only; never loads ONNX Runtime or a model.
        self.onnx.validate()?;
        self.segment.onnx.validate("segment.onnx", crate::onnx::ModelKind::Matte)?;
        self.inpaint.onnx.validate("inpaint.onnx", crate::onnx::ModelKind::Inpaint)?;
        self.depth.onnx.validate("depth.onnx", crate::onnx::ModelKind::Depth)?;
        self.segment.layers.check("segment.layers")?;
        if !(self.segment.layer_gap.is_finite() && (0.0..=1.0).contains(&self.segment.layer_gap)) {
            return Err(Error::usage(format!("segment.layer_gap must be in [0, 1], got {}", self.segment.layer_gap)));
        }
        if !(self.segment.layer_min_fraction.is_finite() && (0.0..=0.5).contains(&self.segment.layer_min_fraction)) {
            return Err(Error::usage(format!("segment.layer_min_fraction must be in [0, 0.5], got {}", self.segment.layer_min_fraction)));
        }
        for (key, v) in [
            ("fill_depth.erode", self.fill_depth.erode),
            ("fill_depth.radius", self.fill_depth.radius),
            ("inpaint.dilate", self.inpaint.dilate),
            ("inpaint.radius", self.inpaint.radius),
            ("segment.edge_softness", self.segment.edge_softness),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::usage(format!("{key} must be a finite number >= 0, got {v}")));
            }
        }
        Ok(())
    }
}

/// True if the relative path `rel` names something inside the folder it is joined to: no root,
/// no drive prefix, no `..` (checked on the words, not the file system; `.` is allowed).
pub fn stays_inside(rel: &Path) -> bool {
    use std::path::Component;
    // A backslash separates folders on Windows; judged the same everywhere so a manifest means
    // the same on every system.
    let unified = rel.to_string_lossy().replace('\\', "/");
    !unified.is_empty() && Path::new(&unified).components().all(|c| matches!(c, Component::Normal(_) | Component::CurDir))
}

/// Turns a TOML/serde error into one line; for an unknown key, suggests the closest valid key.
/// The dotted key (`segment.layers`) assigned on the line of `text` that holds byte `at`,
/// with the table it is in; None off an assignment. O(bytes before `at`).
fn key_at(text: &str, at: usize) -> Option<String> {
    let mut table = String::new();
    let mut start = 0;
    for line in text.split_inclusive('\n') {
        let end = start + line.len();
        let t = line.trim();
        if t.starts_with('[') {
            table = t.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string();
        }
        if (start..end).contains(&at) {
            let (key, _) = t.split_once('=').filter(|_| !t.starts_with('['))?;
            let key = key.trim().trim_matches('"');
            return Some(if table.is_empty() { key.to_string() } else { format!("{table}.{key}") });
        }
        start = end;
    }
    None
}

fn describe_toml_error(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().to_string();
    let mut out = msg.clone();
    if let Some(rest) = msg.strip_prefix("unknown field `") {
        let key = rest.split('`').next().unwrap_or("");
        let expected: Vec<&str> = rest
            .split("expected ")
            .nth(1)
            .map(|s| s.split('`').filter(|t| t.chars().all(|c| c.is_alphanumeric() || c == '_') && !t.is_empty()).collect())
            .unwrap_or_default();
        if let Some(best) = expected.iter().min_by_key(|cand| edit_distance(key, cand)) {
            if edit_distance(key, best) <= key.len().max(3) / 2 + 1 {
                out = format!("unknown key `{key}` (did you mean `{best}`?); valid keys here: {}", expected.join(", "));
            } else {
                out = format!("unknown key `{key}`; valid keys here: {}", expected.join(", "));
            }
        }
    }
    match e.span() {
        Some(span) => {
            let line = text[..span.start.min(text.len())].matches('\n').count() + 1;
            match key_at(text, span.start) {
                Some(key) if !out.contains(&format!("`{key}`")) => format!("{key}: {out} (line {line})"),
                _ => format!("{out} (line {line})"),
            }
        }
        None => out,
    }
}

/// Levenshtein distance, for "did you mean" suggestions.
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1];
        for (j, cb) in b.iter().enumerate() {
            cur.push((prev[j] + (ca != *cb) as usize).min(prev[j + 1] + 1).min(cur[j] + 1));
        }
        prev = cur;
    }
    prev[b.len()]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `[batch] memory_budget_mb` as set, else half of what is available, at least 1 GiB.
    #[test]
    fn the_batch_budget_is_the_set_one_or_half_the_available_memory() {
        let set = BatchConfig { memory_budget_mb: Some(512), ..Default::default() };
        assert_eq!(set.memory_budget_bytes(), 512 << 20);
        let auto = BatchConfig::default().memory_budget_bytes();
        match crate::resources::available_bytes() {
            // MemAvailable moves between the two reads: within 10%.
            Some(b) => {
                let want = (b / 2).max(1 << 30) as f64;
                assert!((auto as f64 / want - 1.0).abs() < 0.1, "{auto} bytes against {want}");
            }
            None => assert_eq!(auto, 4 << 30),
        }
        let parsed: Config = toml::from_str("[batch]\nmemory_budget_mb = 2048\n").unwrap();
        assert_eq!(parsed.batch.memory_budget_mb, Some(2048));
    }

    #[test]
    fn unknown_key_suggests_closest() {
        let e = Config::parse("[render]\nblurr = 3\n").unwrap_err();
        assert!(e.contains("blurr") && e.contains("did you mean `blur`"), "{e}");
        let e = Config::parse("[render]\nblur = \"x\"\n").unwrap_err();
        assert!(e.contains("blur") || e.contains("invalid type"), "{e}");
    }

    /// A wrong value names its key (with its table) and what is accepted, not the parser's types.
    #[test]
    fn wrong_values_name_their_key() {
        for v in ["-1", "2.5", "0", "9", "true", "\"many\""] {
            let e = Config::parse(&format!("[render]\nblur = 3\n\n[segment]\nlayers = {v}\n")).unwrap_err();
            assert!(e.contains("segment.layers") && e.contains("1..=8") && e.contains("line 5"), "{v}: {e}");
            assert!(!e.contains("variant"), "{v}: {e}");
        }
        let e = Config::parse("[render]\nblur = \"x\"\n").unwrap_err();
        assert!(e.starts_with("render.blur:"), "{e}");
        assert_eq!(key_at("a = 1\n[x.y]\n \"b\" = 2\n", 16).as_deref(), Some("x.y.b"));
    }

    #[test]
    fn batch_paths_stay_inside_the_output_folder() {
        for ok in ["{stem}_bokeh", "sub/{stem}", "./{stem}"] {
            assert!(stays_inside(Path::new(ok)), "{ok}");
        }
        for bad in ["../{stem}", "../../escape_{stem}", "/tmp/{stem}", "a/../../{stem}", "..\\{stem}", ""] {
            assert!(!stays_inside(Path::new(bad)), "{bad}");
        }
        let mut cfg = Config::default();
        cfg.batch.output_pattern = "../../escape_{stem}".into();
        assert!(matches!(cfg.validate(), Err(Error::Usage(m)) if m.contains("batch.output_pattern")));
        let mut cfg = Config::default();
        cfg.batch.depth_patterns.clear();
        assert!(matches!(cfg.validate(), Err(Error::Usage(m)) if m.contains("batch.depth_patterns")));
    }

    #[test]
    fn bundled_pipeline_toml_is_the_default() {
        let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/pipeline.toml")).unwrap();
        assert_eq!(Config::parse(&text).unwrap(), Config::default());
    }
}
