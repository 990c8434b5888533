//! A stage's contract made concrete: [`resolve`] applies the stage's spec (preset + overrides,
//! the model file) to a preset's [`Contract`]; [`bind`] checks it against the model when its
//! session is first used: names, ranks, element types and fixed sizes that do not match are
//! errors that name the model file and list what the model actually has.

use super::config::{ModelSpec, OnnxConfig};
use super::contract::{Contract, Layout, ModelKind, OutputRef, SizeSpec, preset};
use super::session::{ModelSession, TensorInfo};
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Resolves a stage's model file and contract from its spec.
pub fn resolve(spec: &ModelSpec, kind: ModelKind, onnx: &OnnxConfig) -> Result<(PathBuf, Contract)> {
    let key = kind.section();
    spec.validate(key, kind)?;
    let name = spec.preset.as_deref().unwrap_or(kind.default_preset());
    let p = preset(name).map_err(|m| Error::usage(format!("{key}.preset: {m}")))?;
    let mut c = (p.contract)();
    if c.kind != kind {
        return Err(Error::usage(format!("{key}.preset: \"{name}\" is a {:?} preset, not a {kind:?} one", c.kind)));
    }
    let path = match (&spec.model, &onnx.model_dir) {
        (Some(m), Some(dir)) if m.is_relative() => dir.join(m),
        (Some(m), _) => m.clone(),
        (None, Some(dir)) => dir.join(p.file),
        (None, None) => {
            return Err(Error::usage(format!(
                "{key}: no model file: set `model = \"path.onnx\"` in [{key}], or give a model folder (onnx.model_dir) holding {}",
                p.file
            )));
        }
    };
    if spec.input.is_some() {
        c.input = spec.input.clone();
    }
    if spec.mask_input.is_some() {
        c.mask_input = spec.mask_input.clone();
    }
    if let Some(o) = &spec.output {
        c.output = o.clone();
    }
    if spec.output_rank.is_some() {
        c.output_rank = spec.output_rank;
    }
    c.layout = spec.layout.unwrap_or(c.layout);
    c.color = spec.color.unwrap_or(c.color);
    if let Some([h, w]) = spec.size {
        c.size = SizeSpec::Fixed { h, w };
    }
    if let Some(m) = spec.multiple {
        let max_side = spec.max_side.or(match c.size {
            SizeSpec::Dynamic { max_side, .. } => max_side,
            SizeSpec::Fixed { .. } => None,
        });
        c.size = SizeSpec::Dynamic { multiple: m, max_side };
    } else if let (Some(ms), SizeSpec::Dynamic { multiple, .. }) = (spec.max_side, c.size) {
        c.size = SizeSpec::Dynamic { multiple, max_side: Some(ms) };
    }
    c.resize = spec.resize.unwrap_or(c.resize);
    c.scale = spec.scale.unwrap_or(c.scale);
    c.mean = spec.mean.unwrap_or(c.mean);
    c.std = spec.std.unwrap_or(c.std);
    c.activation = spec.activation.unwrap_or(c.activation);
    c.output_range = spec.output_range.unwrap_or(c.output_range);
    c.minmax = spec.minmax.unwrap_or(c.minmax);
    c.context = spec.context.unwrap_or(c.context);
    c.feather = spec.feather.unwrap_or(c.feather);
    c.depth = spec.depth.unwrap_or(c.depth);
    if kind == ModelKind::Inpaint && (c.input.is_none() || c.mask_input.is_none()) {
        return Err(Error::usage(format!("{key}: an inpainting contract needs both `input` and `mask_input` names")));
    }
    Ok((path, c))
}

/// The contract bound to a model: resolved tensor names and the model's fixed size if any.
#[derive(Clone, Debug)]
pub struct Binding {
    /// Name of the model's image input.
    pub input: String,
    /// Name of the model's mask input (inpainting only).
    pub mask_input: Option<String>,
    /// Name of the model output read.
    pub output: String,
    /// Rank of that output (2, 3 or 4).
    pub output_rank: usize,
    /// The input's spatial size when the model fixes it (h, w).
    pub fixed: Option<(usize, usize)>,
}

fn list(tensors: &[TensorInfo]) -> String {
    tensors.iter().map(|t| t.to_string()).collect::<Vec<_>>().join(", ")
}

