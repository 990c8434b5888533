//! The classical stages that turn image + depth (+ matte) into layers, in data-flow order:
//! `depth` (normalize, focus) → `segment` → `fill_depth` → `background` (inpaint) → layers.
//! `inpaint` is the Telea algorithm both fills use; `mask` holds shared mask helpers.

pub mod background;
pub mod depth;
pub mod fill_depth;
pub mod inpaint;
pub mod mask;
pub mod segment;
