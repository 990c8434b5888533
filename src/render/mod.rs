//! The renderer: lens model, per-layer kernels and front-to-back compositing.
//!
//! `lens` holds the model's terms (written once), `aperture` the window's taps, `exact` the
//! literal kernel, `composite` eq. 2. [`render`] is the entry point.

pub mod aperture;
pub mod backward;
pub mod chromatic;
pub mod composite;
pub mod exact;
pub mod fast;
pub mod layer;
pub mod lens;
pub mod raw;
pub mod splat;

use crate::error::{Error, Result};
use crate::image::{Image, ImageRef};
pub use aperture::{Aperture, ShapeSpec};
pub use backward::{Gradients, Smoothing, SpanGradients, SpanTape, Tape, render_differentiable, vjp};
pub use layer::Layer;
pub use lens::Profile;
use rayon::prelude::*;
use std::borrow::Borrow;

/// Which per-layer kernel runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kernel {
    /// The official formula, tap by tap (the oracle).
    Exact,
    /// The same model at near-constant cost per pixel.
    Fast {
        /// 1 (fastest) … 8 (converges to the exact kernel).
        quality: u32,
    },
}

impl Kernel {
    /// The kernel's name as the CLI and reports spell it.
    pub fn name(&self) -> &'static str {
        match self {
            Kernel::Exact => "exact",
            Kernel::Fast { .. } => "fast",
        }
    }
}

/// Where a layer sits in the stack, for the physical profile's visibility.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Something is behind it: its visibility is its coverage, and where a blurred edge
    /// thins out, the layers behind show through.
    Front,
    /// The last layer: nothing behind it to reveal. Where it is opaque, a coverage deficit
    /// (a blurred near part of it meeting a sharp far part, whose hidden content the layer
    /// does not have) is filled with the mean colour that reaches the pixel, not with black.
    Backdrop,
}

impl Role {
    /// The role of layer `n` (0-based, front first) of `count`.
    pub fn of(n: usize, count: usize) -> Role {
        if n + 1 == count { Role::Backdrop } else { Role::Front }
    }
}

/// Lens and model parameters of one render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderSettings {
    /// Blur strength K: CoC radius in pixels per unit of relative disparity.
    pub blur: f32,
    /// Normalized disparity of the focal plane.
    pub focus: f32,
    /// Odd side of the square lens window, in pixels.
    pub lens: usize,
    /// `false` gives the classical scatter baseline (O ≡ 1; in the physical profile, one
    /// depth group per layer).
    pub occlusion: bool,
    /// Which calibration of the lens terms (see [`lens::Profile`]).
    pub profile: lens::Profile,
    /// The aperture's shape (see [`aperture::shape`]); anything but the disc needs the
    /// physical profile.
    pub aperture: aperture::Aperture,
}

/// A layer's raw render: per pixel `[ΣR, ΣG, ΣB, W, o]` (weighted colour sums, total weight,
/// non-focal visibility), the same channels as the official renderer's output, plus the
/// per-channel range `[min, max]` of the layer's visible colours (every rendered colour is a
/// weighted mean of them).
#[derive(Clone, Debug, PartialEq)]
pub struct RawLayer {
    image: Image,
    range: [[f32; 2]; 3],
}

impl RawLayer {
    /// Wraps a kernel's raw output (`width * height * 5` values) for `layer`, whose colour
    /// range it records. Panics if `data` has another length (a kernel bug).
    pub fn new(width: usize, height: usize, data: Vec<f32>, layer: &Layer) -> Self {
        RawLayer { image: Image::from_vec(width, height, raw::CHANNELS, data).expect("raw layer size"), range: layer.colour_range() }
    }
    /// Width, pixels.
    pub fn width(&self) -> usize {
        self.image.width
    }
    /// Height, pixels.
    pub fn height(&self) -> usize {
        self.image.height
    }
    /// The raw `[ΣR, ΣG, ΣB, W, o]` of pixel `i` (row-major index).
    #[inline]
    pub fn pixel(&self, i: usize) -> &[f32] {
        &self.image.data[i * raw::CHANNELS..(i + 1) * raw::CHANNELS]
    }
    /// The raw layer as a 5-channel image.
    pub fn image(&self) -> &Image {
        &self.image
    }
    /// Per-channel `[min, max]` of the layer's visible colours.
    pub fn colour_range(&self) -> [[f32; 2]; 3] {
        self.range
    }
}

