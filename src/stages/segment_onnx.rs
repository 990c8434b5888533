//! Segmentation with a saliency / matting model (U^2-Net, ISNet, BiRefNet, MODNet, MediaPipe
//! selfie...): the model's output, resized back to the image, is the foreground's soft matte.
//! Same outcome type as the classical sources ([`Segmentation`]); an empty or full matte
//! renders one layer.

use super::segment::{Segmentation, from_matte};
use crate::error::Result;
use crate::image::Image;
use crate::onnx::{self, ModelKind, ModelSpec, OnnxConfig, OnnxReport};
use crate::timing::ms_since;

/// The model's matte (one channel in [0, 1] at the image's size) and what the model run did.
pub fn predict_matte(rgb: &Image, spec: &ModelSpec, cfg: &OnnxConfig) -> Result<(Image, OnnxReport)> {
    let mut model = onnx::load(spec, ModelKind::Matte, cfg)?;
    let t = std::time::Instant::now();
    let input = onnx::to_model_rgb(rgb);
    model.report.pre_ms += ms_since(t);
    let mut matte = model.predict(&input, 1)?;
    matte.map_inplace(|a| a.clamp(0.0, 1.0));
    Ok((matte, model.report))
}

/// Segments `rgb` (linear RGB) with the configured model.
pub fn from_model(rgb: &Image, spec: &ModelSpec, cfg: &OnnxConfig) -> Result<(Segmentation, OnnxReport)> {
    let (matte, report) = predict_matte(rgb, spec, cfg)?;
    Ok((from_matte(&matte), report))
}
