//! Sessions: one per (model file, threads, providers), created on first use and reused for
//! every later image of the process (a batch pays session creation once).

use super::config::{OnnxConfig, Provider};
use super::runtime;
use crate::error::{Error, Result};
use crate::timing::ms_since;
use ort::ep::{self, ExecutionProvider};
use ort::session::Session;
use ort::value::{Tensor, ValueType};
use std::collections::HashMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Name, element type and dims (-1 = dynamic) of a model input or output.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorInfo {
    /// The tensor's name in the model.
    pub name: String,
    /// Element type as ONNX names it ("float", "uint8", ...).
    pub elem: String,
    /// Dimensions; -1 where the model leaves one dynamic.
    pub dims: Vec<i64>,
}

impl fmt::Display for TensorInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let dims: Vec<String> = self.dims.iter().map(|&d| if d < 0 { "?".into() } else { d.to_string() }).collect();
        write!(f, "\"{}\" {}[{}]", self.name, self.elem, dims.join(", "))
    }
}

/// A loaded model.
pub struct ModelSession {
    /// The model file.
    pub path: PathBuf,
    /// The model's inputs, in declaration order.
    pub inputs: Vec<TensorInfo>,
    /// The model's outputs, in declaration order.
    pub outputs: Vec<TensorInfo>,
    /// Session creation time (model load, graph optimization, provider setup), ms.
    pub create_ms: f64,
    /// Execution providers that were registered (CPU is always available as the fallback).
    pub providers: Vec<String>,
    /// Providers that were asked for but could not be used.
    pub warnings: Vec<String>,
    session: Mutex<Session>,
}

type Key = (PathBuf, usize, Vec<String>);

static CACHE: Mutex<Option<HashMap<Key, Arc<ModelSession>>>> = Mutex::new(None);
static CREATED: AtomicUsize = AtomicUsize::new(0);

/// How many sessions this process has created (a batch should create each model once).
pub fn sessions_created() -> usize {
    CREATED.load(Ordering::Relaxed)
}

/// Drops every cached session (the next use creates them again).
pub fn clear_cache() {
    CACHE.lock().unwrap_or_else(|e| e.into_inner()).take();
}

fn describe(name: &str, t: &ValueType) -> TensorInfo {
    match t {
        ValueType::Tensor { ty, shape, .. } => TensorInfo {
            name: name.to_string(),
            elem: format!("{ty}").to_lowercase().replace("float32", "f32").replace("float", "f32"),
            dims: shape.iter().copied().collect(),
        },
        other => TensorInfo { name: name.to_string(), elem: format!("{other}"), dims: Vec::new() },
    }
}

/// The session for `path`, from the cache or newly created. Returns it and whether it was cached.
pub fn session(path: &Path, cfg: &OnnxConfig) -> Result<(Arc<ModelSession>, bool)> {
    let meta = std::fs::metadata(path).map_err(|e| match e.kind() {
        std::io::ErrorKind::NotFound => Error::input(path, "model file not found"),
        _ => Error::io(path, e),
    })?;
    if !meta.is_file() {
        return Err(Error::input(path, "the model path is not a file"));
    }
    let canon = std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf());
    let key: Key = (canon, cfg.threads, cfg.providers.clone());
    if let Some(s) = CACHE.lock().unwrap_or_else(|e| e.into_inner()).as_ref().and_then(|m| m.get(&key)) {
        return Ok((s.clone(), true));
    }
    let rt = runtime::runtime(cfg)?;
    let s = Arc::new(create(path, cfg, rt)?);
    CREATED.fetch_add(1, Ordering::Relaxed);
    CACHE.lock().unwrap_or_else(|e| e.into_inner()).get_or_insert_with(HashMap::new).insert(key, s.clone());
    Ok((s, false))
}

