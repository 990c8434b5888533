//! Scenes in the `shared/groundtruth` format: thin-lens renders with their exact layers.
//!
//! A folder holds `aif.exr`, `depth.exr`, `fg.exr` (premultiplied), `fg_alpha.exr`, `bg.exr`,
//! `bg_depth.exr`, `gt_<setting>.exr` and `params.json` (see that folder's README). This module
//! loads one and builds the renderer's inputs from it: the exact two layers, or the single
//! all-in-focus layer of the classical baseline.

use crate::color::Transfer;
use crate::error::{Error, Result};
use crate::image::Image;
use crate::io::{ReadLimits, read_depth, read_matte, read_photo};
use crate::render::Layer;
use crate::stages::inpaint::{TeleaOptions, inpaint_telea};
use std::path::{Path, PathBuf};

/// One focus setting of a scene, with its ground truth.
pub struct GtSetting {
    /// The setting's name as the scene's params.json gives it (e.g. "focus_fg").
    pub name: String,
    /// Blur strength in normalized-disparity units (`K_norm`).
    pub blur: f32,
    /// Focus as normalized disparity.
    pub focus: f32,
    /// Largest visible CoC radius, px: the border to leave out when scoring.
    pub coc_max: f32,
    /// The ground-truth render of this setting: linear RGB, the scene's size.
    pub gt: Image,
}

/// A loaded scene.
pub struct GtScene {
    /// The scene's name in reports: params.json's `scene`, else the folder's name.
    pub name: String,
    /// The scene folder.
    pub dir: PathBuf,
    /// The all-in-focus photo: linear RGB.
    pub aif: Image,
    /// Normalized disparity of the frontmost surface at each pixel centre.
    pub disparity: Image,
    /// Foreground coverage in [0, 1] (one channel).
    pub alpha: Image,
    /// Premultiplied foreground colour.
    pub fg: Image,
    /// The background alone (behind the foreground), linear RGB.
    pub bg: Image,
    /// Normalized disparity of the background alone (one channel).
    pub bg_disparity: Image,
    /// The focus settings, each with its ground truth.
    pub settings: Vec<GtSetting>,
    /// The depths (`z_min`, `z_max`, scene units) that normalized disparity 1 and 0 stand for.
    pub z_range: (f64, f64),
}

fn num(v: &serde_json::Value, key: &str, file: &Path) -> Result<f64> {
    v[key].as_f64().ok_or_else(|| Error::input(file, format!("missing number `{key}`")))
}

impl GtScene {
    /// Reads a scene folder: `params.json` and the images it names; every error names the file.
    pub fn load(dir: &Path) -> Result<GtScene> {
        let pfile = dir.join("params.json");
        let text = crate::io::read_input_text(&pfile)?;
        let p: serde_json::Value = serde_json::from_str(&text).map_err(|e| Error::input(&pfile, e.to_string()))?;
        let (zmin, zmax) = (num(&p, "z_min", &pfile)?, num(&p, "z_max", &pfile)?);
        let limits = ReadLimits::default();
        let rgb = |n: &str| read_photo(&dir.join(n), Transfer::Linear, &limits);
        let to_disp = |z: Image| {
            let mut z = z;
            let span = 1.0 / zmin - 1.0 / zmax;
            z.map_inplace(|v| ((1.0 / v as f64 - 1.0 / zmax) / span) as f32);
            z
        };
        let mut settings = Vec::new();
        for s in p["settings"].as_array().ok_or_else(|| Error::input(&pfile, "missing `settings`"))? {
            let name = s["name"].as_str().unwrap_or_default().to_string();
            settings.push(GtSetting {
                blur: num(s, "K_norm", &pfile)? as f32,
                focus: num(s, "focus_norm_disparity", &pfile)? as f32,
                coc_max: num(s, "coc_px_visible_max", &pfile)? as f32,
                gt: rgb(&format!("gt_{name}.exr"))?,
                name,
            });
        }
        Ok(GtScene {
            name: p["scene"]
                .as_str()
                .map(str::to_owned)
                .unwrap_or_else(|| dir.file_name().unwrap_or_default().to_string_lossy().into_owned()),
            dir: dir.to_path_buf(),
            aif: rgb("aif.exr")?,
            disparity: to_disp(read_depth(&dir.join("depth.exr"), &limits)?),
            alpha: read_matte(&dir.join("fg_alpha.exr"), &limits)?,
            fg: rgb("fg.exr")?,
            bg: rgb("bg.exr")?,
            bg_disparity: to_disp(read_depth(&dir.join("bg_depth.exr"), &limits)?),
            settings,
            z_range: (zmin, zmax),
        })
    }

    /// The exact layers: un-premultiplied foreground with its alpha, and the true background.
    /// The foreground's disparity is exact where a foreground surface covers the pixel centre
    /// and Telea-extended elsewhere (the same fill the pipeline uses).
    pub fn exact_layers(&self) -> Result<Vec<Layer<'static>>> {
        let mut fg_rgb = self.fg.clone();
        for (px, &a) in fg_rgb.data.chunks_exact_mut(3).zip(&self.alpha.data) {
            for c in px {
                *c = if a > 1e-4 { *c / a } else { 0.0 };
            }
        }
        let unknown: Vec<bool> = self.disparity.data.iter().zip(&self.bg_disparity.data).map(|(&d, &b)| d <= b + 1e-6).collect();
        let mut fg_disp = self.disparity.clone();
        if unknown.iter().any(|&u| !u) {
            inpaint_telea(&mut fg_disp, &unknown, TeleaOptions::new(5.0))?;
        }
        let opaque = Image::filled(self.bg.width, self.bg.height, 1, 1.0);
        Ok(vec![
            Layer::from_parts(&fg_rgb, &self.alpha, &fg_disp, "ground-truth foreground")?,
            Layer::from_parts(&self.bg, &opaque, &self.bg_disparity, "ground-truth background")?,
        ])
    }

    /// The all-in-focus image as one opaque layer (input of the classical scatter baseline).
    pub fn single_layer(&self) -> Result<Layer<'static>> {
        let opaque = Image::filled(self.aif.width, self.aif.height, 1, 1.0);
        Layer::from_parts(&self.aif, &opaque, &self.disparity, "all-in-focus layer")
    }
}

/// The scene folders (each holding a `params.json`) of a ground-truth folder, sorted; an
/// error naming the folder when it has none.
pub fn scene_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("params.json").is_file())
        .collect();
    dirs.sort();
    if dirs.is_empty() {
        return Err(Error::input(dir, "no scene folder (with params.json) found in this ground-truth folder"));
    }
    Ok(dirs)
}
