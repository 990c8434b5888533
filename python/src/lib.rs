//! `drbokeh._drbokeh`: the library's pipeline, renderer and backward pass for NumPy.
//!
//! The bindings only translate: arrays become [`Image`]s (one copy in) and [`Layer`]s (over
//! NumPy's buffer when it is C-ordered, else a copy), checked as the CLI checks files;
//! keyword arguments become a [`Config`] (parsed by the same serde definitions as
//! `pipeline.toml`, so the same names and messages), and results go back to NumPy without a
//! copy (the `Vec` becomes the array's buffer). The GIL is released while Rust works. Errors:
//! usage and input problems raise `ValueError`, I/O `OSError`, each with the library's
//! message. Conventions: images are H×W×C float32 (linear RGB unless said), layers H×W×5
//! (straight, not premultiplied, colour R, G, B; alpha A; normalized disparity D, 0 far … 1
//! near), front first.

use drbokeh::config::{ApertureConfig, Config};
use drbokeh::pipeline::{BuildLayers, Focus, Pipeline, Scene};
use drbokeh::render::backward::{Smoothing, Tape};
use drbokeh::render::{Layer, RenderSettings};
use drbokeh::stages::depth::{DepthKind, normalize};
use drbokeh::{Error, Image, PhotoEncoding};
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray3, PyArrayDyn, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyOSError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use rayon::prelude::*;
use std::path::PathBuf;

/// The extension's own allocator (its Rust allocations only; the interpreter and NumPy keep
/// theirs). A render allocates and frees frame-sized buffers stage after stage; glibc, in an
/// interpreter whose earlier allocations moved its mmap threshold, maps each afresh and pays
/// page faults and zeroing on every call (+28-51% over the same render from Rust, 1 MP, idle
/// machine; issue 37). mimalloc keeps freed pages for the next buffer: +6.5-8.1% in the same
/// window, the peak 3% higher at 6 MP, and the pages kept between calls (`release_memory`
/// hands them back). Measured with `scripts/python_overhead.py`; `docs/python.md` has the
/// figures.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// The library's error as the Python exception a user expects.
fn py_err(e: Error) -> PyErr {
    match e {
        Error::Io { .. } => PyOSError::new_err(e.to_string()),
        Error::Internal(_) => pyo3::exceptions::PyRuntimeError::new_err(e.to_string()),
        _ => PyValueError::new_err(e.to_string()),
    }
}

/// A float32 array of `name`, H×W (one channel) or H×W×C with C one of `channels`, not empty:
/// the array borrowed read-only (NumPy's buffer, not copied) and its `(h, w, c)`.
fn array_of<'py>(name: &str, a: &Bound<'py, PyAny>, channels: &[usize]) -> PyResult<(PyReadonlyArrayDyn<'py, f32>, (usize, usize, usize))> {
    let arr = a.cast::<PyArrayDyn<f32>>().map_err(|_| {
        let dtype = a.getattr("dtype").map(|d| d.to_string()).unwrap_or_else(|_| a.get_type().to_string());
        PyTypeError::new_err(format!("{name} must be a float32 NumPy array, not {dtype}"))
    })?;
    let ro = arr.readonly();
    let shape = ro.shape().to_vec();
    let (h, w, c) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, c] => (h, w, c),
        _ => return Err(PyValueError::new_err(format!("{name} must be H x W or H x W x C, not of shape {shape:?}"))),
    };
    if !channels.contains(&c) {
        return Err(PyValueError::new_err(format!("{name} has {c} channels (shape {shape:?}); expected {channels:?}")));
    }
    if h == 0 || w == 0 {
        return Err(PyValueError::new_err(format!("{name} is empty (shape {shape:?})")));
    }
    Ok((ro, (h, w, c)))
}

/// A float32 array of `name` as an image (see [`array_of`]), any strides, every value copied
/// once.
fn image_of(name: &str, a: &Bound<'_, PyAny>, channels: &[usize]) -> PyResult<Image> {
    let (ro, hwc) = array_of(name, a, channels)?;
    copied(name, &ro, hwc)
}

