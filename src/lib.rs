//! drbokeh: occlusion-aware lens blur (Dr.Bokeh) from one photo and its depth.
//!
//! Data flow (see DESIGN.md): `io` reads image, depth and matte; `stages` build the layered
//! scene (segment → fill depth → inpaint → layers); `render` scatters each layer through the
//! lens model and composites front to back; `pipeline` ties it together for the CLI and for
//! library users.

#![warn(missing_docs)]

#[cfg(feature = "ndarray")]
pub mod array;
pub mod batch;
pub mod bench;
pub mod color;
pub mod config;
pub mod cpu;
pub mod diff;
pub mod error;
pub mod focus_pull;
pub mod image;
pub mod io;
pub mod job;
pub mod onnx;
pub mod pipeline;
pub mod plot;
pub mod refocus;
pub mod render;
pub mod report;
pub mod resources;
pub mod stages;
pub mod timing;
pub mod view;

pub use color::PhotoEncoding;
pub use config::Config;
pub use error::{Error, Result};
pub use image::{Image, ImageRef};
pub use pipeline::{Focus, Outcome, Pipeline, Scene};
