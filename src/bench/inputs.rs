//! The benchmark's inputs (issue 35): what every method is fed for one case. Users' photos are
//! 8-bit files whose lights are clipped at white, while the scenes' all-in-focus view is linear
//! HDR (lights of radiance 4–50 times white). Each [`Input`] turns the case's
//! [`SceneInputs`] into what a camera of that kind would have delivered:
//!
//! - [`Input::Linear`]: the linear HDR view as it is (today's bench, the ceiling);
//! - [`Input::Srgb8`]: the view stored as an 8-bit sRGB file: each linear sample `v` becomes
//!   `decode(round(255·encode(clamp(v, 0, 1))) / 255)` with the sRGB curve ([`quantize`]);
//! - [`Input::Srgb8Psf`]: the same after a mild camera PSF on the linear view (a Gaussian of
//!   σ = [`CAMERA_PSF_SIGMA`] px) before clipping, as a real camera records it.
//!
//! The depth maps and the matte are the same for every input. The exact layers (methods
//! `Layers` and `Sliced`) go through the same steps: their colours, stored not premultiplied
//! ([`crate::render::layer`]), are quantized as the photo's, the PSF applied within each layer
//! as a normalized convolution (blur of colour·alpha over blur of alpha; alpha unchanged), so
//! they show what clipping costs with perfect layers. No highlights stage runs on them.

use super::scenes::SceneInputs;
use crate::color::{PhotoEncoding, Transfer};
use crate::error::Result;
use crate::image::Image;
use crate::render::Layer;
use crate::render::layer::{A, CHANNELS, R};
use crate::stages::mask::gaussian_blur;
use std::borrow::Cow;

/// σ of the camera PSF of [`Input::Srgb8Psf`], pixels (a Gaussian on the linear view before
/// clipping): a sharp lens and sensor, whose blur spreads a point light over about 3×3 pixels.
pub const CAMERA_PSF_SIGMA: f32 = 0.7;
/// Bits per sample of the integer inputs.
const BITS: u8 = 8;
/// The largest code of an integer sample (`2^BITS - 1`): it decodes to white and holds every
/// value above it.
const WHITE_CODE: f32 = ((1u32 << BITS) - 1) as f32;
/// The transfer curve the integer inputs are stored with.
const TRANSFER: Transfer = Transfer::Srgb;
/// Below this blurred alpha a layer pixel keeps its own colour in the normalized convolution
/// (nothing of the layer lies near enough to carry a colour there).
const MIN_BLURRED_ALPHA: f32 = 1e-6;

/// How the all-in-focus photo reaches the methods (`bench --inputs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Input {
    /// The linear HDR view (radiance above white kept): the ceiling.
    Linear,
    /// The view as an 8-bit sRGB file stores it, clipped at white.
    Srgb8,
    /// [`Input::Srgb8`] after a camera PSF of σ = [`CAMERA_PSF_SIGMA`] px before clipping.
    Srgb8Psf,
}

impl Input {
    /// Every input, in report order (the default of `--inputs`).
    pub const ALL: [Input; 3] = [Input::Linear, Input::Srgb8, Input::Srgb8Psf];

    /// The input's name in report.csv, report.md and `--inputs`.
    pub fn name(self) -> &'static str {
        match self {
            Input::Linear => "linear",
            Input::Srgb8 => "srgb8",
            Input::Srgb8Psf => "srgb8-psf",
        }
    }

    /// A description for report.md.
    pub fn label(self) -> String {
        match self {
            Input::Linear => "linear HDR all-in-focus view (the ceiling)".into(),
            Input::Srgb8 => "8-bit sRGB photo, clipped at white".into(),
            Input::Srgb8Psf => format!("8-bit sRGB photo after a camera PSF (Gaussian, σ = {CAMERA_PSF_SIGMA} px) before clipping"),
        }
    }

    /// Parses an input's name (case-insensitive).
    pub fn parse(s: &str) -> Option<Input> {
        let s = s.trim().to_ascii_lowercase();
        Input::ALL.into_iter().find(|i| i.name() == s)
    }

    /// How the photo is stored: what the pipeline's `Scene::encoding` says, so that its
    /// highlights stage runs on the integer inputs.
    pub fn encoding(self) -> PhotoEncoding {
        match self {
            Input::Linear => PhotoEncoding::Linear,
            Input::Srgb8 | Input::Srgb8Psf => PhotoEncoding::Integer { bits: BITS, transfer: TRANSFER },
        }
    }

    /// True for the inputs clipped at white (integer samples).
    pub fn is_clipped(self) -> bool {
        matches!(self.encoding(), PhotoEncoding::Integer { .. })
    }

    /// σ of the camera PSF applied before clipping, pixels; None for no PSF.
    pub fn psf_sigma(self) -> Option<f32> {
        match self {
            Input::Srgb8Psf => Some(CAMERA_PSF_SIGMA),
            Input::Linear | Input::Srgb8 => None,
        }
    }
}