/// The values of `ro` (of shape `(h, w, c)`) copied into an image. A C-ordered buffer is
/// copied as it is, on every thread (a 1 MP layer is 20 MB: one thread's copy was most of the
/// call's overhead over the library's render, issue 37); any other layout (Fortran order,
/// strides) in logical row-major order.
fn copied(name: &str, ro: &PyReadonlyArrayDyn<'_, f32>, (h, w, c): (usize, usize, usize)) -> PyResult<Image> {
    let data: Vec<f32> = match ro.as_slice() {
        Ok(s) if ro.is_c_contiguous() => {
            let mut v = Vec::new();
            s.par_iter().copied().collect_into_vec(&mut v);
            v
        }
        _ => ro.as_array().iter().copied().collect(),
    };
    Image::from_vec(w, h, c, data).ok_or_else(|| PyValueError::new_err(format!("{name}: {w}x{h}x{c} is too large")))
}

/// A photo: uint8 / uint16 (sRGB, as the CLI decodes 8/16-bit files) or float32 (linear),
/// H×W×3 (or ×4, alpha dropped; or H×W grey).
fn photo_of(a: &Bound<'_, PyAny>, gamma: Option<f32>) -> PyResult<(Image, PhotoEncoding)> {
    use drbokeh::color::Transfer;
    let transfer = gamma.map(Transfer::Gamma).unwrap_or(Transfer::Srgb);
    let integer = |bits: u8, values: Vec<f32>, shape: &[usize]| -> PyResult<(Image, PhotoEncoding)> {
        let scale = ((1u32 << bits) - 1) as f32;
        let raw = to_rgb("image", values.into_iter().map(|v| transfer.decode(v / scale)).collect(), shape)?;
        Ok((raw, PhotoEncoding::Integer { bits, transfer }))
    };
    if let Ok(a8) = a.cast::<PyArrayDyn<u8>>() {
        let ro = a8.readonly();
        return integer(8, ro.as_array().iter().map(|&v| v as f32).collect(), ro.shape());
    }
    if let Ok(a16) = a.cast::<PyArrayDyn<u16>>() {
        let ro = a16.readonly();
        return integer(16, ro.as_array().iter().map(|&v| v as f32).collect(), ro.shape());
    }
    let img = image_of("image", a, &[1, 3, 4])?;
    let shape = [img.height, img.width, img.channels];
    let rgb = to_rgb("image", img.data, &shape)?;
    if rgb.data.iter().any(|v| !v.is_finite()) {
        return Err(PyValueError::new_err("image holds a non-finite value (NaN or infinity)"));
    }
    Ok((rgb, PhotoEncoding::Linear))
}

/// `values` of `shape` (H×W, H×W×1, ×3 or ×4) as three-channel RGB.
fn to_rgb(name: &str, values: Vec<f32>, shape: &[usize]) -> PyResult<Image> {
    let (h, w, c) = match shape[..] {
        [h, w] => (h, w, 1),
        [h, w, c] if [1, 3, 4].contains(&c) => (h, w, c),
        _ => return Err(PyValueError::new_err(format!("{name} must be H x W, H x W x 3 or H x W x 4, not of shape {shape:?}"))),
    };
    if h == 0 || w == 0 {
        return Err(PyValueError::new_err(format!("{name} is empty (shape {shape:?})")));
    }
    let data = match c {
        3 => values,
        1 => values.iter().flat_map(|&v| [v, v, v]).collect(),
        _ => values.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect(),
    };
    Image::from_vec(w, h, 3, data).ok_or_else(|| PyValueError::new_err(format!("{name}: {w}x{h}x3 is too large")))
}

/// A Python layer's values for the length of a call: NumPy's buffer itself when the array is
/// C-ordered (a 1 MP layer is 20 MB: copying two in was most of the call's overhead over the
/// library's render, issue 37), else a row-major copy.
enum Held<'py> {
    Borrowed(PyReadonlyArrayDyn<'py, f32>),
    Copied(Image),
}

/// A Python list of H×W×5 float32 arrays, held while a call's layers use them.
struct HeldLayers<'py>(Vec<(String, (usize, usize), Held<'py>)>);

