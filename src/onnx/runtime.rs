//! Finding and loading ONNX Runtime, once per process and only when a model is used.
//!
//! The library is loaded dynamically (the `ort` crate's `load-dynamic`): nothing is linked or
//! downloaded at build time, and runs that use no model never touch it. Search order:
//! `[onnx] runtime`, then `ORT_DYLIB_PATH`, then the project cache (the `onnxruntime` wheel in
//! `.venv/lib/python*/site-packages/onnxruntime/capi/`, installed by
//! `scripts/setup-test-env.sh`), then well-known system locations. An explicitly given path
//! that does not load is an error (never silently replaced by another library).

use super::config::OnnxConfig;
use crate::error::{Error, Result};
use crate::timing::ms_since;
use ort::environment::Environment;
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

/// The ONNX Runtime release the `ort` crate in use targets (API 1.31): install this version.
pub const ORT_VERSION: &str = "1.31.1";

const INSTALL_HINT: &str = "install ONNX Runtime with `scripts/setup-test-env.sh` (the `onnxruntime==1.31.1` wheel from PyPI into \
     the project's .venv) or `pip install onnxruntime==1.31.1`, then point `[onnx] runtime` or ORT_DYLIB_PATH at its \
     onnxruntime/capi/libonnxruntime.so.* (any ONNX Runtime >= 1.31 works)";

/// The loaded runtime.
pub struct Runtime {
    /// The shared library that was loaded.
    pub library: PathBuf,
    /// ONNX Runtime's version string, as the library reports it.
    pub version: String,
    /// The process-wide ONNX Runtime environment.
    pub env: Environment,
    /// How long loading the library and creating the environment took.
    pub load_ms: f64,
}

static RUNTIME: OnceLock<Runtime> = OnceLock::new();
static LOADING: Mutex<()> = Mutex::new(());

/// True once ONNX Runtime has been loaded in this process (tests use it to show laziness).
pub fn is_loaded() -> bool {
    RUNTIME.get().is_some()
}

/// The runtime, loading it on first use.
pub fn runtime(cfg: &OnnxConfig) -> Result<&'static Runtime> {
    if let Some(r) = RUNTIME.get() {
        return Ok(r);
    }
    let _guard = LOADING.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(r) = RUNTIME.get() {
        return Ok(r);
    }
    let t = std::time::Instant::now();
    let library = locate(cfg)?;
    let builder = ort::init_from(&library).map_err(|e| Error::input(&library, format!("cannot load ONNX Runtime: {e}; {INSTALL_HINT}")))?;
    let env = builder
        .with_name("drbokeh")
        .with_telemetry(false)
        .build()
        .map_err(|e| Error::input(&library, format!("cannot create the ONNX Runtime environment: {e}")))?;
    env.set_log_level(ort::logging::LogLevel::Error);
    let version = ort_version_string(&library);
    let rt = Runtime { library, version, env, load_ms: ms_since(t) };
    Ok(RUNTIME.get_or_init(|| rt))
}

/// The library's version string ("1.31.1"), from its `OrtGetApiBase()->GetVersionString()`.
/// The library is already loaded, so this only takes another reference to it.
fn ort_version_string(library: &Path) -> String {
    // SAFETY: `library` was just loaded successfully by `ort` (same process, same file), and
    // OrtGetApiBase / GetVersionString are the stable C entry points of every ONNX Runtime.
    unsafe {
        let Ok(lib) = libloading::Library::new(library) else { return String::new() };
        let Ok(get) = lib.get::<unsafe extern "C" fn() -> *const ort::sys::OrtApiBase>(b"OrtGetApiBase") else { return String::new() };
        let base = get();
        if base.is_null() {
            return String::new();
        }
        let v = ((*base).GetVersionString)();
        if v.is_null() { String::new() } else { std::ffi::CStr::from_ptr(v).to_string_lossy().into_owned() }
    }
}

/// Where the runtime library would be loaded from, without loading it.
pub fn locate(cfg: &OnnxConfig) -> Result<PathBuf> {
    if let Some(p) = &cfg.runtime {
        if !p.is_file() {
            return Err(Error::input(p, format!("ONNX Runtime library not found (from `[onnx] runtime`); {INSTALL_HINT}")));
        }
        return Ok(p.clone());
    }
    if let Some(p) = std::env::var_os("ORT_DYLIB_PATH").filter(|s| !s.is_empty()) {
        let p = PathBuf::from(p);
        if !p.is_file() {
            return Err(Error::input(&p, format!("ONNX Runtime library not found (from ORT_DYLIB_PATH); {INSTALL_HINT}")));
        }
        return Ok(p);
    }
    let candidates = candidates();
    for c in &candidates {
        if let Some(found) = find_lib_in(c) {
            return Ok(found);
        }
    }
    let searched: Vec<String> = candidates.iter().map(|p| p.display().to_string()).collect();
    Err(Error::input(
        lib_file_name(),
        format!("ONNX Runtime library not found (searched `[onnx] runtime`, ORT_DYLIB_PATH, {}); {INSTALL_HINT}", searched.join(", ")),
    ))
}

fn lib_file_name() -> String {
    format!("{}onnxruntime{}", std::env::consts::DLL_PREFIX, std::env::consts::DLL_SUFFIX)
}

/// Folders that may hold the library: the project cache above the executable, the working
/// directory and the source tree, then system folders.
fn candidates() -> Vec<PathBuf> {
    let mut roots: Vec<PathBuf> = Vec::new();
    if let Ok(exe) = std::env::current_exe() {
        roots.extend(exe.ancestors().skip(1).map(Path::to_path_buf));
    }
    if let Ok(cwd) = std::env::current_dir() {
        roots.extend(cwd.ancestors().map(Path::to_path_buf));
    }
    roots.push(PathBuf::from(env!("CARGO_MANIFEST_DIR")));
    let mut out = Vec::new();
    for r in roots {
        let lib = r.join(".venv").join("lib");
        if let Ok(rd) = std::fs::read_dir(&lib) {
            let mut pys: Vec<PathBuf> = rd.filter_map(|e| e.ok()).map(|e| e.path()).filter(|p| p.join("site-packages").is_dir()).collect();
            pys.sort();
            for py in pys {
                let capi = py.join("site-packages").join("onnxruntime").join("capi");
                if !out.contains(&capi) {
                    out.push(capi);
                }
            }
        }
    }
    for sys in [
        "/usr/local/lib",
        "/usr/lib",
        "/usr/lib/x86_64-linux-gnu",
        "/usr/lib/aarch64-linux-gnu",
        "/opt/onnxruntime/lib",
        "/opt/homebrew/lib",
    ] {
        out.push(PathBuf::from(sys));
    }
    out
}

/// `libonnxruntime.so` or the newest `libonnxruntime.so.X.Y.Z` in `dir`.
fn find_lib_in(dir: &Path) -> Option<PathBuf> {
    let name = lib_file_name();
    let exact = dir.join(&name);
    if exact.is_file() {
        return Some(exact);
    }
    let mut versioned: Vec<PathBuf> = std::fs::read_dir(dir)
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path())
        .filter(|p| {
            p.file_name().and_then(|f| f.to_str()).is_some_and(|f| {
                f.strip_prefix(name.as_str())
                    .is_some_and(|rest| rest.starts_with('.') && rest[1..].chars().all(|c| c.is_ascii_digit() || c == '.'))
            })
        })
        .collect();
    versioned.sort();
    versioned.pop()
}
