//! Layers kept in memory and rendered at focus after focus ([`Refocuser`]): a focus sweep, a
//! focus pull's frames ([`crate::focus_pull`]), an app's focus control.

use crate::error::{Error, Result};
use crate::image::Image;
use crate::pipeline::{Focus, Pipeline};
use crate::render::Layer;
use crate::report::Report;

/// Ready-made layers kept in memory and rendered at one focus after another: a focus sweep,
/// or an app's focus control, reads or estimates the layers once. Each [`Refocuser::render`]
/// gives exactly what [`Pipeline::render_layers`] gives for the same layers and focus; the
/// layers are borrowed, never copied, and stay usable after an error.
///
/// ```
/// use drbokeh::{Config, Focus, Image, Pipeline, refocus::Refocuser, render::Layer};
/// // One 32x32 layer: a grey ramp, opaque, its disparity rising from 0 to 1 across.
/// let mut px = Vec::new();
/// for _y in 0..32 {
///     for x in 0..32 {
///         let v = x as f32 / 31.0;
///         px.extend_from_slice(&[v, v, v, 1.0, v]);
///     }
/// }
/// let layer = Layer::new(Image::from_vec(32, 32, 5, px).expect("32x32x5 values"), "ramp")?;
/// let refocuser = Refocuser::new(Pipeline::from_config(Config::default())?, vec![layer])?;
/// for focus in [0.0, 0.5, 1.0] {
///     let (image, _report) = refocuser.render(Focus::Disparity(focus))?;
///     assert_eq!((image.width, image.height, image.channels), (32, 32, 3));
/// }
/// # Ok::<(), drbokeh::Error>(())
/// ```
pub struct Refocuser {
    pipeline: Pipeline,
    layers: Vec<Layer<'static>>,
}

impl Refocuser {
    /// Keeps `layers` (front first, linear colours, all one size) for rendering with
    /// `pipeline`'s render settings (blur, kernel, quality, profile, occlusion, lens).
    pub fn new(pipeline: Pipeline, layers: Vec<Layer<'static>>) -> Result<Self> {
        let Some(first) = layers.first() else {
            return Err(Error::usage("no layers given"));
        };
        let size = (first.width(), first.height());
        if let Some(other) = layers.iter().find(|l| (l.width(), l.height()) != size) {
            return Err(Error::usage(format!("the layers differ in size: {}x{} and {}x{}", size.0, size.1, other.width(), other.height())));
        }
        Ok(Refocuser { pipeline, layers })
    }

    /// Renders the layers focused at `focus`: the linear RGB image and what ran.
    pub fn render(&self, focus: Focus) -> Result<(Image, Report)> {
        self.pipeline.refocus(&self.layers, focus, None)
    }

    /// [`Refocuser::render`] with the blur `blur` (K) instead of the configured one: equal to
    /// a pipeline configured with that blur (a focus pull's frames, [`crate::focus_pull`]).
    pub fn render_with_blur(&self, focus: Focus, blur: f32) -> Result<(Image, Report)> {
        self.pipeline.refocus(&self.layers, focus, Some(blur))
    }

    /// The layers, front first.
    pub fn layers(&self) -> &[Layer<'static>] {
        &self.layers
    }

    /// Gives the layers back.
    pub fn into_layers(self) -> Vec<Layer<'static>> {
        self.layers
    }
}
