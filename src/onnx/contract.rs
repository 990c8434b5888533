//! Model contracts: what a model expects as input and what its output means, and presets for
//! widely used public exports.
//!
//! Pure data: the vocabulary a contract is written in (layouts, colour orders, scales...),
//! [`Contract`] and the [`PRESETS`]. A stage's spec is resolved into a contract and checked
//! against the model in [`super::binding`].

use serde::{Deserialize, Serialize};

/// Tensor memory layout of the image input (and of a rank-4 output).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// [1, C, H, W] (PyTorch exports).
    Nchw,
    /// [1, H, W, C] (TensorFlow / TFLite / Keras conversions).
    Nhwc,
}

/// Order of the colour channels in the model's input tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ColorOrder {
    /// Red, green, blue (PyTorch conventions).
    Rgb,
    /// Blue, green, red (OpenCV / Caffe conventions).
    Bgr,
}

/// How the image is brought to the model's size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ResizeMode {
    /// Resize to the model size, ignoring the aspect ratio.
    Stretch,
    /// Keep the aspect ratio and pad (with 0 after normalization) to the model size.
    Letterbox,
}

/// Input value scaling of sRGB-encoded colours before mean/std.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ValueScale {
    /// Colours in [0, 1].
    #[serde(rename = "0-1")]
    Unit,
    /// Colours in [0, 255].
    #[serde(rename = "0-255")]
    Byte,
}

/// Function applied to the raw model output before `output_range`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Activation {
    /// The output is used as is.
    None,
    /// `1 / (1 + e^-x)`, for models that output logits.
    Sigmoid,
    /// `e^x`, for models that output log radiance (inverse tone mapping).
    Exp,
}

/// An output chosen by name or by position.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OutputRef {
    /// The output at this position, 0 = first.
    Index(usize),
    /// The output with this name.
    Name(String),
}

/// What a model is used for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum ModelKind {
    /// Saliency / matting: image → soft matte.
    Matte,
    /// Inpainting: image + mask → image.
    Inpaint,
    /// Depth estimation: image → relative disparity.
    Depth,
    /// Inverse tone mapping: 8-bit image → linear HDR image (the clipped highlights' light).
    Highlights,
}

impl ModelKind {
    /// The config table of this kind's model, as errors name it ("segment.onnx", ...).
    pub fn section(self) -> &'static str {
        match self {
            ModelKind::Matte => "segment.onnx",
            ModelKind::Inpaint => "inpaint.onnx",
            ModelKind::Depth => "depth.onnx",
            ModelKind::Highlights => "highlights.onnx",
        }
    }
    pub(super) fn default_preset(self) -> &'static str {
        match self {
            ModelKind::Matte => "u2net",
            ModelKind::Inpaint => "lama",
            ModelKind::Depth => "depth-anything-v2",
            ModelKind::Highlights => "expandnet",
        }
    }
}

/// The model input size.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum SizeSpec {
    /// Exactly `h` x `w`.
    /// Exactly `h` x `w`.
    Fixed {
        /// Input height, pixels.
        h: usize,
        /// Input width, pixels.
        w: usize,
    },
    /// Any size whose sides are multiples of `multiple`, longest side at most `max_side`.
    /// Any size whose sides are multiples of `multiple`, longest side at most `max_side`.
    Dynamic {
        /// Each side is rounded to a multiple of this (e.g. 32, the network's stride).
        multiple: usize,
        /// Longest side, pixels; larger images are shrunk. None: no limit.
        max_side: Option<usize>,
    },
}