impl<'py> HeldLayers<'py> {
    /// The arrays of `layers` (any iterable), checked for type and shape.
    fn of(layers: &Bound<'py, PyAny>) -> PyResult<Self> {
        let list: Vec<Bound<'py, PyAny>> = layers.try_iter()?.collect::<PyResult<_>>()?;
        if list.is_empty() {
            return Err(PyValueError::new_err("layers is empty: give at least one H x W x 5 layer"));
        }
        let held = list.iter().enumerate().map(|(k, a)| {
            let name = format!("layers[{k}]");
            let (ro, hwc @ (h, w, _)) = array_of(&name, a, &[5])?;
            let held = if ro.is_c_contiguous() { Held::Borrowed(ro) } else { Held::Copied(copied(&name, &ro, hwc)?) };
            Ok((name, (w, h), held))
        });
        Ok(HeldLayers(held.collect::<PyResult<_>>()?))
    }

    /// The layers, checked as layer files are (every value finite), over the held values;
    /// the check runs without the GIL.
    fn layers(&self, py: Python<'_>) -> PyResult<Vec<Layer<'_>>> {
        let views: Vec<(&str, (usize, usize), &[f32])> = self
            .0
            .iter()
            .map(|(name, size, held)| {
                let data = match held {
                    Held::Borrowed(ro) => ro.as_slice().expect("a C-ordered array is one slice"),
                    Held::Copied(img) => &img.data[..],
                };
                (name.as_str(), *size, data)
            })
            .collect();
        py.detach(|| views.iter().map(|&(name, (w, h), data)| Layer::borrowed(w, h, data, name)).collect::<drbokeh::Result<_>>())
            .map_err(py_err)
    }
}

/// The library's warnings (a clamped focus, an ignored setting...) as Python `UserWarning`s.
fn warn_all(py: Python<'_>, warnings: &[String]) -> PyResult<()> {
    let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
    for w in warnings {
        let msg = std::ffi::CString::new(w.replace('\0', " ")).expect("no NUL left");
        PyErr::warn(py, &category, &msg, 1)?;
    }
    Ok(())
}

/// NumPy arrays handed back, one per layer.
type Arrays<'py> = Vec<Bound<'py, PyArray3<f32>>>;

/// An image as an H×W×C NumPy array, without a copy.
fn to_numpy<'py>(py: Python<'py>, img: Image) -> Bound<'py, PyArray3<f32>> {
    let (h, w, c) = (img.height, img.width, img.channels);
    Array3::from_shape_vec((h, w, c), img.data).expect("an image's length is its shape").into_pyarray(py)
}

/// The settings of a call: a `pipeline.toml` (or defaults) with keyword arguments on top.
#[derive(Default)]
struct Settings {
    config: Option<PathBuf>,
    profile: Option<String>,
    kernel: Option<String>,
    quality: Option<u32>,
    occlusion: Option<bool>,
    lens: Option<usize>,
    blur: Option<f32>,
    aperture: Option<ApertureConfig>,
}

/// One config value from a Python string through the serde definition `pipeline.toml` uses
/// (same names, same messages).
fn parse_value<T: serde::de::DeserializeOwned>(key: &str, value: &str) -> PyResult<T> {
    parse_literal(key, &toml_string(value), &format!("{value:?}"))
}

/// A TOML literal (`"auto"`, `3`) as the value of `key`, through the same definitions;
/// `shown` is the value as the user gave it, for the message.
fn parse_literal<T: serde::de::DeserializeOwned>(key: &str, literal: &str, shown: &str) -> PyResult<T> {
    #[derive(serde::Deserialize)]
    struct One<T> {
        v: T,
    }
    toml::from_str::<One<T>>(&format!("v = {literal}"))
        .map(|o| o.v)
        .map_err(|e| PyValueError::new_err(format!("{key} = {shown}: {}", e.message())))
}