/// A linear sample as an 8-bit sRGB file stores it, decoded back to linear light: clipped to
/// [0, 1], encoded, rounded to the nearest of the 256 codes, decoded. Also says whether the
/// sample landed on the largest code (clipped: it stands for everything above).
#[inline]
pub fn quantize(v: f32) -> (f32, bool) {
    let code = (TRANSFER.encode(v.clamp(0.0, 1.0)) * WHITE_CODE).round();
    (TRANSFER.decode(code / WHITE_CODE), code >= WHITE_CODE)
}

/// A case's inputs as one [`Input`] delivers them.
pub struct Prepared<'a> {
    /// The input kind.
    pub input: Input,
    /// What the methods render from: for the clipped inputs, the photo and the exact layers'
    /// colours quantized (depth maps and matte as they are).
    pub scene: Cow<'a, SceneInputs>,
    /// Linear light that clipping took from the photo: over the samples stored as white, the
    /// sum of (the linear view before clipping − white), after the PSF for
    /// [`Input::Srgb8Psf`]. None for the linear input.
    pub missing_light: Option<f64>,
}

/// Builds the inputs `input` delivers from a case's linear ones. Linear: borrowed as they are.
/// Clipped inputs: a new photo and new layers (one copy of each, plus four blurred planes per
/// layer with the PSF); O(pixels · layers), single-threaded apart from the blurs.
pub fn prepare(linear: &SceneInputs, input: Input) -> Result<Prepared<'_>> {
    if !input.is_clipped() {
        return Ok(Prepared { input, scene: Cow::Borrowed(linear), missing_light: None });
    }
    let sigma = input.psf_sigma();
    let (aif, missing) = photo(&linear.aif, input);
    let layers = |ls: &[Layer]| -> Result<Vec<Layer<'static>>> { ls.iter().map(|l| record_layer(l, sigma)).collect() };
    let scene = SceneInputs {
        aif: aif.into_owned(),
        disparity: linear.disparity.clone(),
        matte: linear.matte.clone(),
        realistic_disparity: linear.realistic_disparity.clone(),
        two_layers: layers(&linear.two_layers)?,
        plane_layers: layers(&linear.plane_layers)?,
    };
    Ok(Prepared { input, scene: Cow::Owned(scene), missing_light: missing })
}

/// The photo `input` delivers of the linear RGB view `linear` (borrowed for the linear
/// input; for the clipped ones a new image, the PSF applied first when the input has one) and
/// the light clipping took (see [`Prepared::missing_light`]; None for the linear input).
pub fn photo(linear: &Image, input: Input) -> (Cow<'_, Image>, Option<f64>) {
    if !input.is_clipped() {
        return (Cow::Borrowed(linear), None);
    }
    let recorded = match input.psf_sigma() {
        Some(s) => Cow::Owned(blur_rgb(linear, s)),
        None => Cow::Borrowed(linear),
    };
    let (out, missing) = record(&recorded);
    (Cow::Owned(out), Some(missing))
}

/// The photo an 8-bit camera stores of the linear image `linear` (every sample through
/// [`quantize`]), and the light clipping took: the sum over clipped samples of (linear − stored).
fn record(linear: &Image) -> (Image, f64) {
    let mut out = linear.clone();
    let mut missing = 0.0f64;
    for v in &mut out.data {
        let (q, clipped) = quantize(*v);
        if clipped {
            missing += (*v - q) as f64;
        }
        *v = q;
    }
    (out, missing)
}

