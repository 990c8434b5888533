//! The interactive refocus page's HTTP API (`drbokeh view`), independent of the server: a
//! request (method, URL) in, a reply (status, content type, bytes) out.
//!
//! Contract:
//! - The layers are built once (by the caller, [`crate::job::build_layers`]); every reply is
//!   rendered from them with [`Pipeline::refocus`]. `GET /render` at the full width equals
//!   `drbokeh render --layer ...` of those layers at the same focus and blur, bit for bit (the
//!   same PNG encoder and display transfer, [`crate::job::display_transfer`]).
//! - Endpoints: `GET /` (the page), `GET /info` (JSON: size, layers, default and largest blur,
//!   output), `GET /render?focus=F|focus_at=X,Y&blur=K[&width=W][&profile=P][&quality=Q]`
//!   (PNG, 8-bit sRGB; `width` < the photo's renders a preview from layers scaled to that
//!   width, the blur scaled alike, `focus_at` in the photo's pixels), `GET /depth?x=X&y=Y`
//!   (JSON: the disparity a click there focuses on), `GET /overlay?kind=depth|matte[&width=W]`
//!   (PNG grey: the layers' disparity, front-most opaque layer first, or the front layer's
//!   alpha), `POST /save?focus=..|focus_at=..&blur=..[&profile=..][&quality=..]` (renders full
//!   size, writes the output chosen at start atomically, JSON with the path and the equivalent
//!   `drbokeh render` command line).
//! - Bad requests: 400 with `{"error": "..."}` naming the parameter (an unknown one, a missing
//!   or doubled focus, a value out of range, a pixel outside the photo); an unknown path 404;
//!   another method 405. No request chooses a file: `/save` writes only the output fixed at
//!   start.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::pipeline::{Focus, Pipeline, disparity_at};
use crate::render::Layer;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

/// The page (plain HTML and JavaScript, no build step, nothing fetched from elsewhere).
pub const PAGE: &str = include_str!("view/page.html");

/// The largest blur the page's slider offers, as a multiple of the default blur.
pub const BLUR_RANGE: f32 = 2.0;

/// An HTTP reply.
#[derive(Clone, Debug, PartialEq)]
pub struct Reply {
    /// Status code.
    pub status: u16,
    /// `Content-Type`.
    pub content_type: &'static str,
    /// The body.
    pub body: Vec<u8>,
}

impl Reply {
    fn json(status: u16, v: serde_json::Value) -> Reply {
        Reply { status, content_type: "application/json", body: v.to_string().into_bytes() }
    }

    fn error(status: u16, msg: impl Into<String>) -> Reply {
        Reply::json(status, serde_json::json!({ "error": msg.into() }))
    }

    fn png(body: Vec<u8>) -> Reply {
        Reply { status: 200, content_type: "image/png", body }
    }
}

/// Layers scaled to a preview width, and their scale.
struct Preview {
    layers: Vec<Layer<'static>>,
    scale: f32,
}

/// What `drbokeh view` serves (see the module doc).
pub struct Viewer {
    config: Config,
    layers: Vec<Layer<'static>>,
    blur: f32,
    output: PathBuf,
    /// `drbokeh render` and its input arguments, for the command line `/save` shows.
    command: Vec<String>,
    previews: Mutex<HashMap<usize, Arc<Preview>>>,
}

/// The settings of one `/render` or `/save`.
struct Ask {
    focus: Focus,
    blur: f32,
    width: Option<usize>,
    profile: Option<crate::render::Profile>,
    quality: Option<u32>,
    /// `--aperture` and `--anamorphic`, as given (checked when the pipeline is built).
    aperture: Option<String>,
    anamorphic: Option<f32>,
    /// `--bubble` and `--chromatic`, as given (checked when the pipeline is built).
    bubble: Option<f32>,
    chromatic: Option<f32>,
    /// `--cat-eye`, as given.
    cat_eye: Option<f32>,
}

impl Viewer {
    /// A viewer of `layers` (front first) rendered with `config`; `blur` the default blur K,
    /// `output` the file `/save` writes, `command` the `drbokeh render ...` arguments that
    /// read the same inputs (without focus, blur and output).
    pub fn new(config: Config, layers: Vec<Layer<'static>>, blur: f32, output: PathBuf, command: Vec<String>) -> Result<Viewer> {
        let Some(first) = layers.first() else { return Err(Error::usage("no layers to view")) };
        let size = (first.width(), first.height());
        if layers.iter().any(|l| (l.width(), l.height()) != size) {
            return Err(Error::usage("the layers differ in size"));
        }
        crate::render::check_blur("render.blur", blur)?;
        Ok(Viewer { config, layers, blur, output, command, previews: Mutex::new(HashMap::new()) })
    }