/// `s` as a TOML basic string.
fn toml_string(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_control() => out.push_str(&format!("\\u{:04X}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `aperture=`: a shape as `--aperture` spells it (`"blades:6,rotation=30"`), or a dict of
/// `pipeline.toml`'s `[aperture]` keys (`shape`, `anamorphic`, `bubble`, `chromatic`,
/// `cat_eye`), read through that table's definition (same names, same messages). None: the
/// disc.
fn aperture_of(a: Option<&Bound<'_, PyAny>>) -> PyResult<Option<ApertureConfig>> {
    let Some(a) = a.filter(|a| !a.is_none()) else { return Ok(None) };
    if let Ok(shape) = a.extract::<String>() {
        return Ok(Some(ApertureConfig { shape, ..ApertureConfig::default() }));
    }
    let bad = || {
        PyTypeError::new_err(
            "aperture: a shape string (\"blades:6,rotation=30\") or a dict of [aperture]'s keys (shape, anamorphic, bubble, chromatic, cat_eye)",
        )
    };
    let dict = a.cast::<pyo3::types::PyDict>().map_err(|_| bad())?;
    let mut entries = Vec::new();
    for (k, v) in dict.iter() {
        let key: String = k.extract().map_err(|_| bad())?;
        let value = if let Ok(s) = v.extract::<String>() {
            toml_string(&s)
        } else if v.is_instance_of::<pyo3::types::PyBool>() {
            return Err(PyTypeError::new_err(format!("aperture[{key:?}]: a number or a string, not a bool")));
        } else {
            let x: f64 = v.extract().map_err(|_| PyTypeError::new_err(format!("aperture[{key:?}]: a number or a string")))?;
            if !x.is_finite() {
                return Err(PyValueError::new_err(format!("aperture[{key:?}] = {x}: must be finite")));
            }
            format!("{x:?}")
        };
        entries.push(format!("{} = {value}", toml_string(&key)));
    }
    parse_literal("aperture", &format!("{{ {} }}", entries.join(", ")), &a.repr().map(|r| r.to_string()).unwrap_or_default()).map(Some)
}

/// The differentiable renders' aperture: the disc without one.
fn resolved_aperture(a: Option<&ApertureConfig>) -> PyResult<drbokeh::render::Aperture> {
    a.map_or(Ok(drbokeh::render::Aperture::DISC), |a| a.resolve().map_err(py_err))
}

impl Settings {
    fn config(&self, py: Python<'_>, layer_count: Option<&Bound<'_, PyAny>>) -> PyResult<Config> {
        let mut cfg = match &self.config {
            Some(p) => py.detach(|| Config::load(p)).map_err(py_err)?,
            None => Config::default(),
        };
        let r = &mut cfg.render;
        if let Some(p) = &self.profile {
            r.profile = parse_value("profile", p)?;
        }
        if let Some(k) = &self.kernel {
            r.kernel = parse_value("kernel", k)?;
        }
        if let Some(q) = self.quality {
            r.quality = q;
        }
        if let Some(o) = self.occlusion {
            r.occlusion = o;
        }
        if self.lens.is_some() {
            r.lens = self.lens;
        }
        if self.blur.is_some() {
            r.blur = self.blur;
        }
        if let Some(a) = &self.aperture {
            cfg.aperture = a.clone();
        }
        if let Some(n) = layer_count {
            cfg.segment.layers = if let Ok(s) = n.extract::<String>() {
                parse_value("layers", &s)?
            } else {
                let k: i64 = n.extract().map_err(|_| PyTypeError::new_err("layers must be an int or \"auto\""))?;
                parse_literal("layers", &k.to_string(), &k.to_string())?
            };
        }
        cfg.validate().map_err(py_err)?;
        Ok(cfg)
    }
}

/// Runs `f` with the GIL released, on `threads` threads (None: every core).
fn run<T: Send>(py: Python<'_>, threads: Option<usize>, f: impl FnOnce() -> drbokeh::Result<T> + Send) -> PyResult<T> {
    py.detach(|| match threads {
        None => f(),
        Some(n) => {
            let n = drbokeh::resources::check_threads(n, "threads")?;
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| Error::usage(format!("threads = {n}: cannot start the thread pool: {e}")))?;
            pool.install(f)
        }
    })
    .map_err(py_err)
}

/// The focus of the keyword arguments: exactly one of focus (normalized disparity), focus_at
/// (x, y) and focus_depth (metric depth).
fn focus_of(focus: Option<f32>, focus_at: Option<(i64, i64)>, focus_depth: Option<f64>) -> PyResult<Focus> {
    match (focus, focus_at, focus_depth) {
        (Some(f), None, None) => Ok(Focus::Disparity(f)),
        (None, Some((x, y)), None) => Ok(Focus::At(x, y)),
        (None, None, Some(z)) => Ok(Focus::Depth(z)),
        _ => Err(PyValueError::new_err("give exactly one of focus (normalized disparity), focus_at=(x, y) and focus_depth")),
    }
}

/// The scene of a photo, a depth map (any size of the photo's aspect ratio) and a matte.
fn scene_of(
    py: Python<'_>,
    image: &Bound<'_, PyAny>,
    depth: &Bound<'_, PyAny>,
    matte: Option<&Bound<'_, PyAny>>,
    depth_kind: &str,
    cfg: &Config,
) -> PyResult<Scene> {
    let (rgb, encoding) = photo_of(image, cfg.render.gamma)?;
    let raw = image_of("depth", depth, &[1])?;
    let kind: DepthKind = parse_value("depth_kind", depth_kind)?;
    let matte = matte.map(|m| image_of("matte", m, &[1])).transpose()?;
    py.detach(move || -> drbokeh::Result<Scene> {
        let (w, h) = (rgb.width, rgb.height);
        let fits = |what: &str, img: &Image| -> drbokeh::Result<()> {
            if drbokeh::io::embedded_depth::same_aspect((img.width, img.height), (w, h)) {
                Ok(())
            } else {
                Err(Error::usage(format!("{what} is {}x{} but the image is {w}x{h} (a different aspect ratio)", img.width, img.height)))
            }
        };
        fits("depth", &raw)?;
        let mut disparity = normalize(&raw, kind, "depth".as_ref())?;
        if (disparity.map.width, disparity.map.height) != (w, h) {
            disparity.map = disparity.map.resized(w, h);
        }
        let matte = match matte {
            Some(m) => {
                fits("matte", &m)?;
                if m.data.iter().any(|v| !v.is_finite() || *v < 0.0 || *v > 1.0) {
                    return Err(Error::usage("matte must hold values in [0, 1]"));
                }
                Some(if (m.width, m.height) == (w, h) { m } else { m.resized(w, h) })
            }
            None => None,
        };
        Ok(Scene { rgb, disparity, matte, encoding })
    })
    .map_err(py_err)
}

/// What `render` and `build_layers` share: the focus, the configuration and the scene.
#[allow(clippy::too_many_arguments)]
fn photo_job(
    py: Python<'_>,
    (image, depth, matte): (&Bound<'_, PyAny>, &Bound<'_, PyAny>, Option<&Bound<'_, PyAny>>),
    (focus, focus_at, focus_depth): (Option<f32>, Option<(i64, i64)>, Option<f64>),
    depth_kind: &str,
    settings: Settings,
    layers: Option<&Bound<'_, PyAny>>,
) -> PyResult<(Focus, Config, Scene)> {
    let f = focus_of(focus, focus_at, focus_depth)?;
    let cfg = settings.config(py, layers)?;
    let scene = scene_of(py, image, depth, matte, depth_kind, &cfg)?;
    Ok((f, cfg, scene))
}

/// Renders a photo with its depth map: the whole pipeline, the defaults and checks of
/// `drbokeh render`. Returns H×W×3 linear RGB float32. `aperture`: the bokeh's shape, a
/// string as `--aperture` spells it or a dict of `[aperture]`'s keys (every function taking
/// it reads it so).
#[pyfunction]
#[pyo3(signature = (image, depth, *, matte=None, focus=None, focus_at=None, focus_depth=None, blur=None, depth_kind="depth", profile=None, kernel=None, layers=None, config=None, threads=None, aperture=None))]
#[allow(clippy::too_many_arguments)]
fn render<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    matte: Option<&Bound<'py, PyAny>>,
    focus: Option<f32>,
    focus_at: Option<(i64, i64)>,
    focus_depth: Option<f64>,
    blur: Option<f32>,
    depth_kind: &str,
    profile: Option<String>,
    kernel: Option<String>,
    layers: Option<&Bound<'py, PyAny>>,
    config: Option<PathBuf>,
    threads: Option<usize>,
    aperture: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let settings = Settings { config, profile, kernel, blur, aperture: aperture_of(aperture)?, ..Settings::default() };
    let (f, cfg, scene) = photo_job(py, (image, depth, matte), (focus, focus_at, focus_depth), depth_kind, settings, layers)?;
    let pipeline = Pipeline::from_config(cfg).map_err(py_err)?;
    let outcome = run(py, threads, || pipeline.run(&scene, f))?;
    warn_all(py, &outcome.report.warnings)?;
    let mut out = outcome.image;
    // As `drbokeh render` writes it (in gamma mode, shown as out^(1/G)).
    drbokeh::job::display_transfer(&mut out, pipeline.config());
    Ok(to_numpy(py, out))
}

/// The layers the pipeline renders for a photo (front first, each H×W×5: R, G, B, A, D),
/// built for the given focus and blur (what is hidden behind the foreground is filled as far
/// as that blur reaches).
#[pyfunction]
#[pyo3(signature = (image, depth, *, matte=None, focus=None, focus_at=None, focus_depth=None, blur=None, depth_kind="depth", layers=None, config=None, threads=None))]
#[allow(clippy::too_many_arguments)]
fn build_layers<'py>(
    py: Python<'py>,
    image: &Bound<'py, PyAny>,
    depth: &Bound<'py, PyAny>,
    matte: Option<&Bound<'py, PyAny>>,
    focus: Option<f32>,
    focus_at: Option<(i64, i64)>,
    focus_depth: Option<f64>,
    blur: Option<f32>,
    depth_kind: &str,
    layers: Option<&Bound<'py, PyAny>>,
    config: Option<PathBuf>,
    threads: Option<usize>,
) -> PyResult<Arrays<'py>> {
    let settings = Settings { config, blur, ..Settings::default() };
    let (f, cfg, scene) = photo_job(py, (image, depth, matte), (focus, focus_at, focus_depth), depth_kind, settings, layers)?;
    let out = run(py, threads, move || Pipeline::from_config(cfg)?.run_with(&scene, f, BuildLayers::Only))?;
    warn_all(py, &out.report.warnings)?;
    Ok(out.layers.into_iter().map(|l| to_numpy(py, l.into_image())).collect())
}