/// A layer as the 8-bit camera would store its colours: blurred by the PSF of σ `sigma` (px)
/// within the layer when given (normalized convolution, alpha unchanged), then quantized.
fn record_layer(layer: &Layer, sigma: Option<f32>) -> Result<Layer<'static>> {
    let mut img = layer.image().to_image();
    if let Some(s) = sigma {
        let alpha = img.channel(A);
        let blurred_alpha = gaussian_blur(&alpha, s);
        let weighted: Vec<Image> = (R..R + 3)
            .map(|c| {
                let mut p = img.channel(c);
                p.data.iter_mut().zip(&alpha.data).for_each(|(v, &a)| *v *= a);
                gaussian_blur(&p, s)
            })
            .collect();
        for (i, px) in img.data.chunks_exact_mut(CHANNELS).enumerate() {
            let a = blurred_alpha.data[i];
            if a > MIN_BLURRED_ALPHA {
                for (c, plane) in weighted.iter().enumerate() {
                    px[R + c] = plane.data[i] / a;
                }
            }
        }
    }
    let mut out = Layer::new(img, "8-bit layer")?;
    out.map_colors(|v| quantize(v).0);
    Ok(out)
}

/// A linear RGB image blurred by a Gaussian of σ `sigma` pixels, channel by channel (edges
/// clamped, as [`gaussian_blur`]). Allocates the three planes and the result.
fn blur_rgb(rgb: &Image, sigma: f32) -> Image {
    let planes: Vec<Image> = (0..rgb.channels).map(|c| gaussian_blur(&rgb.channel(c), sigma)).collect();
    Image::stack(&planes.iter().collect::<Vec<_>>())
}

/// The input the method tables, the main plot and the crops are drawn from: the linear one
/// when it ran (the ceiling), else the first of `inputs` (linear for none).
pub fn primary_input(inputs: &[Input]) -> Input {
    if inputs.contains(&Input::Linear) { Input::Linear } else { inputs.first().copied().unwrap_or(Input::Linear) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::color::srgb_to_linear;

    /// The quantizer against the plain formula at every code and between codes; white and
    /// everything above it is the largest code, and only it counts as clipped.
    #[test]
    fn quantize_is_the_8bit_srgb_round_trip() {
        for code in 0..=255u32 {
            let v = srgb_to_linear(code as f32 / 255.0);
            let (q, clipped) = quantize(v);
            assert!((q - v).abs() <= 1e-6 * v.max(1e-3), "code {code}: {q} vs {v}");
            assert_eq!(clipped, code == 255, "code {code}");
        }
        for v in [1.0f32, 1.5, 20.0, 1e4] {
            assert_eq!(quantize(v), (srgb_to_linear(1.0), true));
        }
        assert_eq!(quantize(-0.5), (0.0, false));
        // Between two codes: the nearer one in the encoded scale.
        let mid = srgb_to_linear(100.4 / 255.0);
        assert_eq!(quantize(mid).0, srgb_to_linear(100.0 / 255.0));
    }

    /// The missing light is what lies above white at the clipped samples; the PSF spreads a
    /// point light but (away from the border) keeps its total light.
    #[test]
    fn missing_light_of_a_clipped_point() {
        let mut img = Image::filled(16, 16, 3, 0.25);
        img.pixel_mut(8, 8).copy_from_slice(&[20.0, 10.0, 0.5]);
        let (photo, missing) = record(&img);
        assert_eq!(photo.pixel(8, 8)[0], srgb_to_linear(1.0));
        assert!((missing - (19.0 + 9.0)).abs() < 1e-4, "{missing}");
        let blurred = blur_rgb(&img, CAMERA_PSF_SIGMA);
        let sum = Image::sum;
        assert!((sum(&blurred) - sum(&img)).abs() < 1e-3 * sum(&img), "{} vs {}", sum(&blurred), sum(&img));
        assert!(blurred.pixel(8, 8)[0] < 20.0 && blurred.pixel(9, 8)[0] > 1.0);
    }

    /// The normalized convolution keeps a uniform layer's colour (alpha edge included) and its
    /// alpha; the colours come out quantized.
    #[test]
    fn layer_psf_keeps_alpha_and_a_flat_colour() {
        let (w, h) = (12, 10);
        let mut img = Image::new(w, h, CHANNELS);
        for (i, px) in img.data.chunks_exact_mut(CHANNELS).enumerate() {
            let a = if i % w < 6 { 1.0 } else { 0.0 };
            px.copy_from_slice(&[0.3, 0.6, 3.0, a, 0.5]);
        }
        let layer = Layer::new(img.clone(), "test").unwrap();
        let out = record_layer(&layer, Some(CAMERA_PSF_SIGMA)).unwrap();
        for (o, i) in out.image().data.chunks_exact(CHANNELS).zip(img.data.chunks_exact(CHANNELS)) {
            assert_eq!(&o[A..], &i[A..]);
            for (got, was) in o[R..R + 3].iter().zip(&i[R..R + 3]) {
                assert_eq!(*got, quantize(*was).0, "{o:?}");
            }
        }
    }
}