fn create(path: &Path, cfg: &OnnxConfig, rt: &runtime::Runtime) -> Result<ModelSession> {
    let t = Instant::now();
    let bytes = crate::io::read_input(path)?;
    if bytes.is_empty() {
        return Err(Error::input(path, "the model file is empty (not an ONNX model)"));
    }
    let internal = |e: ort::Error| Error::Internal(format!("ONNX Runtime session options for {}: {e}", path.display()));
    let mut b = Session::builder(&rt.env).map_err(internal)?;
    if cfg.threads > 0 {
        b = b.with_intra_threads(cfg.threads).map_err(|e| internal(e.into()))?;
    }
    let mut warnings = Vec::new();
    let mut providers = Vec::new();
    for name in &cfg.providers {
        let Some(p) = Provider::parse(name) else {
            return Err(Error::usage(format!("onnx.providers: unknown execution provider \"{name}\"")));
        };
        if p == Provider::Cpu {
            break;
        }
        let available = match p {
            Provider::Cuda => ep::CUDA::is_available(),
            Provider::TensorRt => ep::TensorRT::is_available(),
            Provider::CoreMl => ep::CoreML::is_available(),
            Provider::DirectMl => ep::DirectML::is_available(),
            Provider::Cpu => Ok(true),
        }
        .unwrap_or(false);
        if !available {
            warnings.push(format!(
                "execution provider {} is not in the ONNX Runtime at {} (version {}); falling back to the next provider / CPU",
                p.ort_name(),
                rt.library.display(),
                rt.version
            ));
            continue;
        }
        let dispatch = match p {
            Provider::Cuda => ep::CUDA::default().build(),
            Provider::TensorRt => ep::TensorRT::default().build(),
            Provider::CoreMl => ep::CoreML::default().build(),
            Provider::DirectMl => ep::DirectML::default().build(),
            Provider::Cpu => unreachable!(),
        }
        .error_on_failure();
        match b.with_execution_providers([dispatch]) {
            Ok(nb) => {
                b = nb;
                providers.push(p.ort_name().to_string());
            }
            Err(e) => {
                warnings.push(format!(
                    "execution provider {} could not be registered ({}); falling back to the next provider / CPU",
                    p.ort_name(),
                    e.message()
                ));
                b = e.recover();
            }
        }
    }
    providers.push(Provider::Cpu.ort_name().to_string());
    let session = b
        .commit_from_memory(&bytes)
        .map_err(|e| Error::input(path, format!("is not a loadable ONNX model: {}", e.message().lines().next().unwrap_or("").trim())))?;
    let inputs = session.inputs().iter().map(|o| describe(o.name(), o.dtype())).collect();
    let outputs = session.outputs().iter().map(|o| describe(o.name(), o.dtype())).collect();
    Ok(ModelSession {
        path: path.to_path_buf(),
        inputs,
        outputs,
        create_ms: ms_since(t),
        providers,
        warnings,
        session: Mutex::new(session),
    })
}

/// One input of a run: name, shape and data (float32).
pub struct Feed {
    /// The model input it feeds.
    pub name: String,
    /// Its dimensions (no dynamic ones).
    pub shape: Vec<i64>,
    /// Its values, row-major, `shape`'s product in length.
    pub data: Vec<f32>,
}

impl ModelSession {
    /// Runs the model and returns the named output's shape and values. A NaN or Inf in the
    /// output is an error naming the model file.
    pub fn run(&self, feeds: Vec<Feed>, output: &str) -> Result<(Vec<i64>, Vec<f32>)> {
        let mut values = Vec::with_capacity(feeds.len());
        for f in feeds {
            let t = Tensor::from_array((f.shape.clone(), f.data)).map_err(|e| {
                Error::Internal(format!("cannot build input \"{}\" {:?} for {}: {e}", f.name, f.shape, self.path.display()))
            })?;
            values.push((f.name, t.into_dyn()));
        }
        let mut session = self.session.lock().unwrap_or_else(|e| e.into_inner());
        let outputs = session
            .run(values)
            .map_err(|e| Error::input(&self.path, format!("inference failed: {}", e.message().lines().next().unwrap_or("").trim())))?;
        let value = outputs
            .get(output)
            .ok_or_else(|| Error::Internal(format!("{}: output \"{output}\" missing from the run", self.path.display())))?;
        let (shape, data) = value
            .try_extract_tensor::<f32>()
            .map_err(|e| Error::input(&self.path, format!("output \"{output}\" is not a float32 tensor: {e}")))?;
        let bad = data.iter().filter(|v| !v.is_finite()).count();
        if bad > 0 {
            return Err(Error::input(
                &self.path,
                format!("the model's output \"{output}\" contains {bad} NaN/Inf value(s) of {} (a broken or mis-fed model)", data.len()),
            ));
        }
        Ok((shape.iter().copied().collect(), data.to_vec()))
    }
}