/// Renders given layers (front first, each H×W×5 float32: R, G, B, A, D) at `focus`
/// (normalized disparity) and `blur` (K, CoC radius in pixels per unit of disparity), as
/// `drbokeh render --layer`. Returns H×W×3 linear RGB float32.
#[pyfunction]
#[pyo3(signature = (layers, focus, blur, *, profile=None, kernel=None, quality=None, occlusion=None, lens=None, threads=None, aperture=None))]
#[allow(clippy::too_many_arguments)]
fn render_layers<'py>(
    py: Python<'py>,
    layers: &Bound<'py, PyAny>,
    focus: f32,
    blur: f32,
    profile: Option<String>,
    kernel: Option<String>,
    quality: Option<u32>,
    occlusion: Option<bool>,
    lens: Option<usize>,
    threads: Option<usize>,
    aperture: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let held = HeldLayers::of(layers)?;
    let layers = held.layers(py)?;
    let s =
        Settings { profile, kernel, quality, occlusion, lens, blur: Some(blur), aperture: aperture_of(aperture)?, ..Settings::default() };
    let cfg = s.config(py, None)?;
    // The layers are borrowed: the render gives them back (`refocus`), not the pipeline.
    let (image, report) = run(py, threads, move || Pipeline::from_config(cfg)?.refocus(&layers, Focus::Disparity(focus), None))?;
    warn_all(py, &report.warnings)?;
    Ok(to_numpy(py, image))
}

