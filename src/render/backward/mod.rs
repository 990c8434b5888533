//! The backward pass of the exact kernel: vector-Jacobian products of the render (layers →
//! composited linear RGB) with respect to every layer's colour, alpha and disparity and to the
//! focus and the blur strength K, for both profiles.
//!
//! What is differentiated:
//! - **official**: the exact kernel's function itself ([`crate::render::exact`]; a [`Tape`]'s
//!   image is [`crate::render::render`]'s). It is smooth in colour, alpha, disparity, focus and
//!   K except where the visibility box's half-size `trunc(σ/2)` steps (piecewise constant in
//!   disparity: its derivative there is taken as 0) and at `d = 0` (`|d|`, subgradient 0).
//! - **physical**: the exact kernel with its hard edges rounded by [`Smoothing`]: the disk's
//!   one-pixel ramp becomes a smoothstep `edge_width` wide (with the flux norm of that disk,
//!   so in-focus pixels keep their value), and the depth groups' fill `min(coverage, 1)` is
//!   rounded over `fill_width` of coverage (0: the hard fill, differentiated piecewise). The
//!   backdrop's `max(coverage, α)` and `|d|` at `d = 0` are differentiated piecewise.
//! - In both, the compositor's clamp of a layer colour to its colour range (which only
//!   removes rounding) is the identity, and a layer whose weight at a pixel is exactly 0 passes
//!   no gradient to its colour there (its transmittance still does).
//!
//! Gradients are summed in f64 and saturate at ±`f32::MAX` when returned: they are finite for
//! every finite input, including the official model's far window corners at lens 71, where
//! the official CUDA derivative of the soft step is inf/inf.
//!
//! Cost: [`Tape::record`] is one forward render that also keeps each layer's raw sums (and, in
//! the physical profile, three depth groups per pixel: 96 bytes); [`Tape::vjp`] is one more
//! pass over the taps per layer, scattering gradients to sources in parallel row bands (see
//! `benches/backward.rs` for the measured ratio to the forward).

mod accum;
mod official;
mod physical;
mod span;

use super::aperture::{self, Tap};
use super::layer::{self, Layer};
use super::lens::{self, Profile};
use super::{RawLayer, RenderSettings, Role, composite, exact, validate};
use crate::error::{Error, Result};
use crate::image::Image;
use accum::PixelGrad;
use rayon::prelude::*;
pub use span::{BIN_STEP, SpanGradients, SpanTape};

/// Widths of the physical profile's smooth edges in differentiable renders (the official
/// profile has none to round).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Smoothing {
    /// Width of the disk's smooth edge, pixels, > 0: the coverage goes from 1 to 0 as a
    /// smoothstep over `edge_width` centred on the CoC radius. 1 (the default) has the hard
    /// ramp's width, half-way point and area.
    pub edge_width: f32,
    /// How far in coverage, in [0, 0.5], the fill rule `min(coverage, 1)` of the in-layer depth
    /// groups is rounded ([`lens::fill_min`]; a fully covered pixel then lets `fill_width/4`
    /// through). 0 (the default) is the hard rule of the renderer, whose derivative jumps where
    /// the groups' coverage reaches 1 (inside a surface of one depth).
    pub fill_width: f32,
}

/// Checks a VJP's `cotangent`: linear RGB of the render's size `w`×`h`, every value finite
/// (a usage error otherwise: the caller's loss made it).
pub(crate) fn check_cotangent(cotangent: &Image, w: usize, h: usize) -> Result<()> {
    if (cotangent.width, cotangent.height, cotangent.channels) != (w, h, 3) {
        return Err(Error::usage(format!(
            "the cotangent is {}x{} with {} channels but the render is {w}x{h} RGB",
            cotangent.width, cotangent.height, cotangent.channels
        )));
    }
    if !cotangent.all_finite() {
        return Err(Error::usage("the cotangent has non-finite values"));
    }
    Ok(())
}

impl Default for Smoothing {
    fn default() -> Self {
        Smoothing { edge_width: 1.0, fill_width: 0.0 }
    }
}

impl Smoothing {
    /// Checks the widths: `edge_width` finite in (0, 16], `fill_width` in [0, 0.5]. The usage
    /// error names the field.
    pub fn validate(&self) -> Result<()> {
        if !(self.edge_width > 0.0 && self.edge_width <= 16.0) {
            return Err(Error::usage(format!("smoothing.edge_width must be in (0, 16] pixels, got {}", self.edge_width)));
        }
        if !(0.0..=0.5).contains(&self.fill_width) {
            return Err(Error::usage(format!("smoothing.fill_width must be in [0, 0.5], got {}", self.fill_width)));
        }
        Ok(())
    }
}