    /// The photo's size.
    pub fn size(&self) -> (usize, usize) {
        (self.layers[0].width(), self.layers[0].height())
    }

    /// Answers one request (see the module doc); never panics on what a client sends.
    pub fn handle(&self, method: &str, url: &str) -> Reply {
        let (path, query) = url.split_once('?').unwrap_or((url, ""));
        let params: Vec<(String, String)> = form_urlencoded::parse(query.as_bytes()).into_owned().collect();
        let r = match (method, path) {
            ("GET", "/") => Ok(Reply { status: 200, content_type: "text/html; charset=utf-8", body: PAGE.as_bytes().to_vec() }),
            ("GET", "/info") => Ok(self.info()),
            ("GET", "/render") => self.render(&params),
            ("GET", "/depth") => self.depth(&params),
            ("GET", "/overlay") => self.overlay(&params),
            ("POST", "/save") => self.save(&params),
            (_, "/" | "/info" | "/render" | "/depth" | "/overlay" | "/save") => {
                return Reply::error(405, format!("{method} is not allowed on {path}"));
            }
            _ => return Reply::error(404, format!("no such page: {path}")),
        };
        r.unwrap_or_else(|e| match e {
            Error::Usage(m) | Error::Input { msg: m, .. } => Reply::error(400, m),
            other => Reply::error(500, other.to_string()),
        })
    }

    fn info(&self) -> Reply {
        let (w, h) = self.size();
        Reply::json(
            200,
            serde_json::json!({
                "width": w, "height": h, "layers": self.layers.len(), "blur": self.blur,
                "blur_max": self.blur * BLUR_RANGE, "output": self.output.display().to_string(),
                "profile": self.config.render.profile, "quality": self.config.render.quality,
                "aperture": self.config.aperture.shape, "anamorphic": self.config.aperture.anamorphic,
                "bubble": self.config.aperture.bubble, "chromatic": self.config.aperture.chromatic,
                "cat_eye": self.config.aperture.cat_eye,
            }),
        )
    }

