//! Pre- and post-processing around a model: resizing, letterboxing, value scaling, mean/std
//! normalization, layout and colour order on the way in; layout, activation, value range,
//! min-max normalization, un-letterboxing and resizing back on the way out.
//!
//! All functions are pure and public so that tests can compute the expected result of a stub
//! model independently of the session.

use super::contract::{Activation, ColorOrder, Contract, Layout, ResizeMode, SizeSpec, ValueScale};
use crate::error::{Error, Result};
use crate::image::Image;
use rayon::prelude::*;
use std::path::Path;

/// Where the image sits in the model's input canvas.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Geometry {
    /// Size of the image fed in (before resizing).
    pub src_w: usize,
    /// Height of the image fed in (before resizing).
    pub src_h: usize,
    /// Model input size.
    pub model_w: usize,
    /// Model input height.
    pub model_h: usize,
    /// The rectangle of the canvas holding the resized image (the rest is padding).
    pub x0: usize,
    /// Top row of the image's rectangle in the canvas.
    pub y0: usize,
    /// Width of the image's rectangle in the canvas (its resized width).
    pub w: usize,
    /// Height of the image's rectangle in the canvas (its resized height).
    pub h: usize,
}

fn round_to_multiple(v: f64, m: usize, max_side: Option<usize>) -> usize {
    let mut r = ((v / m as f64).round() as usize).max(1) * m;
    if let Some(ms) = max_side {
        while r > ms && r > m {
            r -= m;
        }
    }
    r
}

/// Plans the model input size and the image's place in it.
pub fn plan(size: SizeSpec, resize: ResizeMode, src_w: usize, src_h: usize) -> Geometry {
    let (sw, sh) = (src_w.max(1) as f64, src_h.max(1) as f64);
    let full = |mw: usize, mh: usize| Geometry { src_w, src_h, model_w: mw, model_h: mh, x0: 0, y0: 0, w: mw, h: mh };
    let boxed = |mw: usize, mh: usize, w: usize, h: usize| Geometry {
        src_w,
        src_h,
        model_w: mw,
        model_h: mh,
        x0: (mw - w) / 2,
        y0: (mh - h) / 2,
        w,
        h,
    };
    match (size, resize) {
        (SizeSpec::Fixed { h, w }, ResizeMode::Stretch) => full(w, h),
        (SizeSpec::Fixed { h, w }, ResizeMode::Letterbox) => {
            let s = (w as f64 / sw).min(h as f64 / sh);
            let cw = ((sw * s).round() as usize).clamp(1, w);
            let ch = ((sh * s).round() as usize).clamp(1, h);
            boxed(w, h, cw, ch)
        }
        (SizeSpec::Dynamic { multiple, max_side }, mode) => {
            let s = max_side.map_or(1.0, |m| (m as f64 / sw.max(sh)).min(1.0));
            match mode {
                ResizeMode::Stretch => full(round_to_multiple(sw * s, multiple, max_side), round_to_multiple(sh * s, multiple, max_side)),
                ResizeMode::Letterbox => {
                    let cw = ((sw * s).round() as usize).max(1);
                    let ch = ((sh * s).round() as usize).max(1);
                    let up = |v: usize| v.div_ceil(multiple) * multiple;
                    boxed(up(cw), up(ch), cw, ch)
                }
            }
        }
    }
}

/// Tensor shape of a `channels`-channel input for the geometry and layout.
pub fn input_shape(g: &Geometry, layout: Layout, channels: usize) -> Vec<i64> {
    let (c, h, w) = (channels as i64, g.model_h as i64, g.model_w as i64);
    match layout {
        Layout::Nchw => vec![1, c, h, w],
        Layout::Nhwc => vec![1, h, w, c],
    }
}

/// Writes the canvas (model_h x model_w x C, interleaved, already normalized) as a tensor.
fn to_layout(canvas: &[f32], g: &Geometry, channels: usize, layout: Layout) -> Vec<f32> {
    match layout {
        Layout::Nhwc => canvas.to_vec(),
        Layout::Nchw => {
            let n = g.model_w * g.model_h;
            let mut out = vec![0f32; n * channels];
            for (i, px) in canvas.chunks_exact(channels).enumerate() {
                for (ch, &v) in px.iter().enumerate() {
                    out[ch * n + i] = v;
                }
            }
            out
        }
    }
}