/// The gradients of a scalar loss `L` given `∂L/∂image` (see [`Tape::vjp`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Gradients {
    /// Per layer, front first, an image of the layer's shape: `∂L/∂` R, G, B, A, D of every
    /// pixel at the channels of [`layer::CHANNELS`] (D is the normalized disparity).
    pub layers: Vec<Image>,
    /// `∂L/∂focus`.
    pub focus: f32,
    /// `∂L/∂K` (`RenderSettings::blur`).
    pub blur: f32,
}

/// The cotangent of one raw layer pixel, what [`Tape::composite_backward`] hands each layer's
/// backward. Official: `[g_ΣR, g_ΣG, g_ΣB, g_W, g_o, e_R, e_G, e_B]`, where `e = g·T` is set
/// only where the layer has neither weight nor visibility (see [`official::backward`]).
/// Physical: `[g_P_r, g_P_g, g_P_b, g_A, g_α, 0, 0, 0]` of the filled `[P, A]`, `g_α` being
/// the backdrop's own-alpha share of its visibility.
type RawCot = [f64; 8];

/// What a layer's forward leaves for the backward.
enum Record {
    Official(RawLayer),
    Physical(physical::Record),
}

impl Record {
    fn raw(&self) -> &RawLayer {
        match self {
            Record::Official(raw) => raw,
            Record::Physical(rec) => &rec.raw,
        }
    }
}

/// A recorded differentiable render: the forward image and, per layer, the per-pixel sums its
/// backward needs (no per-tap tape). Record once, then take any number of [`Tape::vjp`]s.
///
/// ```
/// use drbokeh::Image;
/// use drbokeh::render::{Layer, Profile, RenderSettings, Smoothing, Tape};
/// // An 8×8 slanted gradient, opaque, disparity 0.3 … 0.7.
/// let mut px = Vec::new();
/// for i in 0..64 {
///     let v = i as f32 / 64.0;
///     px.extend_from_slice(&[v, 0.5, 1.0 - v, 1.0, 0.3 + 0.4 * v]);
/// }
/// let layers = [Layer::new(Image::from_vec(8, 8, 5, px).unwrap(), "example")?];
/// let s = RenderSettings { blur: 6.0, focus: 0.5, lens: 7, occlusion: true, profile: Profile::Physical, aperture: drbokeh::render::Aperture::DISC };
/// let tape = Tape::record(&layers, &s, Smoothing::default())?;
/// // L = sum of the red channel: its gradient with respect to the image is 1 on red.
/// let mut seed = Image::new(8, 8, 3);
/// seed.data.chunks_exact_mut(3).for_each(|px| px[0] = 1.0);
/// let g = tape.vjp(&seed)?;
/// assert_eq!((g.layers[0].width, g.layers[0].height, g.layers[0].channels), (8, 8, 5));
/// // Brightening red anywhere brightens the sum of red; green does not change it.
/// assert!(g.layers[0].data.chunks_exact(5).all(|d| d[0] > 0.0 && d[1] == 0.0));
/// assert!(g.focus.is_finite() && g.blur.is_finite());
/// # Ok::<(), drbokeh::Error>(())
/// ```
pub struct Tape<'a> {
    layers: &'a [Layer<'a>],
    settings: RenderSettings,
    smoothing: Smoothing,
    ray_test: bool,
    taps: Vec<Tap>,
    records: Vec<Record>,
    image: Image,
    /// With chromatic aberration, one achromatic tape per colour channel (K scaled by the
    /// channel's factor, see [`crate::render::chromatic`]); `records` is then empty.
    channels: Option<Box<[Tape<'a>; 3]>>,
}