    /// The parameters of `/render` and `/save`, checked.
    fn ask(&self, params: &[(String, String)], allow_width: bool) -> Result<Ask> {
        let (w, h) = self.size();
        let mut focus = None;
        let (mut blur, mut width, mut profile, mut quality) = (None, None, None, None);
        let (mut aperture, mut anamorphic, mut bubble, mut chromatic, mut cat_eye) = (None, None, None, None, None);
        for (k, v) in params {
            let dup = || Error::usage(format!("{k} is given twice"));
            let number = |what: &str| -> Result<f64> {
                v.trim().parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| Error::usage(format!("{k} = {v:?}: {what}")))
            };
            match k.as_str() {
                "focus" | "focus_at" if focus.is_some() => {
                    return Err(Error::usage("give one of focus and focus_at, once"));
                }
                "focus" => focus = Some(Focus::Disparity(number("a finite normalized disparity")? as f32)),
                "focus_at" => {
                    let xy = v.split_once(',').and_then(|(x, y)| Some((x.trim().parse::<i64>().ok()?, y.trim().parse::<i64>().ok()?)));
                    let (x, y) = xy.ok_or_else(|| Error::usage(format!("focus_at = {v:?}: X,Y in pixels of the {w}x{h} photo")))?;
                    if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                        return Err(Error::usage(format!("focus_at = {x},{y} is outside the {w}x{h} photo")));
                    }
                    focus = Some(Focus::At(x, y));
                }
                "blur" if blur.is_some() => return Err(dup()),
                "blur" => {
                    let k = number("a blur K >= 0")? as f32;
                    let most = self.blur * BLUR_RANGE * 4.0 + 64.0;
                    if !(0.0..=most).contains(&k) {
                        return Err(Error::usage(format!("blur = {k}: give 0 ..= {most}")));
                    }
                    blur = Some(k);
                }
                "width" if allow_width => {
                    let n = v.trim().parse::<usize>().ok().filter(|&n| (1..=w).contains(&n));
                    width = Some(n.ok_or_else(|| Error::usage(format!("width = {v:?}: give 1 ..= {w} (the photo's width)")))?);
                }
                "profile" => {
                    profile = Some(match v.as_str() {
                        "physical" => crate::render::Profile::Physical,
                        "official" => crate::render::Profile::Official,
                        _ => return Err(Error::usage(format!("profile = {v:?}: physical or official"))),
                    })
                }
                "quality" => {
                    let q = v.trim().parse::<u32>().ok().filter(|q| (1..=8).contains(q));
                    quality = Some(q.ok_or_else(|| Error::usage(format!("quality = {v:?}: give 1 ..= 8")))?);
                }
                "aperture" => {
                    crate::render::ShapeSpec::parse(v, "aperture")?;
                    aperture = Some(v.clone());
                }
                "anamorphic" => anamorphic = Some(number("an aspect ratio in [0.1, 10]")? as f32),
                "bubble" => bubble = Some(number("a rim brightness in [-1, 1]")? as f32),
                "chromatic" => chromatic = Some(number("a chromatic aberration in [-0.5, 0.5]")? as f32),
                "cat_eye" => cat_eye = Some(number("a cat's eye strength in [0, 1]")? as f32),
                _ => return Err(Error::usage(format!("unknown parameter {k:?}"))),
            }
        }
        let focus = focus.ok_or_else(|| Error::usage("give focus (normalized disparity) or focus_at (X,Y)"))?;
        Ok(Ask { focus, blur: blur.unwrap_or(self.blur), width, profile, quality, aperture, anamorphic, bubble, chromatic, cat_eye })
    }

    /// The pipeline of one request: the configuration with its profile and quality.
    fn pipeline(&self, a: &Ask) -> Result<Pipeline> {
        let mut cfg = self.config.clone();
        if let Some(p) = a.profile {
            cfg.render.profile = p;
        }
        if let Some(q) = a.quality {
            cfg.render.quality = q;
        }
        if let Some(s) = &a.aperture {
            cfg.aperture.shape = s.clone();
        }
        cfg.aperture.anamorphic = a.anamorphic.unwrap_or(cfg.aperture.anamorphic);
        cfg.aperture.bubble = a.bubble.unwrap_or(cfg.aperture.bubble);
        cfg.aperture.chromatic = a.chromatic.unwrap_or(cfg.aperture.chromatic);
        cfg.aperture.cat_eye = a.cat_eye.unwrap_or(cfg.aperture.cat_eye);
        Pipeline::from_config(cfg)
    }

    /// The layers scaled to `width` (cached per width), or the layers themselves.
    fn preview(&self, width: Option<usize>) -> Option<Arc<Preview>> {
        let (w, h) = self.size();
        let pw = width.filter(|&pw| pw < w)?;
        let mut cache = self.previews.lock().unwrap_or_else(|e| e.into_inner());
        let p = cache.entry(pw).or_insert_with(|| {
            let ph = ((h as f64 * pw as f64 / w as f64).round() as usize).max(1);
            let layers = self
                .layers
                .iter()
                .map(|l| Layer::new(l.image().resized(pw, ph), "preview").expect("a resized layer stays finite"))
                .collect();
            Arc::new(Preview { layers, scale: pw as f32 / w as f32 })
        });
        Some(p.clone())
    }

    /// Renders an [`Ask`]: the image, for display ([`crate::job::display_transfer`] applied).
    fn rendered(&self, a: &Ask) -> Result<(Image, crate::color::Transfer)> {
        let pipeline = self.pipeline(a)?;
        let (mut image, _) = match self.preview(a.width) {
            Some(p) => {
                let focus = match a.focus {
                    Focus::At(x, y) => Focus::At((x as f32 * p.scale) as i64, (y as f32 * p.scale) as i64),
                    f => f,
                };
                pipeline.refocus(&p.layers, focus, Some(a.blur * p.scale))?
            }
            None => pipeline.refocus(&self.layers, a.focus, Some(a.blur))?,
        };
        let transfer = crate::job::display_transfer(&mut image, pipeline.config());
        Ok((image, transfer))
    }

    fn render(&self, params: &[(String, String)]) -> Result<Reply> {
        let a = self.ask(params, true)?;
        let (image, transfer) = self.rendered(&a)?;
        let mut png = Vec::new();
        crate::io::encode_png(&mut png, &image, 8, transfer).map_err(Error::Internal)?;
        Ok(Reply::png(png))
    }

    fn depth(&self, params: &[(String, String)]) -> Result<Reply> {
        let (mut x, mut y) = (None, None);
        for (k, v) in params {
            let n = v.trim().parse::<i64>().map_err(|_| Error::usage(format!("{k} = {v:?}: a pixel coordinate")));
            match k.as_str() {
                "x" => x = Some(n?),
                "y" => y = Some(n?),
                _ => return Err(Error::usage(format!("unknown parameter {k:?}"))),
            }
        }
        let (x, y) = x.zip(y).ok_or_else(|| Error::usage("give x and y"))?;
        let d = disparity_at(&self.layers, x, y).map_err(|_| {
            let (w, h) = self.size();
            Error::usage(format!("x,y = {x},{y} is outside the {w}x{h} photo"))
        })?;
        Ok(Reply::json(200, serde_json::json!({ "x": x, "y": y, "disparity": d, "focus": d })))
    }

    fn overlay(&self, params: &[(String, String)]) -> Result<Reply> {
        let (w, h) = self.size();
        let (mut kind, mut width) = (None, None);
        for (k, v) in params {
            match k.as_str() {
                "kind" if v == "depth" || v == "matte" => kind = Some(v.clone()),
                "kind" => return Err(Error::usage(format!("kind = {v:?}: depth or matte"))),
                "width" => {
                    let n = v.trim().parse::<usize>().ok().filter(|&n| (1..=w).contains(&n));
                    width = Some(n.ok_or_else(|| Error::usage(format!("width = {v:?}: give 1 ..= {w}")))?);
                }
                _ => return Err(Error::usage(format!("unknown parameter {k:?}"))),
            }
        }
        let kind = kind.ok_or_else(|| Error::usage("give kind=depth or kind=matte"))?;
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                if kind == "matte" {
                    if self.layers.len() > 1 { self.layers[0].alpha(i) } else { 1.0 }
                } else {
                    disparity_at(&self.layers, (i % w) as i64, (i / w) as i64).unwrap_or(0.0)
                }
            })
            .collect();
        let mut img = Image::from_vec(w, h, 1, data).expect("the photo's size");
        if let Some(pw) = width.filter(|&pw| pw < w) {
            img = img.resized(pw, ((h as f64 * pw as f64 / w as f64).round() as usize).max(1));
        }
        let mut png = Vec::new();
        crate::io::encode_png(&mut png, &img, 8, crate::color::Transfer::Linear).map_err(Error::Internal)?;
        Ok(Reply::png(png))
    }

    fn save(&self, params: &[(String, String)]) -> Result<Reply> {
        let a = self.ask(params, false)?;
        let pipeline = self.pipeline(&a)?;
        let (mut image, _) = pipeline.refocus(&self.layers, a.focus, Some(a.blur))?;
        crate::job::write_image(&self.output, &mut image, pipeline.config())?;
        let mut cmd = self.command.clone();
        match a.focus {
            Focus::At(x, y) => cmd.extend(["--focus-at".into(), format!("{x},{y}")]),
            Focus::Disparity(f) => cmd.extend(["--focus".into(), f.to_string()]),
            Focus::Depth(z) => cmd.extend(["--focus-depth".into(), z.to_string()]),
        }
        cmd.extend(["--blur".into(), a.blur.to_string()]);
        if let Some(p) = a.profile {
            cmd.extend(["--profile".into(), if p == crate::render::Profile::Official { "official" } else { "physical" }.into()]);
        }
        if let Some(q) = a.quality {
            cmd.extend(["--quality".into(), q.to_string()]);
        }
        if let Some(s) = a.aperture.as_ref().filter(|s| s.as_str() != "disc") {
            cmd.extend(["--aperture".into(), s.clone()]);
        }
        if let Some(x) = a.anamorphic.filter(|&x| x != 1.0) {
            cmd.extend(["--anamorphic".into(), x.to_string()]);
        }
        if let Some(b) = a.bubble.filter(|&b| b != 0.0) {
            cmd.extend(["--bubble".into(), b.to_string()]);
        }
        if let Some(c) = a.chromatic.filter(|&c| c != 0.0) {
            cmd.extend(["--chromatic".into(), c.to_string()]);
        }
        if let Some(c) = a.cat_eye.filter(|&c| c != 0.0) {
            cmd.extend(["--cat-eye".into(), c.to_string()]);
        }
        cmd.extend(["-o".into(), self.output.display().to_string()]);
        let line = cmd.iter().map(|s| shell_quote(s)).collect::<Vec<_>>().join(" ");
        Ok(Reply::json(200, serde_json::json!({ "path": self.output.display().to_string(), "command": line })))
    }
}

/// `s` quoted for a POSIX shell where it needs to be.
fn shell_quote(s: &str) -> String {
    if !s.is_empty() && s.chars().all(|c| c.is_ascii_alphanumeric() || "-_./,=:+@%".contains(c)) {
        s.to_owned()
    } else {
        format!("'{}'", s.replace('\'', "'\\''"))
    }
}