/// The differentiable render's settings from keyword arguments.
fn diff_settings(
    layers: &[Layer],
    focus: f32,
    blur: f32,
    profile: Option<&str>,
    occlusion: bool,
    lens: Option<usize>,
    aperture: Option<&Bound<'_, PyAny>>,
) -> PyResult<RenderSettings> {
    let profile = match profile {
        Some(p) => parse_value("profile", p)?,
        None => drbokeh::render::Profile::default(),
    };
    drbokeh::render::check_blur("blur", blur).map_err(py_err)?;
    let aperture = resolved_aperture(aperture_of(aperture)?.as_ref())?;
    // The window holds the largest channel's circle (chromatic aberration scales K).
    let lens = lens.unwrap_or_else(|| drbokeh::render::auto_lens(layers, blur * aperture.max_channel_scale(), focus));
    Ok(RenderSettings { blur, focus, lens, occlusion, profile, aperture })
}

/// The function `render_layers_vjp` differentiates: the exact kernel's render of `layers`
/// (the physical profile's disk edges rounded over `edge_width` pixels, its depth groups' fill
/// rule over `fill_width`). H×W×3 linear RGB float32.
#[pyfunction]
#[pyo3(signature = (layers, focus, blur, *, profile=None, occlusion=true, lens=None, edge_width=1.0, fill_width=0.0, threads=None, aperture=None))]
#[allow(clippy::too_many_arguments)]
fn render_layers_differentiable<'py>(
    py: Python<'py>,
    layers: &Bound<'py, PyAny>,
    focus: f32,
    blur: f32,
    profile: Option<String>,
    occlusion: bool,
    lens: Option<usize>,
    edge_width: f32,
    fill_width: f32,
    threads: Option<usize>,
    aperture: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let held = HeldLayers::of(layers)?;
    let layers = held.layers(py)?;
    let s = diff_settings(&layers, focus, blur, profile.as_deref(), occlusion, lens, aperture)?;
    let smoothing = Smoothing { edge_width, fill_width };
    let image = run(py, threads, move || Tape::record(&layers, &s, smoothing).map(|t| t.image().clone()))?;
    Ok(to_numpy(py, image))
}