impl<'a> Tape<'a> {
    /// Renders `layers` with the exact kernel (the physical profile with `smoothing`'s edges)
    /// and keeps what [`Tape::vjp`] needs. Same checks and errors as [`crate::render::render`].
    pub fn record(layers: &'a [Layer<'a>], s: &RenderSettings, smoothing: Smoothing) -> Result<Self> {
        Self::record_with(layers, s, smoothing, false)
    }

    /// [`Tape::record`] with, where `ray_test` is set, the geometric ray test of depth from
    /// defocus in the physical profile's depth groups: a source in a target's "behind" group
    /// counts only as far as the ray from the target to it passes the layer's own surface
    /// where it crosses the target's depth ([`lens::ray_crossing`], [`lens::ray_clear`]; the
    /// surface read bilinearly from the layer's disparity). That is the visibility of a 2.5D
    /// surface, which the groups' coverage fill alone only approximates: meant for opaque
    /// layers (a transparent pixel's disparity stops rays as an opaque one would). The VJP
    /// differentiates it (the crossing's position and the surface there included). Errors as
    /// [`Tape::record`]; a usage error if `ray_test` is asked of the official profile.
    pub fn record_with(layers: &'a [Layer<'a>], s: &RenderSettings, smoothing: Smoothing, ray_test: bool) -> Result<Self> {
        validate(layers, s)?;
        smoothing.validate()?;
        if ray_test && s.profile != Profile::Physical {
            return Err(Error::usage("the ray test is a term of the physical profile's depth groups: use the physical profile"));
        }
        if let Some(scales) = s.aperture.channel_scales() {
            let mut tapes = Vec::with_capacity(3);
            let [image] = super::chromatic::per_channel(scales, |scale, _| {
                let sc = RenderSettings { blur: s.blur * scale, aperture: s.aperture.achromatic(), ..*s };
                let tape = Self::record_with(layers, &sc, smoothing, ray_test)?;
                let image = tape.image.clone();
                tapes.push(tape);
                Ok([image])
            })?;
            let channels: Box<[Tape<'a>; 3]> = Box::new(tapes.try_into().map_err(|_| Error::Internal("three channel tapes".into()))?);
            return Ok(Tape {
                layers,
                settings: *s,
                smoothing,
                ray_test,
                taps: Vec::new(),
                records: Vec::new(),
                image,
                channels: Some(channels),
            });
        }
        let taps = aperture::disk_taps(s.lens);
        let n = layers.len();
        let records: Vec<Record> = layers
            .iter()
            .enumerate()
            .map(|(k, l)| match s.profile {
                Profile::Official => Record::Official(exact::scatter_layer(l, s, &taps, Role::of(k, n))),
                Profile::Physical => Record::Physical(physical::record(l, s, &smoothing, &taps, Role::of(k, n), ray_test)),
            })
            .collect();
        let (w, h) = (layers[0].width(), layers[0].height());
        let mut acc = composite::accumulator(w, h);
        for rec in &records {
            let raw = rec.raw();
            let range = raw.colour_range();
            acc.par_chunks_exact_mut(composite::ACC_CHANNELS).enumerate().for_each(|(i, px)| composite::over(raw.pixel(i), &range, px));
        }
        let image = composite::finish(w, h, acc);
        if !image.all_finite() {
            return Err(Error::Internal(format!(
                "the differentiable exact kernel produced non-finite pixels (blur {}, focus {}, lens {}); please report this",
                s.blur, s.focus, s.lens
            )));
        }
        Ok(Tape { layers, settings: *s, smoothing, ray_test, taps, records, image, channels: None })
    }

    /// The rendered linear RGB image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    /// The gradients of a loss `L` whose gradient with respect to [`Tape::image`] is
    /// `cotangent` (3 channels, the image's size, finite): `Jᵀ·cotangent` for every layer
    /// input, the focus and K. Allocates per layer the cotangents of its raw sums (40 bytes per
    /// pixel) and the gradient accumulators (56 bytes per pixel, plus the row bands').
    pub fn vjp(&self, cotangent: &Image) -> Result<Gradients> {
        let (w, h) = (self.image.width, self.image.height);
        check_cotangent(cotangent, w, h)?;
        if let (Some(tapes), Some(scales)) = (&self.channels, self.settings.aperture.channel_scales()) {
            return chromatic_vjp(tapes, scales, cotangent);
        }
        let cots = self.composite_backward(cotangent);
        let s = &self.settings;
        let (mut g_focus, mut g_blur) = (0f64, 0f64);
        let mut layers = Vec::with_capacity(self.layers.len());
        for ((l, rec), cot) in self.layers.iter().zip(&self.records).zip(&cots) {
            let mut grads = match rec {
                Record::Official(_) => official::backward(l, s, &self.taps, cot),
                Record::Physical(r) => {
                    let mut g = physical::backward(l, s, &self.smoothing, &self.taps, r, cot, self.ray_test);
                    // The backdrop's visibility max(A, α) where α wins: its own alpha's share.
                    g.iter_mut().zip(cot).for_each(|(g, c)| g.alpha += c[4]);
                    g
                }
            };
            let (img, gf, gk) = finish(l, s, &mut grads);
            g_focus += gf;
            g_blur += gk;
            layers.push(img);
        }
        Ok(Gradients { layers, focus: saturate(g_focus), blur: saturate(g_blur) })
    }

    /// The compositor's adjoint: per layer and pixel, the cotangents of the raw pixel the
    /// layer's backward consumes (see [`RawCot`]). f64; O(pixels·layers).
    fn composite_backward(&self, cotangent: &Image) -> Vec<Vec<RawCot>> {
        let n = self.records.len();
        let (w, h) = (self.image.width, self.image.height);
        let ranges: Vec<[[f32; 2]; 3]> = self.records.iter().map(|r| r.raw().colour_range()).collect();
        // Pixel-major: the n layers' cotangents of pixel i at [i·n, (i + 1)·n).
        let mut flat = vec![[0f64; 8]; w * h * n];
        flat.par_chunks_mut(n).enumerate().for_each(|(i, out)| {
            let g: [f64; 3] = std::array::from_fn(|c| cotangent.data[i * 3 + c] as f64);
            // The transmittance in front of each layer, parked in out[l][0] until the
            // backward sweep overwrites it.
            let mut t = 1f64;
            for (l, rec) in self.records.iter().enumerate() {
                out[l][0] = t;
                t *= 1.0 - rec.raw().pixel(i)[super::raw::VISIBILITY] as f64;
            }
            let mut g_t = 0f64; // ∂L/∂T of the layer behind
            for l in (0..n).rev() {
                let px = self.records[l].raw().pixel(i);
                let (weight, vis, tl) = (px[super::raw::WEIGHT] as f64, px[super::raw::VISIBILITY] as f64, out[l][0]);
                // The colour as composited (clamped); 0 where the layer has no weight.
                let colour: [f64; 3] = std::array::from_fn(|c| {
                    if weight > 0.0 { (px[c] / px[super::raw::WEIGHT]).clamp(ranges[l][c][0], ranges[l][c][1]) as f64 } else { 0.0 }
                });
                let g_colour: f64 = (0..3).map(|c| g[c] * colour[c]).sum();
                let alpha = self.layers[l].alpha(i) as f64;
                let backdrop_alpha = matches!(self.records[l], Record::Physical(_)) && Role::of(l, n) == Role::Backdrop && alpha > weight;
                out[l] = match self.records[l] {
                    // Visibility = coverage: the layer adds P·T and leaves T·(1 - A).
                    Record::Physical(_) if !backdrop_alpha => [g[0] * tl, g[1] * tl, g[2] * tl, -g_t * tl, 0.0, 0.0, 0.0, 0.0],
                    // C·V·T with C = X/W, whether X/W are ΣRGB/W (official) or P/A with the
                    // backdrop's visibility α (physical).
                    _ => {
                        let (mut gx, mut g_w) = ([0f64; 3], 0f64);
                        if weight > 0.0 {
                            for c in 0..3 {
                                gx[c] = g[c] * vis * tl / weight;
                                g_w -= gx[c] * px[c] as f64 / weight;
                            }
                        }
                        // An official layer with no weight and no visibility here: the
                        // first source to gain alpha in both its taps and its box brings
                        // its own colour (the right derivative at α = 0).
                        let empty = if weight == 0.0 && vis == 0.0 { g.map(|g| g * tl) } else { [0.0; 3] };
                        // ∂/∂o (official) or ∂/∂α of the backdrop (physical).
                        [gx[0], gx[1], gx[2], g_w, g_colour * tl - g_t * tl, empty[0], empty[1], empty[2]]
                    }
                };
                g_t = g_colour * vis + g_t * (1.0 - vis);
            }
        });
        // Pixel-major → one plane per layer.
        (0..n).map(|l| flat.iter().skip(l).step_by(n).copied().collect()).collect()
    }
}