/// The image input tensor: `img` (three channels, RGB, values in [0, 1], i.e. sRGB-encoded
/// colours) resized into the geometry's content rectangle, scaled, normalized with mean/std,
/// reordered to the contract's colour order and layout. Padding is 0 after normalization.
pub fn image_tensor(img: &Image, c: &Contract, g: &Geometry) -> Vec<f32> {
    assert_eq!(img.channels, 3, "image_tensor: RGB input");
    let r = img.resized(g.w, g.h);
    let k = match c.scale {
        ValueScale::Unit => 1.0f32,
        ValueScale::Byte => 255.0,
    };
    let order: [usize; 3] = match c.color {
        ColorOrder::Rgb => [0, 1, 2],
        ColorOrder::Bgr => [2, 1, 0],
    };
    let mut canvas = vec![0f32; g.model_w * g.model_h * 3];
    canvas.par_chunks_mut(g.model_w * 3).enumerate().skip(g.y0).take(g.h).for_each(|(y, row)| {
        let src = &r.data[(y - g.y0) * g.w * 3..(y - g.y0 + 1) * g.w * 3];
        for x in 0..g.w {
            let dst = &mut row[(g.x0 + x) * 3..(g.x0 + x) * 3 + 3];
            for (slot, &col) in order.iter().enumerate() {
                dst[slot] = (src[x * 3 + col] * k - c.mean[col]) / c.std[col];
            }
        }
    });
    to_layout(&canvas, g, 3, c.layout)
}

/// The mask input tensor: `mask` (one channel) resized into the content rectangle and made
/// binary (any coverage counts as masked, so no foreground colour is used as context).
pub fn mask_tensor(mask: &Image, layout: Layout, g: &Geometry) -> Vec<f32> {
    assert_eq!(mask.channels, 1, "mask_tensor: one channel");
    let r = mask.resized(g.w, g.h);
    let mut canvas = vec![0f32; g.model_w * g.model_h];
    for y in 0..g.h {
        for x in 0..g.w {
            canvas[(g.y0 + y) * g.model_w + g.x0 + x] = if r.data[y * g.w + x] > 1e-3 { 1.0 } else { 0.0 };
        }
    }
    to_layout(&canvas, g, 1, layout)
}

fn sigmoid(v: f32) -> f32 {
    if v >= 0.0 {
        1.0 / (1.0 + (-v).exp())
    } else {
        let e = v.exp();
        e / (1.0 + e)
    }
}

/// Turns a model output into an image of `channels` channels at the geometry's source size:
/// picks the layout (rank 4: the contract's; rank 3: [1, H, W]; rank 2: [H, W]), applies the
/// activation, maps `output_range` to [0, 1], puts a BGR model's colour output back in RGB
/// order, drops the padding, min-max normalizes when the contract says so, and resizes back. An output smaller or larger than the input canvas is
/// scaled with it. `model` names the file in errors.
pub fn decode_output(shape: &[i64], data: &[f32], c: &Contract, g: &Geometry, channels: usize, model: &Path) -> Result<Image> {
    let dims: Vec<usize> = shape.iter().map(|&d| d.max(0) as usize).collect();
    let (oc, oh, ow, nchw) = match dims.as_slice() {
        [1, a, b, d] => match c.layout {
            Layout::Nchw => (*a, *b, *d, true),
            Layout::Nhwc => (*d, *a, *b, false),
        },
        [1, h, w] => (1, *h, *w, true),
        [h, w] => (1, *h, *w, true),
        _ => {
            return Err(Error::input(
                model,
                format!("output has shape {shape:?}; expected [1, C, H, W], [1, H, W, C], [1, H, W] or [H, W]"),
            ));
        }
    };
    if oc < channels {
        return Err(Error::input(model, format!("output has {oc} channel(s) (shape {shape:?}), {channels} needed")));
    }
    if oh == 0 || ow == 0 || data.len() != oc * oh * ow {
        return Err(Error::input(model, format!("output shape {shape:?} does not match its {} values", data.len())));
    }
    // Content rectangle in output pixels.
    let sx = ow as f64 / g.model_w as f64;
    let sy = oh as f64 / g.model_h as f64;
    let x0 = ((g.x0 as f64 * sx).round() as usize).min(ow - 1);
    let y0 = ((g.y0 as f64 * sy).round() as usize).min(oh - 1);
    let cw = ((g.w as f64 * sx).round() as usize).clamp(1, ow - x0);
    let ch = ((g.h as f64 * sy).round() as usize).clamp(1, oh - y0);
    let [lo, hi] = c.output_range;
    let span = hi - lo;
    // A colour output is in the model's channel order (BGR models answer in BGR).
    let slot: Vec<usize> = if channels == 3 && c.color == ColorOrder::Bgr { vec![2, 1, 0] } else { (0..channels).collect() };
    let mut content = Image::new(cw, ch, channels);
    for y in 0..ch {
        for x in 0..cw {
            for (k, &dst) in slot.iter().enumerate() {
                let (yy, xx) = (y0 + y, x0 + x);
                let idx = if nchw { (k * oh + yy) * ow + xx } else { (yy * ow + xx) * oc + k };
                let v = match c.activation {
                    Activation::None => data[idx],
                    Activation::Sigmoid => sigmoid(data[idx]),
                    Activation::Exp => data[idx].exp(),
                };
                content.data[(y * cw + x) * channels + dst] = (v - lo) / span;
            }
        }
    }
    if c.minmax {
        let (mn, mx) = content.data.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        let d = mx - mn;
        if d > 1e-12 {
            content.map_inplace(|v| (v - mn) / d);
        } else {
            content.map_inplace(|_| 0.0);
        }
    }
    Ok(content.resized(g.src_w, g.src_h))
}