/// Smallest scatter radius over a layer's visible pixels (alpha > 0); 1.0 if none.
pub fn min_visible_radius(img: ImageRef<'_>, sigma: &[f32]) -> f32 {
    let m = sigma
        .iter()
        .zip(img.data.chunks_exact(layer::CHANNELS))
        .filter(|(_, px)| px[layer::A] > 0.0)
        .map(|(&s, _)| s)
        .fold(f32::INFINITY, f32::min);
    if m.is_finite() { m } else { 1.0 }
}

/// Largest scatter radius `|D - focus|·K + 1` over the pixels a layer actually shows
/// (alpha > 0), over all layers. 1.0 for an all-transparent scene. O(layers): the radius
/// grows with `|D - focus|`, so it is the larger of the visible disparity range's ends'
/// ([`Layer::visible_disparity`]), the same value as the largest over the pixels.
pub fn max_scatter_radius(layers: &[Layer], blur: f32, focus: f32) -> f32 {
    layers
        .iter()
        .filter_map(Layer::visible_disparity)
        .map(|[lo, hi]| lens::scatter_radius(lo - focus, blur).max(lens::scatter_radius(hi - focus, blur)))
        .fold(1.0, f32::max)
}

/// The lens window the scene needs: half-size `ceil(σ_max) + 2`, so every tap whose soft step
/// is above ~0.5% of its plateau is inside, capped at the image's larger side (beyond that
/// the window only reads replicated border pixels). Always odd.
pub fn auto_lens(layers: &[Layer], blur: f32, focus: f32) -> usize {
    let (w, h) = (layers[0].width(), layers[0].height());
    let sigma = max_scatter_radius(layers, blur, focus);
    let p = (sigma.ceil() as f64 + 2.0).min(w.max(h) as f64).max(1.0) as usize;
    2 * p + 1
}

/// Checks that the layers agree in size and that the settings are usable.
pub fn validate<'a, L: Borrow<Layer<'a>>>(layers: &[L], s: &RenderSettings) -> Result<()> {
    let Some(first) = layers.first().map(Borrow::borrow) else {
        return Err(Error::usage("nothing to render: no layers"));
    };
    for (n, l) in layers.iter().map(Borrow::borrow).enumerate() {
        if (l.width(), l.height()) != (first.width(), first.height()) {
            return Err(Error::usage(format!(
                "layer {} is {}x{} but layer 1 is {}x{}: all layers must have the same size",
                n + 1,
                l.width(),
                l.height(),
                first.width(),
                first.height()
            )));
        }
    }
    check_blur("render.blur", s.blur)?;
    check_focus("render.focus", s.focus)?;
    check_lens("render.lens", s.lens)?;
    let max = max_lens(first.width(), first.height());
    if s.lens > max {
        return Err(Error::usage(format!(
            "render.lens {} is wider than a {}x{} image can use (at most {max}: twice the diagonal; the window would only read replicated border pixels)",
            s.lens,
            first.width(),
            first.height()
        )));
    }
    if s.profile == Profile::Official && !s.aperture.is_disc() {
        return Err(Error::usage(format!(
            "aperture {}: the official profile renders the disc only (its soft-step footprint is radial); use the physical profile",
            s.aperture.label()
        )));
    }
    Ok(())
}

/// The one rule for a blur strength K (pixels of CoC radius per unit of disparity): a finite
/// number >= 0 (0 renders everything in focus). Returns `k`; the usage error names `key`, the
/// parameter or config key the value came from (`render.blur`).
pub fn check_blur(key: &str, k: f32) -> Result<f32> {
    if k.is_finite() && k >= 0.0 { Ok(k) } else { Err(Error::usage(format!("{key} must be a finite number >= 0, got {k}"))) }
}

/// The one rule for a focal plane given as normalized disparity: a finite number (values
/// outside [0, 1] are usable; the pipeline clamps them with a warning). Returns `f`; the usage
/// error names `key` (`render.focus`).
pub fn check_focus(key: &str, f: f32) -> Result<f32> {
    if f.is_finite() { Ok(f) } else { Err(Error::usage(format!("{key} must be a finite number, got {f}"))) }
}

/// A focal plane given as normalized disparity, clamped to the scene's disparity range [0, 1],
/// with the warning that says so (`render` and `dfd` alike); `key` names the parameter
/// (`render.focus`).
pub fn focus_in_range(key: &str, f: f32) -> (f32, Option<String>) {
    if (0.0..=1.0).contains(&f) {
        return (f, None);
    }
    let c = f.clamp(0.0, 1.0);
    (c, Some(format!("{key} {f} is outside [0, 1] (the scene's disparity range); clamped to {c}")))
}