/// Checks the model against the contract. Every mismatch is an input error naming `path`
/// and listing the model's actual inputs or outputs.
pub fn bind(c: &Contract, s: &ModelSession) -> Result<Binding> {
    let path: &Path = &s.path;
    let have_in = || format!("the model has inputs: {}", list(&s.inputs));
    let have_out = || format!("the model has outputs: {}", list(&s.outputs));
    let find = |name: &str| s.inputs.iter().find(|t| t.name == name);
    let image = match &c.input {
        Some(n) => find(n).ok_or_else(|| {
            Error::input(path, format!("no input named \"{n}\" (contract `{}` of preset {}); {}", "input", c.preset, have_in()))
        })?,
        None => {
            let expected = if c.mask_input.is_some() { 2 } else { 1 };
            if s.inputs.len() != expected {
                return Err(Error::input(
                    path,
                    format!(
                        "expected {expected} input(s) (preset {}); {}; name the image input with `input = \"...\"`",
                        c.preset,
                        have_in()
                    ),
                ));
            }
            &s.inputs[0]
        }
    };
    let (chan_axis, h_axis, w_axis) = match c.layout {
        Layout::Nchw => (1, 2, 3),
        Layout::Nhwc => (3, 1, 2),
    };
    let check_4d = |t: &TensorInfo, channels: i64, what: &str| -> Result<()> {
        if t.elem != "f32" {
            return Err(Error::input(
                path,
                format!("{what} \"{}\" is {}, only float32 tensors are supported; {}", t.name, t.elem, have_in()),
            ));
        }
        if t.dims.len() != 4 {
            return Err(Error::input(
                path,
                format!("{what} \"{}\" has rank {}, the contract ({:?}) needs rank 4; {}", t.name, t.dims.len(), c.layout, have_in()),
            ));
        }
        let ch = t.dims[chan_axis];
        if ch >= 0 && ch != channels {
            return Err(Error::input(
                path,
                format!(
                    "{what} \"{}\" has {ch} channel(s) on the {:?} channel axis, expected {channels} (wrong layout? set layout = \"nchw\" or \"nhwc\"); {}",
                    t.name,
                    c.layout,
                    have_in()
                ),
            ));
        }
        if t.dims[0] > 1 {
            return Err(Error::input(path, format!("{what} \"{}\" has a fixed batch of {}, expected 1; {}", t.name, t.dims[0], have_in())));
        }
        Ok(())
    };
    check_4d(image, 3, "input")?;
    let (mh, mw) = (image.dims[h_axis], image.dims[w_axis]);
    let fixed = if mh > 0 && mw > 0 { Some((mh as usize, mw as usize)) } else { None };
    match (c.size, fixed) {
        (SizeSpec::Fixed { h, w }, Some((fh, fw))) if (h, w) != (fh, fw) => {
            return Err(Error::input(
                path,
                format!(
                    "the model's input \"{}\" has the fixed size {fh}x{fw} (HxW) but the contract (preset {}) says {h}x{w}; set size = [{fh}, {fw}]",
                    image.name, c.preset
                ),
            ));
        }
        (SizeSpec::Dynamic { multiple, .. }, Some((fh, fw))) => {
            return Err(Error::input(
                path,
                format!(
                    "the model's input \"{}\" has the fixed size {fh}x{fw} (HxW) but the contract (preset {}) says dynamic (multiple of {multiple}); set size = [{fh}, {fw}]",
                    image.name, c.preset
                ),
            ));
        }
        _ => {}
    }
    if (mh > 0) != (mw > 0) {
        return Err(Error::input(path, format!("input \"{}\" fixes only one of height and width: {}", image.name, image)));
    }
    let mask_input = match &c.mask_input {
        Some(n) => {
            let m = find(n).ok_or_else(|| {
                Error::input(path, format!("no input named \"{n}\" (contract `mask_input` of preset {}); {}", c.preset, have_in()))
            })?;
            check_4d(m, 1, "mask input")?;
            Some(m.name.clone())
        }
        None => None,
    };
    let out = match &c.output {
        OutputRef::Index(i) => s
            .outputs
            .get(*i)
            .ok_or_else(|| Error::input(path, format!("no output #{i} (the model has {} output(s)); {}", s.outputs.len(), have_out())))?,
        OutputRef::Name(n) => s
            .outputs
            .iter()
            .find(|t| &t.name == n)
            .ok_or_else(|| Error::input(path, format!("no output named \"{n}\" (contract of preset {}); {}", c.preset, have_out())))?,
    };
    if out.elem != "f32" {
        return Err(Error::input(
            path,
            format!("output \"{}\" is {}, only float32 tensors are supported; {}", out.name, out.elem, have_out()),
        ));
    }
    let rank = out.dims.len();
    match c.output_rank {
        Some(r) if r != rank => {
            return Err(Error::input(
                path,
                format!("output \"{}\" has rank {rank}, the contract (preset {}) expects rank {r}; {}", out.name, c.preset, have_out()),
            ));
        }
        None if !(2..=4).contains(&rank) => {
            return Err(Error::input(path, format!("output \"{}\" has rank {rank}, expected 2, 3 or 4; {}", out.name, have_out())));
        }
        _ => {}
    }
    Ok(Binding { input: image.name.clone(), mask_input, output: out.name.clone(), output_rank: rank, fixed })
}