/// A complete contract.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Contract {
    /// Preset the contract started from.
    pub preset: String,
    /// What the model is used for.
    pub kind: ModelKind,
    /// Name of the image input; None: the model's only input.
    pub input: Option<String>,
    /// Name of the mask input (inpainting: 1 = fill); None for other kinds.
    pub mask_input: Option<String>,
    /// Which output holds the result.
    pub output: OutputRef,
    /// Expected rank of that output (2, 3 or 4); None: not checked.
    pub output_rank: Option<usize>,
    /// Input tensor layout.
    pub layout: Layout,
    /// Channel order of the input tensor.
    pub color: ColorOrder,
    /// The input size the image is brought to.
    pub size: SizeSpec,
    /// How the image is brought to that size.
    pub resize: ResizeMode,
    /// Units of the input colours before normalization.
    pub scale: ValueScale,
    /// Per-channel mean, RGB order, in the units of `scale`: `x' = (x - mean) / std`.
    pub mean: [f32; 3],
    /// Per-channel standard deviation, RGB order, in the units of `scale` (non-zero).
    pub std: [f32; 3],
    /// Function applied to the raw output.
    pub activation: Activation,
    /// The activated output's value range `[lo, hi]`, mapped linearly to [0, 1].
    pub output_range: [f32; 2],
    /// Min-max normalize the output over the image (saliency maps, relative depth).
    pub minmax: bool,
    /// Inpainting: context fraction around the mask's bounding box (fixed-size models).
    pub context: f32,
    /// Inpainting: feathered seam width in pixels.
    pub feather: f32,
    /// Inpainting: how the disparity is filled.
    pub depth: DepthFill,
}

/// A documented preset.
pub struct Preset {
    /// The preset's name as `preset = "..."` spells it.
    pub name: &'static str,
    /// Default model file name in `onnx.model_dir`.
    pub file: &'static str,
    /// Where the conventions come from.
    pub source: &'static str,
    /// Builds the preset's contract.
    pub contract: fn() -> Contract,
}

const IMAGENET_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const IMAGENET_STD: [f32; 3] = [0.229, 0.224, 0.225];

fn base(preset: &str, kind: ModelKind) -> Contract {
    Contract {
        preset: preset.into(),
        kind,
        input: None,
        mask_input: None,
        output: OutputRef::Index(0),
        output_rank: Some(4),
        layout: Layout::Nchw,
        color: ColorOrder::Rgb,
        size: SizeSpec::Fixed { h: 320, w: 320 },
        resize: ResizeMode::Stretch,
        scale: ValueScale::Unit,
        mean: [0.0; 3],
        std: [1.0; 3],
        activation: Activation::None,
        output_range: [0.0, 1.0],
        minmax: false,
        context: 0.5,
        feather: 2.0,
        depth: DepthFill::Telea,
    }
}