/// The one rule for a lens window side regardless of the image (pixels): odd, hence >= 1 (the
/// window is centred on its pixel). [`validate`] also bounds it by the image ([`max_lens`]).
/// Returns `lens`; the usage error names `key` (`render.lens`).
pub fn check_lens(key: &str, lens: usize) -> Result<usize> {
    if !lens.is_multiple_of(2) { Ok(lens) } else { Err(Error::usage(format!("{key} must be odd and >= 1, got {lens}"))) }
}

/// The widest lens window that can matter for a `w × h` image: side `2·⌈diagonal⌉ + 1`, so
/// every pixel sees every other one. Wider windows only add replicated border pixels and
/// cost memory and time quadratically (a lens of 100001 tried to list 8·10⁹ taps).
pub fn max_lens(w: usize, h: usize) -> usize {
    2 * ((w * w + h * h) as f64).sqrt().ceil() as usize + 1
}

/// Estimated seconds of an exact-kernel render of `layers` layers of `pixels` pixels with a
/// window of side `lens` on `threads` threads: ~7·10⁷ taps per second per thread (measured:
/// 1 MP, CoC 60, lens 125, two layers, 178.6 s on this project's 2-core machine).
pub fn exact_seconds(pixels: u64, lens: usize, layers: usize, threads: usize) -> f64 {
    const TAPS_PER_SECOND_PER_THREAD: f64 = 7e7;
    pixels as f64 * aperture::disk_tap_count(lens) as f64 * layers as f64 / (TAPS_PER_SECOND_PER_THREAD * threads.max(1) as f64)
}

/// Renders each layer with `kernel` and composites them front to back. Returns linear RGB.
pub fn render(layers: &[Layer], s: &RenderSettings, kernel: Kernel) -> Result<Image> {
    let refs: Vec<&Layer> = layers.iter().collect();
    render_with_stats(&refs, s, kernel).map(|(img, _)| img)
}

/// [`render`], plus what the fast kernel did for each layer (None for the exact kernel).
///
/// Layers are rendered one after another straight into a streaming compositor (see
/// [`composite::over`]): besides the layers and the 12-byte RGB result, the fast kernel
/// holds a 4-byte transmittance and a 4-byte scatter radius per pixel plus its coarse grids,
/// never a whole raw layer.
///
/// With chromatic aberration (`s.aperture.channel_scales()`) the stack is rendered once per
/// colour channel ([`chromatic::per_channel`]); the stats are the green (unscaled) pass's.
pub fn render_with_stats(layers: &[&Layer], s: &RenderSettings, kernel: Kernel) -> Result<(Image, Vec<Option<fast::FastStats>>)> {
    validate(layers, s)?;
    let ranges: Vec<[[f32; 2]; 3]> = layers.iter().map(|l| l.colour_range()).collect();
    let peak = ranges.iter().flatten().flatten().fold(0f32, |m, v| m.max(v.abs()));
    if peak > SAFE_COLOUR {
        return render_scaled(layers, s, kernel, peak);
    }
    let Some(scales) = s.aperture.channel_scales() else { return render_pass(layers, &ranges, s, kernel) };
    let mut green = Vec::new();
    let [image] = chromatic::per_channel(scales, |scale, c| {
        let sc = RenderSettings { blur: s.blur * scale, aperture: s.aperture.achromatic(), ..*s };
        let (image, stats) = render_pass(layers, &ranges, &sc, kernel)?;
        if c == 1 {
            green = stats;
        }
        Ok([image])
    })?;
    Ok((image, green))
}

/// Largest colour magnitude the kernels sum as given: the render is linear in colour, and
/// larger ones (up to `f32::MAX`, which overflowed the official profile's fast sums) are
/// rendered scaled down by a power of two ([`render_scaled`]). 1e30 leaves the sums a factor
/// of 3e8 of headroom (a window of 801² taps is 6.4e5).
pub const SAFE_COLOUR: f32 = 1e30;

