//! The ONNX parts of `pipeline.toml`: the `[onnx]` runtime section and the per-stage model
//! sections (`[segment.onnx]`, `[inpaint.onnx]`, `[depth.onnx]`, `[highlights.onnx]`), all
//! optional.
//!
//! A stage's model is a preset (see [`super::contract::PRESETS`]) plus any overrides of its
//! contract; the model file is `model` (relative paths are taken in `onnx.model_dir` when set,
//! else in the working directory) or, when unset, the preset's file name in `onnx.model_dir`.

use super::contract::{Activation, ColorOrder, DepthFill, Layout, ModelKind, OutputRef, ResizeMode, ValueScale};
use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// `[onnx]`: where ONNX Runtime comes from and how sessions are built.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OnnxConfig {
    /// Path of `libonnxruntime.so` / `onnxruntime.dll` / `libonnxruntime.dylib`. Unset:
    /// `ORT_DYLIB_PATH`, then the project cache (`.venv/.../onnxruntime/capi/`), then
    /// well-known system locations.
    pub runtime: Option<PathBuf>,
    /// Folder holding the model files (`--model-dir`).
    pub model_dir: Option<PathBuf>,
    /// Intra-op threads of each session; 0 = ONNX Runtime's default (all physical cores).
    pub threads: usize,
    /// Execution providers to try in order ("cuda", "tensorrt", "coreml", "directml", "cpu").
    /// One that the runtime lacks or that fails to register is skipped with a warning; CPU is
    /// always the last resort.
    pub providers: Vec<String>,
}

impl Default for OnnxConfig {
    fn default() -> Self {
        OnnxConfig { runtime: None, model_dir: None, threads: 0, providers: vec!["cpu".into()] }
    }
}

/// A stage's model: preset + overrides. Every field is optional.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelSpec {
    /// The .onnx file.
    pub model: Option<PathBuf>,
    /// A preset name (e.g. "u2net", "lama", "midas-small"); unset: the stage's default preset.
    pub preset: Option<String>,
    /// Name of the image input; unset: the model's only input (matting, depth).
    pub input: Option<String>,
    /// Name of the mask input (inpainting).
    pub mask_input: Option<String>,
    /// Output name, or its index (0 = first output).
    pub output: Option<OutputRef>,
    /// Rank of the output tensor (2, 3 or 4); unset: the preset's.
    pub output_rank: Option<usize>,
    /// Input tensor layout: "nchw" or "nhwc"; unset: the preset's.
    pub layout: Option<Layout>,
    /// Channel order the model expects: "rgb" or "bgr"; unset: the preset's.
    pub color: Option<ColorOrder>,
    /// Fixed model input size [height, width].
    pub size: Option<[usize; 2]>,
    /// Dynamic input size: each side a multiple of this (replaces a fixed `size`).
    pub multiple: Option<usize>,
    /// Dynamic input size: longest side at most this many pixels (larger images are shrunk).
    pub max_side: Option<usize>,
    /// How the image is brought to the model size: "stretch" or "letterbox"; unset: the preset's.
    pub resize: Option<ResizeMode>,
    /// Input value scaling: "0-1" or "0-255".
    pub scale: Option<ValueScale>,
    /// Per-channel mean and std (RGB order, in the units of `scale`): x' = (x - mean) / std.
    pub mean: Option<[f32; 3]>,
    /// Per-channel standard deviation (RGB order, units of `scale`), non-zero; see `mean`.
    pub std: Option<[f32; 3]>,
    /// Activation applied to the raw output: "none", "sigmoid" or "exp" (log-radiance outputs).
    pub activation: Option<Activation>,
    /// The output's value range [lo, hi], mapped to [0, 1] (e.g. [0, 255]).
    pub output_range: Option<[f32; 2]>,
    /// Min-max normalize the output over the image (saliency maps, relative depth).
    pub minmax: Option<bool>,
    /// Inpainting with a fixed-size model: context around the mask's bounding box, as a
    /// fraction of the box's larger side (at least 16 px).
    pub context: Option<f32>,
    /// Inpainting: blend the model's result into the unmasked pixels up to this many pixels
    /// from the mask (a feathered seam); 0 pastes only the masked pixels.
    pub feather: Option<f32>,
    /// Inpainting: how the background disparity is filled ("telea" or "model").
    pub depth: Option<DepthFill>,
}

impl ModelSpec {
    /// True when a model is configured at all (a file or a preset).
    pub fn is_configured(&self) -> bool {
        self.model.is_some() || self.preset.is_some()
    }

    /// True when nothing is set (serialization skips such a section).
    pub fn is_default(&self) -> bool {
        *self == ModelSpec::default()
    }

