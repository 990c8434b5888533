//! The classical stages that turn image + depth (+ matte) into layers, in data-flow order:
//! `light_recovery` (the light of clipped highlights, integer photos) → `depth` (normalize, focus) → `segment` (then `matting`:
//! a depth split's or a model's outline moved onto the photo's edges) → `depth_edges` (how far the depth map's edges ramp
//! past the matte's) → `fill_depth` → `background` (inpaint, with the `contamination` and
//! `highlights` rules) → `foreground` (colour at soft edges) → layers; with `--layers`, `slices`
//! cuts the background at gaps of its depth and the same stages peel each slice in turn.
//! `work_box` is the part of the frame one peel can touch (the pipeline runs the peel there).
//! `inpaint` is the Telea algorithm the fills use (`patchmatch` the optional exemplar fill of
//! the colour); `mask` holds shared mask helpers.
//! `*_onnx` are the model-based alternatives (see `crate::onnx`), behind the same interfaces.

pub mod background;
pub mod camera_psf;
pub mod closed_form;
pub mod contamination;
pub mod depth;
pub mod depth_edges;
pub mod depth_onnx;
pub mod fill_depth;
pub mod foreground;
pub mod highlight_completion;
pub mod highlights;
pub mod highlights_onnx;
pub mod inpaint;
pub mod inpaint_onnx;
pub mod layer_count;
pub mod light_recovery;
pub mod mask;
pub mod matting;
pub mod patchmatch;
pub mod segment;
pub mod segment_onnx;
pub mod slices;
pub mod work_box;