/// [`Tape::vjp`] of a chromatic render: channel `c` of the image is channel `c` of tape `c`'s
/// render, whose K is `scales[c]·K`, so the gradients are the sum over the channels of each
/// tape's VJP of that channel's cotangent alone, K's scaled by the channel's factor.
fn chromatic_vjp(tapes: &[Tape; 3], scales: [f32; 3], cotangent: &Image) -> Result<Gradients> {
    let mut total: Option<Gradients> = None;
    for (c, (tape, &scale)) in tapes.iter().zip(&scales).enumerate() {
        let mut cot = Image::new(cotangent.width, cotangent.height, 3);
        cot.data.chunks_exact_mut(3).zip(cotangent.data.chunks_exact(3)).for_each(|(o, g)| o[c] = g[c]);
        let mut g = tape.vjp(&cot)?;
        g.blur = saturate(g.blur as f64 * scale as f64);
        total = Some(match total {
            None => g,
            Some(mut t) => {
                for (a, b) in t.layers.iter_mut().zip(&g.layers) {
                    a.data.iter_mut().zip(&b.data).for_each(|(a, b)| *a = saturate(*a as f64 + *b as f64));
                }
                t.focus = saturate(t.focus as f64 + g.focus as f64);
                t.blur = saturate(t.blur as f64 + g.blur as f64);
                t
            }
        });
    }
    Ok(total.expect("three channels"))
}

