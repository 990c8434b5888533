//! Depth estimation with a model (MiDaS, Depth-Anything-V2...), used when no depth map is
//! given: the model's relative disparity, min-max normalized, becomes the scene's normalized
//! disparity (so `--focus-depth` is not available: there is no metric depth).

use super::depth::{DepthKind, Disparity, normalize};
use crate::error::Result;
use crate::image::Image;
use crate::onnx::{self, ModelKind, ModelSpec, OnnxConfig, OnnxReport};
use crate::timing::ms_since;

/// Predicts the normalized disparity of `rgb` (linear RGB).
pub fn estimate_disparity(rgb: &Image, spec: &ModelSpec, cfg: &OnnxConfig) -> Result<(Disparity, OnnxReport)> {
    let mut model = onnx::load(spec, ModelKind::Depth, cfg)?;
    let t = std::time::Instant::now();
    let input = onnx::to_model_rgb(rgb);
    model.report.pre_ms += ms_since(t);
    let raw = model.predict(&input, 1)?;
    let t = std::time::Instant::now();
    let disparity = normalize(&raw, DepthKind::Disparity, &model.path)?;
    model.report.post_ms += ms_since(t);
    Ok((disparity, model.report))
}

/// The ways to give a photo depth, named by every "no depth" message (the library's names:
/// `job.depth` and `onnx.model_dir` read as `--depth` and `--model-dir` on the command line).
pub const THREE_WAYS: &str = "three ways forward: (1) a depth file (job.depth DEPTH: EXR, 16-bit PNG/TIFF, float TIFF or NPY); \
     (2) a photo that embeds its depth map (a portrait-mode JPEG with Google Dynamic Depth or GDepth XMP, or a HEIC with a depth image; `drbokeh inspect PHOTO` shows what a photo holds); \
     (3) a depth model ([depth.onnx] model = \"midas_small.onnx\", preset = \"midas-small\" in the config, or a model folder (onnx.model_dir) holding depth_anything_v2.onnx)";

/// The disparity of a photo given without a depth map and without an embedded one: the
/// `[depth.onnx]` model's, or the default depth preset's file in `onnx.model_dir`. With
/// neither, a usage error that says `why_no_embedded` (why the photo's own depth is not used)
/// and names the three ways forward ([`THREE_WAYS`]).
pub fn estimate_without_depth_map(
    rgb: &Image,
    spec: &ModelSpec,
    cfg: &OnnxConfig,
    why_no_embedded: &str,
) -> Result<(Disparity, OnnxReport)> {
    if !spec.is_configured() {
        match &cfg.model_dir {
            None => {
                return Err(crate::error::Error::usage(format!(
                    "job.depth is required: no depth file is given, {why_no_embedded}, and no depth model is configured; {THREE_WAYS}"
                )));
            }
            Some(dir) => {
                let (path, _) = crate::onnx::binding::resolve(spec, ModelKind::Depth, cfg)?;
                if !path.is_file() {
                    return Err(crate::error::Error::usage(format!(
                        "job.depth is required: no depth file is given, {why_no_embedded}, and the model folder {} has no {}; {THREE_WAYS}",
                        dir.display(),
                        path.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default()
                    )));
                }
            }
        }
    }
    estimate_disparity(rgb, spec, cfg)
}