/// The presets, with their source conventions.
pub const PRESETS: &[Preset] = &[
    Preset {
        name: "u2net",
        file: "u2net.onnx",
        source: "U^2-Net (xuebinqin/U-2-Net; rembg's u2net.onnx): 320x320 RGB in [0,1], ImageNet mean/std, \
                 first output d0 already through a sigmoid, min-max normalized",
        contract: || Contract {
            size: SizeSpec::Fixed { h: 320, w: 320 },
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            minmax: true,
            ..base("u2net", ModelKind::Matte)
        },
    },
    Preset {
        name: "isnet",
        file: "isnet.onnx",
        source: "ISNet / DIS (xuebinqin/DIS; rembg's isnet-general-use.onnx): 1024x1024 RGB in [0,1], mean 0.5 std 1, \
                 first output already through a sigmoid, min-max normalized",
        contract: || Contract {
            size: SizeSpec::Fixed { h: 1024, w: 1024 },
            mean: [0.5; 3],
            std: [1.0; 3],
            minmax: true,
            ..base("isnet", ModelKind::Matte)
        },
    },
    Preset {
        name: "birefnet",
        file: "birefnet.onnx",
        source: "BiRefNet (ZhengPeng7/BiRefNet ONNX export): 1024x1024 RGB in [0,1], ImageNet mean/std, \
                 first output is logits -> sigmoid",
        contract: || Contract {
            size: SizeSpec::Fixed { h: 1024, w: 1024 },
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            activation: Activation::Sigmoid,
            ..base("birefnet", ModelKind::Matte)
        },
    },
    Preset {
        name: "modnet",
        file: "modnet.onnx",
        source: "MODNet (ZeHuiLin/MODNet onnx/export_onnx.py): input \"input\" 1x3xHxW, dynamic size (multiple of 32, \
                 longest side 512), RGB in [0,1] with mean 0.5 std 0.5, output \"output\" matte in [0,1]",
        contract: || Contract {
            input: Some("input".into()),
            output: OutputRef::Name("output".into()),
            size: SizeSpec::Dynamic { multiple: 32, max_side: Some(512) },
            mean: [0.5; 3],
            std: [0.5; 3],
            ..base("modnet", ModelKind::Matte)
        },
    },
    Preset {
        name: "mediapipe-selfie",
        file: "mediapipe_selfie.onnx",
        source: "MediaPipe selfie segmentation (TFLite converted with tf2onnx): 1x256x256x3 NHWC, RGB in [0,1], \
                 output 1x256x256x1 already through a sigmoid",
        contract: || Contract {
            layout: Layout::Nhwc,
            size: SizeSpec::Fixed { h: 256, w: 256 },
            ..base("mediapipe-selfie", ModelKind::Matte)
        },
    },
    Preset {
        name: "lama",
        file: "lama.onnx",
        source: "LaMa (advimman/lama; Carve/LaMa-ONNX lama_fp32.onnx): inputs \"image\" 1x3x512x512 RGB in [0,1] and \
                 \"mask\" 1x1x512x512 in {0,1}, output 1x3x512x512 in [0,255]",
        contract: || Contract {
            input: Some("image".into()),
            mask_input: Some("mask".into()),
            size: SizeSpec::Fixed { h: 512, w: 512 },
            output_range: [0.0, 255.0],
            ..base("lama", ModelKind::Inpaint)
        },
    },
    Preset {
        name: "lama-dynamic",
        file: "lama_dynamic.onnx",
        source: "LaMa exported with dynamic axes: inputs \"image\" 1x3xHxW RGB in [0,1] and \"mask\" 1x1xHxW in {0,1}, \
                 H and W multiples of 8, output 1x3xHxW in [0,1]",
        contract: || Contract {
            input: Some("image".into()),
            mask_input: Some("mask".into()),
            size: SizeSpec::Dynamic { multiple: 8, max_side: Some(2048) },
            ..base("lama-dynamic", ModelKind::Inpaint)
        },
    },
    Preset {
        name: "midas-small",
        file: "midas_small.onnx",
        source: "MiDaS v2.1 small (isl-org/MiDaS model-small.onnx): 256x256 RGB in [0,1], ImageNet mean/std, \
                 output 1x256x256 relative inverse depth, min-max normalized",
        contract: || Contract {
            size: SizeSpec::Fixed { h: 256, w: 256 },
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            output_rank: Some(3),
            minmax: true,
            ..base("midas-small", ModelKind::Depth)
        },
    },
    Preset {
        name: "depth-anything-v2",
        file: "depth_anything_v2.onnx",
        source: "Depth-Anything-V2 (DepthAnything/Depth-Anything-V2 ONNX exports): 1x3xHxW, sides multiples of 14, \
                 longest side 518, RGB in [0,1], ImageNet mean/std, output 1xHxW relative disparity, min-max normalized",
        contract: || Contract {
            size: SizeSpec::Dynamic { multiple: 14, max_side: Some(518) },
            mean: IMAGENET_MEAN,
            std: IMAGENET_STD,
            output_rank: Some(3),
            minmax: true,
            ..base("depth-anything-v2", ModelKind::Depth)
        },
    },
    Preset {
        name: "expandnet",
        file: "expandnet.onnx",
        source: "ExpandNet (dmarnerides/hdr-expandnet, its PyTorch `forward` exported with dynamic height and width; no official \
                 ONNX file): 1x3xHxW RGB in [0,1], any size (the network resizes its global branch to 256x256 itself), output \
                 1x3xHxW linear HDR through a sigmoid, of arbitrary scale (drbokeh scales it to the photo's mid-tones)",
        contract: || Contract { size: SizeSpec::Dynamic { multiple: 1, max_side: Some(1024) }, ..base("expandnet", ModelKind::Highlights) },
    },
];

/// Looks a preset up by name; the error lists the known ones.
pub fn preset(name: &str) -> std::result::Result<&'static Preset, String> {
    PRESETS.iter().find(|p| p.name == name).ok_or_else(|| {
        format!("unknown preset \"{name}\"; known presets: {}", PRESETS.iter().map(|p| p.name).collect::<Vec<_>>().join(", "))
    })
}

/// How the inpainting stage fills the background's disparity.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum DepthFill {
    /// Telea inpainting of the disparity (as the classical stage).
    #[default]
    Telea,
    /// The inpainting model on the disparity replicated to three channels (as the official
    /// pipeline does).
    Model,
}
