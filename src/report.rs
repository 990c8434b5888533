//! What a run reports (`--json`): every stage ran or skipped with its time and detail, the
//! parameters used, the warnings, where the depth came from, the output or a focus pull's
//! frames. Filled by [`crate::pipeline`] and [`crate::job`].

use crate::timing::ms_since;
use serde::Serialize;
use std::time::Instant;

/// Whether a stage ran (serialized lowercase: "ran", "skipped").
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum StageStatus {
    /// The stage did its work; `ms` is how long it took.
    Ran,
    /// The stage was not needed; `reason` says why and `ms` is 0.
    Skipped,
}

/// What happened in one stage.
#[derive(Clone, Debug, Serialize)]
pub struct StageReport {
    /// The stage: "read", "depth_model", "highlights", "segment", "fill_depth", "inpaint", "slice", "render",
    /// "save_layers" or "write".
    pub name: &'static str,
    /// Whether it ran.
    pub status: StageStatus,
    /// Why it was skipped (absent when it ran).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Wall-clock time it took, milliseconds (0 when skipped).
    pub ms: f64,
    /// Stage-specific numbers (pixels filled, kernel used, model report...), as JSON.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub detail: Option<serde_json::Value>,
}

impl StageReport {
    /// A stage that ran for `ms` milliseconds, with optional `detail`.
    pub fn ran(name: &'static str, ms: f64, detail: Option<serde_json::Value>) -> Self {
        StageReport { name, status: StageStatus::Ran, reason: None, ms, detail }
    }

    /// A stage that was skipped, and why.
    pub fn skipped(name: &'static str, reason: impl Into<String>) -> Self {
        StageReport { name, status: StageStatus::Skipped, reason: Some(reason.into()), ms: 0.0, detail: None }
    }
}

/// The parameters a render actually used.
#[derive(Clone, Debug, Default, Serialize)]
pub struct UsedParams {
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Blur strength K used: pixels of CoC radius per unit of normalized disparity.
    pub blur: f32,
    /// Focal plane used, normalized disparity in [0, 1] (after clamping).
    pub focus: f32,
    /// Lens window side, pixels (odd); 0 when nothing was rendered.
    pub lens: usize,
    /// The kernel: "exact", "fast (quality Q)", or "none" when nothing was rendered.
    pub kernel: String,
    /// False for the classical scatter baseline (no occlusion terms).
    pub occlusion: bool,
    /// The naive gamma G when used; None: exact sRGB transfer.
    pub gamma: Option<f32>,
    /// Number of layers (1, 2 or `[segment] layers` from the pipeline; as given otherwise).
    pub layers: usize,
    /// Largest circle-of-confusion radius in the scene, pixels.
    pub max_coc_radius_px: f32,
    /// Worker threads the render used.
    pub threads: usize,
    /// The aperture's shape as `--aperture` spells it (`disc`, `blades:6,rotation=0,...`).
    pub aperture: String,
}

/// Where a render's depth came from (`depth_source` in `--json`; tagged by `kind`).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum DepthSource {
    /// A depth file (`--depth`).
    File {
        /// The file.
        path: String,
        /// Its size, pixels.
        width: usize,
        /// Its size, pixels.
        height: usize,
        /// Bits per sample in the file.
        bit_depth: u8,
    },
    /// A depth map embedded in the photo.
    Embedded {
        /// The photo.
        path: String,
        /// Its parameters (the embedding as `container`: "gdepth" or "dynamic-depth"; format,
        /// near, far, mime, size...).
        #[serde(flatten)]
        info: Box<crate::io::embedded_depth::DepthInfo>,
    },
    /// A depth model (`[depth.onnx]` or `onnx.model_dir`).
    Model {
        /// The model file.
        model: String,
        /// The preset its contract started from.
        preset: String,
    },
}

/// Where a render's matte came from (`matte_source` in `--json`; tagged by `kind`).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum MatteSource {
    /// A matte file (`--matte`).
    File {
        /// The file.
        path: String,
        /// Its size, pixels.
        width: usize,
        /// Its size, pixels.
        height: usize,
    },
    /// A matte embedded in the photo (a HEIF portrait matte).
    Embedded {
        /// The photo.
        path: String,
        /// Where in it (container "heif", aux type, item, size, bits).
        #[serde(flatten)]
        info: Box<crate::io::heif_depth::MatteInfo>,
    },
}

impl MatteSource {
    /// One line for people (`-v`).
    pub fn describe(&self) -> String {
        match self {
            MatteSource::File { path, width, height } => format!("file {path} ({width}x{height})"),
            MatteSource::Embedded { path, info } => format!("embedded in {path}: {}", info.describe()),
        }
    }
}

impl DepthSource {
    /// One line for people (`-v`).
    pub fn describe(&self) -> String {
        match self {
            DepthSource::File { path, width, height, bit_depth } => format!("file {path} ({width}x{height}, {bit_depth}-bit)"),
            DepthSource::Embedded { path, info } => format!("embedded in {path}: {}", info.describe()),
            DepthSource::Model { model, preset } => format!("model {model} (preset {preset})"),
        }
    }
}

/// One frame of a focus pull ([`crate::focus_pull`]).
#[derive(Clone, Debug, Serialize)]
pub struct FrameReport {
    /// The written file.
    pub output: String,
    /// The frame's focus (normalized disparity).
    pub focus: f32,
    /// The frame's blur K.
    pub blur: f32,
    /// Render and write, milliseconds.
    pub ms: f64,
}

/// Machine-readable summary of a run (`--json`).
#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    /// Every stage, in order, ran or skipped.
    pub stages: Vec<StageReport>,
    /// The parameters the render actually used.
    pub params: UsedParams,
    /// What the user should know (filled depth, clamped focus, long renders...).
    pub warnings: Vec<String>,
    /// Where the scene's depth came from (set by [`crate::job::run`] for a photo; absent for
    /// given layers).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub depth_source: Option<DepthSource>,
    /// Where the scene's matte came from, when it has one (set by [`crate::job::run`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub matte_source: Option<MatteSource>,
    /// The written file (set by [`crate::job::run`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub output: Option<String>,
    /// A focus pull's frames, in order (set by [`crate::job::run`]; empty otherwise).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub frames: Vec<FrameReport>,
    /// Wall-clock time of the whole run, milliseconds.
    pub total_ms: f64,
}

impl Report {
    pub(crate) fn ran(&mut self, name: &'static str, t: Instant, detail: Option<serde_json::Value>) {
        self.stages.push(StageReport::ran(name, ms_since(t), detail));
    }
    pub(crate) fn skipped(&mut self, name: &'static str, reason: impl Into<String>) {
        self.stages.push(StageReport::skipped(name, reason));
    }
}