    /// Checks the values the types cannot express; `key` is the config section (for messages).
    pub fn validate(&self, key: &str, kind: ModelKind) -> Result<()> {
        if let Some(p) = &self.preset {
            super::contract::preset(p).map_err(|m| Error::usage(format!("{key}.preset: {m}")))?;
        }
        if self.size.is_some() && self.multiple.is_some() {
            return Err(Error::usage(format!("{key}: set either `size` (fixed) or `multiple` (dynamic), not both")));
        }
        if let Some([h, w]) = self.size
            && (h == 0 || w == 0)
        {
            return Err(Error::usage(format!("{key}.size must be two positive numbers [height, width], got [{h}, {w}]")));
        }
        if self.multiple == Some(0) || self.max_side == Some(0) {
            return Err(Error::usage(format!("{key}.multiple and {key}.max_side must be >= 1")));
        }
        if let Some(r) = self.output_rank
            && !(2..=4).contains(&r)
        {
            return Err(Error::usage(format!("{key}.output_rank must be 2, 3 or 4, got {r}")));
        }
        if let Some(s) = self.std
            && s.iter().any(|v| !(v.is_finite() && *v != 0.0))
        {
            return Err(Error::usage(format!("{key}.std must be finite and non-zero, got {s:?}")));
        }
        if let Some(m) = self.mean
            && m.iter().any(|v| !v.is_finite())
        {
            return Err(Error::usage(format!("{key}.mean must be finite, got {m:?}")));
        }
        if let Some([lo, hi]) = self.output_range
            && !(lo.is_finite() && hi.is_finite() && hi > lo)
        {
            return Err(Error::usage(format!("{key}.output_range must be [lo, hi] with lo < hi, got [{lo}, {hi}]")));
        }
        for (name, v) in [("context", self.context), ("feather", self.feather)] {
            if let Some(v) = v {
                if kind != ModelKind::Inpaint {
                    return Err(Error::usage(format!("{key}.{name} applies to inpainting models only ([inpaint.onnx])")));
                }
                if !(v.is_finite() && v >= 0.0) {
                    return Err(Error::usage(format!("{key}.{name} must be a finite number >= 0, got {v}")));
                }
            }
        }
        if self.depth.is_some() && kind != ModelKind::Inpaint {
            return Err(Error::usage(format!("{key}.depth applies to inpainting models only ([inpaint.onnx])")));
        }
        if self.mask_input.is_some() && kind != ModelKind::Inpaint {
            return Err(Error::usage(format!("{key}.mask_input applies to inpainting models only ([inpaint.onnx])")));
        }
        Ok(())
    }
}

/// `[depth]`: the optional depth-estimation model, used when no depth map is given.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthConfig {
    /// The model (`[depth.onnx]`); used only when no depth map is given or embedded in the photo.
    pub onnx: ModelSpec,
}

impl OnnxConfig {
    /// Checks `providers` (known names) and `threads` without loading ONNX Runtime; errors name
    /// the `onnx.*` key.
    pub fn validate(&self) -> Result<()> {
        for p in &self.providers {
            if Provider::parse(p).is_none() {
                return Err(Error::usage(format!(
                    "onnx.providers: unknown execution provider \"{p}\"; known: {}",
                    Provider::NAMES.join(", ")
                )));
            }
        }
        if self.threads > 1024 {
            return Err(Error::usage(format!("onnx.threads must be 0 (default) .. 1024, got {}", self.threads)));
        }
        Ok(())
    }
}

/// An execution provider the config may ask for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Provider {
    /// ONNX Runtime's default CPU provider (always available).
    Cpu,
    /// NVIDIA CUDA.
    Cuda,
    /// NVIDIA TensorRT.
    TensorRt,
    /// Apple Core ML.
    CoreMl,
    /// Microsoft DirectML (also spelled "dml").
    DirectMl,
}

impl Provider {
    /// The names `onnx.providers` accepts, as error messages list them.
    pub const NAMES: &'static [&'static str] = &["cpu", "cuda", "tensorrt", "coreml", "directml"];

    /// The provider named `s` (case-insensitive; "dml" for DirectML); None if unknown.
    pub fn parse(s: &str) -> Option<Provider> {
        Some(match s.to_ascii_lowercase().as_str() {
            "cpu" => Provider::Cpu,
            "cuda" => Provider::Cuda,
            "tensorrt" => Provider::TensorRt,
            "coreml" => Provider::CoreMl,
            "directml" | "dml" => Provider::DirectMl,
            _ => return None,
        })
    }

    /// ONNX Runtime's name of the provider.
    pub fn ort_name(self) -> &'static str {
        match self {
            Provider::Cpu => "CPUExecutionProvider",
            Provider::Cuda => "CUDAExecutionProvider",
            Provider::TensorRt => "TensorrtExecutionProvider",
            Provider::CoreMl => "CoreMLExecutionProvider",
            Provider::DirectMl => "DmlExecutionProvider",
        }
    }
}