/// The vector-Jacobian product of [`render_layers_differentiable`]: for the cotangent
/// (H×W×3, ∂loss/∂image), returns `(layer_grads, d_focus, d_blur)`, `layer_grads` one H×W×5
/// array per layer (∂loss/∂ R, G, B, A, D).
#[pyfunction]
#[pyo3(signature = (layers, focus, blur, cotangent, *, profile=None, occlusion=true, lens=None, edge_width=1.0, fill_width=0.0, threads=None, aperture=None))]
#[allow(clippy::too_many_arguments)]
fn render_layers_vjp<'py>(
    py: Python<'py>,
    layers: &Bound<'py, PyAny>,
    focus: f32,
    blur: f32,
    cotangent: &Bound<'py, PyAny>,
    profile: Option<String>,
    occlusion: bool,
    lens: Option<usize>,
    edge_width: f32,
    fill_width: f32,
    threads: Option<usize>,
    aperture: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Arrays<'py>, f32, f32)> {
    let held = HeldLayers::of(layers)?;
    let layers = held.layers(py)?;
    let cot = image_of("cotangent", cotangent, &[3])?;
    let s = diff_settings(&layers, focus, blur, profile.as_deref(), occlusion, lens, aperture)?;
    let smoothing = Smoothing { edge_width, fill_width };
    let g = run(py, threads, move || Tape::record(&layers, &s, smoothing)?.vjp(&cot))?;
    Ok((g.layers.into_iter().map(|l| to_numpy(py, l)).collect(), g.focus, g.blur))
}