/// [`render_with_stats`] of layers whose colours reach `peak` > [`SAFE_COLOUR`]: the colours
/// scaled by 2^-k below it (exact but for values 2^-k-fold below the smallest normal, which no
/// pixel of such a render shows), rendered, and the result scaled back, held within
/// `±f32::MAX` (a blur of colours at `f32::MAX` can round above it). Copies the layers.
fn render_scaled(layers: &[&Layer], s: &RenderSettings, kernel: Kernel, peak: f32) -> Result<(Image, Vec<Option<fast::FastStats>>)> {
    let k = (peak / SAFE_COLOUR).log2().ceil() as i32;
    let down = 2f32.powi(-k);
    let scaled = layers
        .iter()
        .map(|l| {
            let mut image = l.image().to_image();
            image.data.par_chunks_exact_mut(layer::CHANNELS).for_each(|px| px[..3].iter_mut().for_each(|c| *c *= down));
            Layer::new(image, "a layer scaled into the renderer's range")
        })
        .collect::<Result<Vec<_>>>()?;
    let (mut out, stats) = render_with_stats(&scaled.iter().collect::<Vec<_>>(), s, kernel)?;
    let up = 2f32.powi(k);
    out.data.par_iter_mut().for_each(|v| *v = (*v * up).clamp(-f32::MAX, f32::MAX));
    Ok((out, stats))
}

/// One achromatic pass of [`render_with_stats`] (the caller has validated), with each layer's
/// [`Layer::colour_range`].
fn render_pass(
    layers: &[&Layer],
    ranges: &[[[f32; 2]; 3]],
    s: &RenderSettings,
    kernel: Kernel,
) -> Result<(Image, Vec<Option<fast::FastStats>>)> {
    let (w, h) = (layers[0].width(), layers[0].height());
    let mut acc = composite::accumulator(w, h);
    let mut stats = Vec::with_capacity(layers.len());
    let taps = if kernel == Kernel::Exact { aperture::disk_taps(s.lens) } else { Vec::new() };
    for (n, (l, range)) in layers.iter().zip(ranges).enumerate() {
        let over = |raw: &raw::Pixel, px: &mut [f32]| composite::over(raw, range, px);
        match kernel {
            Kernel::Exact => {
                let raw = exact::scatter_layer(l, s, &taps, Role::of(n, layers.len()));
                acc.par_chunks_exact_mut(composite::ACC_CHANNELS)
                    .enumerate()
                    .for_each(|(i, px)| over(raw.pixel(i).try_into().expect("raw pixel"), px));
                stats.push(None);
            }
            Kernel::Fast { quality } => {
                let st = fast::scatter_layer_into(
                    l,
                    s,
                    fast::FastParams::from_quality(quality),
                    Role::of(n, layers.len()),
                    &mut acc,
                    composite::ACC_CHANNELS,
                    &over,
                );
                stats.push(Some(st));
            }
        }
    }
    let out = composite::finish(w, h, acc);
    // Finite layers and settings give finite output (see DESIGN.md); anything else is a
    // kernel bug, reported as such instead of being written as a wrong image.
    if !out.all_finite() {
        return Err(Error::Internal(format!(
            "the {} kernel produced non-finite pixels (blur {}, focus {}, lens {}); please report this",
            kernel.name(),
            s.blur,
            s.focus,
            s.lens
        )));
    }
    Ok((out, stats))
}

/// The per-layer raw renders, front first (stored whole: for tests against the official raws
/// and for tools that inspect them; [`render`] streams instead). A raw layer has one weight
/// per pixel, so chromatic aberration is left out: this is the green channel's render.
pub fn render_raw(layers: &[Layer], s: &RenderSettings, kernel: Kernel) -> Vec<RawLayer> {
    let s = &RenderSettings { aperture: s.aperture.achromatic(), ..*s };
    let taps = if kernel == Kernel::Exact { aperture::disk_taps(s.lens) } else { Vec::new() };
    layers
        .iter()
        .enumerate()
        .map(|(n, l)| match kernel {
            Kernel::Exact => exact::scatter_layer(l, s, &taps, Role::of(n, layers.len())),
            Kernel::Fast { quality } => fast::scatter_layer(l, s, fast::FastParams::from_quality(quality), Role::of(n, layers.len())).0,
        })
        .collect()
}

/// Front-to-back "over" composite of the layers' own colours, with no blur: what the renderer
/// would show if nothing were out of focus.
pub fn alpha_composite(layers: &[Layer]) -> Image {
    let (w, h) = (layers[0].width(), layers[0].height());
    let mut out = Image::new(w, h, 3);
    for (i, px) in out.data.chunks_exact_mut(3).enumerate() {
        let mut t = 1f32;
        for l in layers {
            let src = &l.image().data[i * layer::CHANNELS..(i + 1) * layer::CHANNELS];
            for c in 0..3 {
                px[c] += t * src[layer::A] * src[c];
            }
            t *= 1.0 - src[layer::A];
        }
    }
    out
}