/// The gradients of one layer as its image of `∂L/∂[R, G, B, A, D]`, and its share of
/// `(∂L/∂focus, ∂L/∂K)`: the radius and defocus gradients go to the disparity through
/// `∂σ/∂d`, `∂q/∂d` and to K through `∂σ/∂K`, `∂q/∂K`; `∂d/∂focus = -1`.
fn finish(layer: &Layer, s: &RenderSettings, grads: &mut [PixelGrad]) -> (Image, f64, f64) {
    let (w, h) = (layer.width(), layer.height());
    let mut img = Image::new(w, h, layer::CHANNELS);
    let (mut g_focus, mut g_blur) = (0f64, 0f64);
    for (i, (g, px)) in grads.iter().zip(img.data.chunks_exact_mut(layer::CHANNELS)).enumerate() {
        let d = layer.disparity(i) - s.focus;
        let (dr_dd, dr_dk) = lens::coc_radius_grad(d, s.blur);
        let (dq_dd, dq_dk) = if s.profile == Profile::Official { lens::focal_defocus_grad(d, s.blur) } else { (0.0, 0.0) };
        let g_d = g.disparity + g.radius * dr_dd as f64 + g.defocus * dq_dd as f64;
        g_blur += g.radius * dr_dk as f64 + g.defocus * dq_dk as f64;
        g_focus -= g_d;
        px[layer::R] = saturate(g.colour[0]);
        px[layer::R + 1] = saturate(g.colour[1]);
        px[layer::R + 2] = saturate(g.colour[2]);
        px[layer::A] = saturate(g.alpha);
        px[layer::D] = saturate(g_d);
    }
    (img, g_focus, g_blur)
}

/// An f64 gradient as f32, saturating at ±`f32::MAX` (a gradient beyond is a direction, not a
/// step size; the caller's optimiser clips it).
fn saturate(v: f64) -> f32 {
    v.clamp(-(f32::MAX as f64), f32::MAX as f64) as f32
}

/// The span tape differentiates the disc only (its per-row spans are the disc's): a render
/// with another aperture is refused there rather than differentiated as a disc (a wrong
/// gradient with no error). [`Tape`] differentiates every aperture; chromatic aberration per
/// channel.
pub(crate) fn check_span_aperture(s: &RenderSettings) -> Result<()> {
    if s.aperture.is_disc() {
        return Ok(());
    }
    Err(crate::error::Error::usage(format!(
        "aperture {}: the fast differentiable render (depth from defocus's fast kernel) draws the disc only; the exact kernel (dfd --kernel exact, Tape) differentiates any aperture",
        s.aperture.label()
    )))
}

/// Renders like [`Tape::record`] and returns the image and `Jᵀ·cotangent` (see [`Tape::vjp`]).
pub fn vjp(layers: &[Layer], s: &RenderSettings, smoothing: Smoothing, cotangent: &Image) -> Result<(Image, Gradients)> {
    let tape = Tape::record(layers, s, smoothing)?;
    let g = tape.vjp(cotangent)?;
    Ok((tape.image, g))
}

/// The function [`vjp`] differentiates: the exact kernel's render, with the physical
/// profile's edges rounded by `smoothing` (the official profile's is [`crate::render::render`]'s
/// image). Linear RGB.
pub fn render_differentiable(layers: &[Layer], s: &RenderSettings, smoothing: Smoothing) -> Result<Image> {
    Tape::record(layers, s, smoothing).map(|t| t.image)
}