/// Depth from defocus, as `drbokeh dfd`: the disparity map (H×W float32 in [0, 1], the
/// units of `focus` and `blur`) that turns the all-in-focus photo `aif` into `bokeh`, the same
/// view focused at `focus` with blur `blur` (Adam through the differentiable renderer, coarse
/// to fine). Photos: uint8/uint16 sRGB or float32 linear, H×W×3. `loss`: "l1-grad",
/// "l1-grad-ssim" or "l1-grad-hssim"; `kernel`: "auto", "fast", "exact" or "ray".
#[pyfunction]
#[pyo3(signature = (aif, bokeh, focus, blur, *, iters=None, levels=None, learning_rate=None, init=None, loss=None, kernel=None, profile=None, occlusion=true, threads=None, aperture=None))]
#[allow(clippy::too_many_arguments)]
fn dfd<'py>(
    py: Python<'py>,
    aif: &Bound<'py, PyAny>,
    bokeh: &Bound<'py, PyAny>,
    focus: &Bound<'py, PyAny>,
    blur: f32,
    iters: Option<i64>,
    levels: Option<i64>,
    learning_rate: Option<f32>,
    init: Option<f32>,
    loss: Option<String>,
    kernel: Option<String>,
    profile: Option<String>,
    occlusion: bool,
    threads: Option<usize>,
    aperture: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, numpy::PyArray2<f32>>> {
    use drbokeh::diff::dfd::{self as d, DfdOptions, LossVariant};
    let (aif, _) = photo_of(aif, None)?;
    // A list or tuple of photos is a focal stack, with a list of foci (one per photo).
    let stack = bokeh.cast::<pyo3::types::PyList>().is_ok() || bokeh.cast::<pyo3::types::PyTuple>().is_ok();
    let (photos, foci): (Vec<Image>, Vec<f32>) = if stack {
        let photos = bokeh.try_iter()?.map(|p| photo_of(&p?, None).map(|(img, _)| img)).collect::<PyResult<Vec<_>>>()?;
        let foci: Vec<f32> = focus
            .extract()
            .map_err(|_| PyTypeError::new_err("focus: a focal stack (bokeh a list of photos) takes a list of foci, one per photo"))?;
        if foci.len() != photos.len() {
            return Err(PyValueError::new_err(format!(
                "{} defocused photo(s) but {} focus value(s): give one focal plane per photo, in the same order",
                photos.len(),
                foci.len()
            )));
        }
        (photos, foci)
    } else {
        let f: f32 = focus.extract().map_err(|_| PyTypeError::new_err("focus: a number (a list only with a list of photos)"))?;
        (vec![photo_of(bokeh, None)?.0], vec![f])
    };
    let defaults = DfdOptions::default();
    let mut opts = DfdOptions {
        iters: d::check_iters("iters", iters.unwrap_or(defaults.iters as i64)).map_err(py_err)?,
        levels: d::check_levels("levels", levels.unwrap_or(defaults.levels as i64)).map_err(py_err)?,
        learning_rate: learning_rate.unwrap_or(defaults.learning_rate),
        init: init.unwrap_or(defaults.init),
        ..defaults
    };
    if let Some(l) = &loss {
        opts.weights = parse_value::<LossVariant>("loss", l)?.weights();
    }
    if let Some(k) = &kernel {
        opts.kernel = parse_value("kernel", k)?;
    }
    let profile = match &profile {
        Some(p) => parse_value("profile", p)?,
        None => drbokeh::render::Profile::default(),
    };
    let aperture = resolved_aperture(aperture_of(aperture)?.as_ref())?;
    let s = RenderSettings { blur, focus: foci[0], lens: 1, occlusion, profile, aperture };
    let est = run(py, threads, move || {
        let shots: Vec<d::Shot> = photos.iter().zip(&foci).map(|(photo, &focus)| d::Shot::linear(photo, focus)).collect();
        d::estimate_stack(&aif, &shots, &s, &opts, |_| {})
    })?;
    warn_all(py, &est.warnings)?;
    let (h, w) = (est.disparity.height, est.disparity.width);
    let arr = numpy::ndarray::Array2::from_shape_vec((h, w), est.disparity.data).expect("a map's length is its shape");
    Ok(arr.into_pyarray(py))
}

/// Hands the memory the extension's allocator keeps for its next render back to the system.
/// Between calls the extension keeps the pages of its largest render (about 1 GB after a 6 MP
/// render of two layers; `docs/python.md`), so that the next render does not fault them in
/// again; a program that renders once, or seldom, and lives on can call this after. Results
/// already returned stay valid (NumPy owns them). The next render is slower by what it must map
/// afresh.
#[pyfunction]
fn release_memory(py: Python<'_>) {
    // Each rayon worker has its own heap, and mi_collect frees only the calling thread's (and
    // abandoned segments): so every worker collects, then this thread.
    // SAFETY: `mi_collect` only frees pages no live allocation uses; any thread may call it.
    py.detach(|| {
        rayon::broadcast(|_| unsafe { libmimalloc_sys::mi_collect(true) });
        unsafe { libmimalloc_sys::mi_collect(true) }
    });
}

/// The native module.
#[pymodule]
fn _drbokeh(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(render, m)?)?;
    m.add_function(wrap_pyfunction!(build_layers, m)?)?;
    m.add_function(wrap_pyfunction!(render_layers, m)?)?;
    m.add_function(wrap_pyfunction!(render_layers_differentiable, m)?)?;
    m.add_function(wrap_pyfunction!(render_layers_vjp, m)?)?;
    m.add_function(wrap_pyfunction!(dfd, m)?)?;
    m.add_function(wrap_pyfunction!(release_memory, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
