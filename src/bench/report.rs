//! The benchmark's outputs: `report.csv` (one row per case × input × method × setting),
//! `report.md` (Table-1-style summary, per-category rows, Dr.Bokeh against the baselines, all
//! on the primary input; then the inputs compared, [`super::input_report`]),
//! `error_vs_time.png` (primary input) and `error_vs_time_<input>.png` (each other input),
//! and side-by-side crops in `crops/`.

use super::inputs::Input;
use super::run::{BenchOptions, BenchResult, Case, Method, Row, Variant, srgb};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::plot::{self, draw_text, text_width};
use crate::render::Profile;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// Report categories, in table order, with their descriptions.
pub const CATEGORIES: [(&str, &str); 5] = [
    ("fg_in_focus", "foreground in focus"),
    ("bg_in_focus", "background in focus"),
    ("between", "focus between the layers"),
    ("thin", "thin structures (1–4 px)"),
    ("highlights", "HDR highlights behind edges"),
];

/// PSNR values are capped here before averaging (identical images give +inf).
pub const PSNR_CAP: f64 = 100.0;

/// Mean of the values that are not NaN (a metric that could not be computed); NaN if none.
pub(super) fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v.filter(|x| !x.is_nan()) {
        s += x;
        n += 1;
    }
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// Median (mean of the middle two for an even count); NaN for no values.
pub(super) fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

fn cap(p: f64) -> f64 {
    p.min(PSNR_CAP)
}

/// Mean scores of a group of rows.
#[derive(Clone, Copy, Debug)]
pub struct Summary {
    /// Rows averaged.
    pub n: usize,
    /// Mean PSNR, dB, on sRGB-encoded output clipped to [0, 1] (each capped at `PSNR_CAP`).
    pub psnr_srgb: f64,
    /// Mean SSIM (0 … 1, 1 = identical) on sRGB-encoded output clipped to [0, 1].
    pub ssim_srgb: f64,
    /// Mean PSNR, dB, in linear light (peak 1, each capped at `PSNR_CAP`).
    pub psnr: f64,
    /// Mean SSIM in linear light.
    pub ssim: f64,
    /// Mean root-mean-square error in linear light.
    pub rmse: f64,
    /// Mean RMSE after the best gain (exposure-insensitive), linear light.
    pub si_rmse: f64,
    /// Mean zero-normalized cross-correlation, -1 … 1 (1 = identical up to gain and offset).
    pub zncc: f64,
    /// Median run time, milliseconds.
    pub time_ms: f64,
}

/// Means of the rows' scores (PSNR capped first) and the median of their times.
pub fn summarize(rows: &[&Row]) -> Summary {
    Summary {
        n: rows.len(),
        psnr_srgb: mean(rows.iter().map(|r| cap(r.scores.psnr_srgb))),
        ssim_srgb: mean(rows.iter().map(|r| r.scores.ssim_srgb)),
        psnr: mean(rows.iter().map(|r| cap(r.scores.psnr))),
        ssim: mean(rows.iter().map(|r| r.scores.ssim)),
        rmse: mean(rows.iter().map(|r| r.scores.rmse)),
        si_rmse: mean(rows.iter().map(|r| r.scores.si_rmse)),
        zncc: mean(rows.iter().map(|r| r.scores.zncc)),
        time_ms: median(rows.iter().map(|r| r.time_ms).collect()),
    }
}

/// Mean scores per (method, setting), in method order.
pub fn by_method(rows: &[Row]) -> BTreeMap<(Method, Variant), Summary> {
    let mut groups: BTreeMap<(Method, Variant), Vec<&Row>> = BTreeMap::new();
    for r in rows {
        groups.entry((r.method, r.variant)).or_default().push(r);
    }
    groups.into_iter().map(|(k, v)| (k, summarize(&v))).collect()
}

/// The input the method tables, the main plot and the crops are drawn from: the linear one
/// when it ran (the ceiling), else the first of `inputs` (linear for none).
pub fn primary_input(inputs: &[Input]) -> Input {
    if inputs.contains(&Input::Linear) { Input::Linear } else { inputs.first().copied().unwrap_or(Input::Linear) }
}

/// The inputs present in `rows`, in report order.
pub fn inputs_of(rows: &[Row]) -> Vec<Input> {
    Input::ALL.into_iter().filter(|i| rows.iter().any(|r| r.input == *i)).collect()
}

/// The rows rendered from `input` (copies).
pub fn input_rows(rows: &[Row], input: Input) -> Vec<Row> {
    rows.iter().filter(|r| r.input == input).cloned().collect()
}

/// The rows of the primary input ([`primary_input`] of the inputs present): what the method
/// tables and [`comparisons`] read.
pub fn primary_rows(rows: &[Row]) -> Vec<Row> {
    input_rows(rows, primary_input(&inputs_of(rows)))
}

/// Writes every output of a run into `opts.out`.
pub fn write_all(opts: &BenchOptions, res: &BenchResult) -> Result<()> {
    let out = &opts.out;
    write_text(&out.join("report.csv"), &csv(&res.rows))?;
    write_text(&out.join("report.md"), &markdown(opts, res))?;
    let primary = primary_input(&inputs_of(&res.rows));
    for input in inputs_of(&res.rows) {
        let (file, title) = if input == primary {
            ("error_vs_time.png".to_string(), format!("mean PSNR vs run time, {} cases", res.cases))
        } else {
            (plot_file(input), format!("mean PSNR vs run time, {} cases, {} input", res.cases, input.name()))
        };
        time_plot(&out.join(file), &title, &input_rows(&res.rows, input))?;
    }
    if !res.crops.is_empty() {
        let dir = out.join("crops");
        std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
        for c in &res.crops {
            write_panels(&dir.join(format!("{}.png", c.name)), &c.panels)?;
        }
    }
    Ok(())
}

/// The error-versus-time figure of a non-primary input: `error_vs_time_<input>.png`.
pub fn plot_file(input: Input) -> String {
    format!("error_vs_time_{}.png", input.name())
}

/// Writes the error-versus-time figure of `rows` (one input's): one series per method and lens
/// profile, so a line joins only settings of one model.
fn time_plot(path: &Path, title: &str, rows: &[Row]) -> Result<()> {
    let means = by_method(rows);
    let series: Vec<plot::Series> = [Profile::Official, Profile::Physical]
        .into_iter()
        .flat_map(|profile| Method::ALL.iter().map(move |&m| (m, profile)))
        .filter_map(|(m, profile)| {
            let pts: Vec<plot::Point> = means
                .iter()
                .filter(|((mm, v), _)| *mm == m && v.profile() == profile)
                .map(|((_, v), s)| plot::Point { x: s.time_ms, value: s.psnr_srgb, label: v.name() })
                .collect();
            let name = match profile {
                Profile::Official => m.name().to_owned(),
                Profile::Physical => format!("{} (physical)", m.name()),
            };
            (!pts.is_empty()).then_some(plot::Series { name, points: pts })
        })
        .collect();
    plot::error_vs_time(path, title, "mean PSNR, sRGB (dB, higher is better)", &series)
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::io::atomic::write_atomic(path, |w| w.write_all(text.as_bytes()).map_err(|e| Error::io(path, e)))
}

/// One row per case × input × method × setting. `light_missing` and `light_recovered` are empty
/// except on the pipeline's rows from clipped inputs: linear light clipping took from the
/// photo, summed over its samples, and the fraction of it the highlights stage gave back
/// (empty when nothing was clipped; see [`super::run::LightRecovery`]). `outline_violations`
/// and `alpha_mae` are the scores along the true outline ([`super::outline`]; `alpha_mae` on
/// the pipeline's rows only).
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "scene,setting,categories,method,variant,input,width,height,threads,blur,focus,max_coc_px,border_px,runs,time_ms,\
         rmse,si_rmse,psnr_linear,ssim_linear,zncc,psnr_srgb,ssim_srgb,psnr_srgb_full_frame,light_missing,light_recovered,outline_violations,alpha_mae\n",
    );
    for r in rows {
        let sc = &r.scores;
        let missing = r.light.map(|l| format!("{:.4}", l.missing)).unwrap_or_default();
        let recovered = r.light.and_then(|l| l.fraction()).map(|f| format!("{f:.4}")).unwrap_or_default();
        let violations = r.outline.violations;
        let alpha_mae = r.outline.alpha_mae.map(|a| format!("{a:.4}")).unwrap_or_default();
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{:.4},{:.4},{:.3},{},{},{:.3},{:.6},{:.6},{:.4},{:.6},{:.6},{:.4},{:.6},{:.4},{missing},{recovered},{violations:.4},{alpha_mae}",
            r.scene,
            r.setting,
            r.categories.join(";"),
            r.method.name(),
            r.variant.name(),
            r.input.name(),
            r.width,
            r.height,
            r.threads,
            r.blur,
            r.focus,
            r.max_coc,
            r.border,
            r.runs,
            r.time_ms,
            sc.rmse,
            sc.si_rmse,
            sc.psnr,
            sc.ssim,
            sc.zncc,
            sc.psnr_srgb,
            sc.ssim_srgb,
            sc.psnr_srgb_full
        );
    }
    s
}

/// The reference rows (exact kernel) of one method, keyed by case.
fn reference_rows(rows: &[Row], m: Method) -> BTreeMap<(String, String), &Row> {
    profile_rows(rows, m, Profile::Official)
}

/// The rows of one method rendered with `profile` by the exact kernel (the gather, which has
/// no profile, with its only setting), keyed by case. `rows` are one input's.
fn profile_rows(rows: &[Row], m: Method, profile: Profile) -> BTreeMap<(String, String), &Row> {
    let v = match profile {
        Profile::Physical if rows.iter().any(|r| r.method == m && r.variant == Variant::PhysicalExact) => Variant::PhysicalExact,
        _ => m.reference(),
    };
    rows.iter().filter(|r| r.method == m && r.variant == v).map(|r| ((r.scene.clone(), r.setting.clone()), r)).collect()
}

/// The summary table (the part of report.md that README shows).
pub fn summary_table(rows: &[Row]) -> String {
    let mut s = String::new();
    s.push_str("| method | setting | PSNR sRGB (dB) | SSIM sRGB | PSNR linear (dB) | SSIM linear | RMSE linear | SI-RMSE | ZNCC | median time (ms) |\n");
    s.push_str("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |\n");
    for ((m, v), x) in by_method(rows) {
        let _ = writeln!(
            s,
            "| {} | {} | {:.2} | {:.4} | {:.2} | {:.4} | {:.4} | {:.4} | {:.4} | {:.1} |",
            m.name(),
            v.name(),
            x.psnr_srgb,
            x.ssim_srgb,
            x.psnr,
            x.ssim,
            x.rmse,
            x.si_rmse,
            x.zncc,
            x.time_ms
        );
    }
    s
}

/// Dr.Bokeh (exact layers, exact kernel) against each baseline: mean differences and wins.
pub fn comparisons(rows: &[Row]) -> String {
    let ours = reference_rows(rows, Method::Layers);
    let mut s = String::new();
    if ours.is_empty() {
        return s;
    }
    for base in [Method::Scatter, Method::Gather, Method::Pipeline, Method::Sliced] {
        let theirs = reference_rows(rows, base);
        let pairs: Vec<(&Row, &Row)> = ours.iter().filter_map(|(k, o)| theirs.get(k).map(|t| (*o, *t))).collect();
        if pairs.is_empty() {
            continue;
        }
        let n = pairs.len();
        let dp = mean(pairs.iter().map(|(o, t)| cap(o.scores.psnr_srgb) - cap(t.scores.psnr_srgb)));
        let ds = mean(pairs.iter().map(|(o, t)| o.scores.ssim_srgb - t.scores.ssim_srgb));
        let dpl = mean(pairs.iter().map(|(o, t)| cap(o.scores.psnr) - cap(t.scores.psnr)));
        let wins_p = pairs.iter().filter(|(o, t)| o.scores.psnr_srgb > t.scores.psnr_srgb).count();
        let wins_s = pairs.iter().filter(|(o, t)| o.scores.ssim_srgb > t.scores.ssim_srgb).count();
        let _ = writeln!(
            s,
            "- vs **{}** ({}): mean PSNR sRGB {:+.2} dB, mean SSIM sRGB {:+.4}, mean PSNR linear {:+.2} dB; \
             Dr.Bokeh is better in {wins_p}/{n} cases by PSNR and {wins_s}/{n} by SSIM.",
            base.name(),
            base.label(),
            dp,
            ds,
            dpl
        );
        let mut losses: Vec<&(&Row, &Row)> = pairs.iter().filter(|(o, t)| o.scores.psnr_srgb < t.scores.psnr_srgb).collect();
        losses.sort_by(|a, b| (a.0.scores.psnr_srgb - a.1.scores.psnr_srgb).total_cmp(&(b.0.scores.psnr_srgb - b.1.scores.psnr_srgb)));
        if !losses.is_empty() && matches!(base, Method::Scatter | Method::Gather) {
            let list: Vec<String> = losses
                .iter()
                .take(8)
                .map(|(o, t)| {
                    format!("{} {} [{}] {:+.2} dB", o.scene, o.setting, o.categories.join(","), o.scores.psnr_srgb - t.scores.psnr_srgb)
                })
                .collect();
            let _ = writeln!(s, "  - worse by PSNR in: {}", list.join("; "));
        }
    }
    s
}

/// A markdown table's header: the fixed columns (`head`, and their alignment row `align`),
/// then one right-aligned column per name. Ends with a newline.
pub(super) fn table_head<'a>(head: &str, align: &str, names: impl Iterator<Item = &'a str>) -> String {
    let mut s = String::from(head);
    let mut n = 0;
    for name in names {
        let _ = write!(s, " {name} |");
        n += 1;
    }
    s.push('\n');
    s.push_str(align);
    s.push_str(&" ---: |".repeat(n));
    s.push('\n');
    s
}

/// Mean sRGB PSNR / SSIM per category and method, every method with `profile` (exact kernel).
pub fn category_table(rows: &[Row], profile: Profile) -> String {
    let methods: Vec<Method> = Method::ALL.into_iter().filter(|m| rows.iter().any(|r| r.method == *m)).collect();
    let mut s = table_head("| category | cases |", "| --- | ---: |", methods.iter().map(|m| m.name()));
    for (cat, desc) in CATEGORIES {
        let n = profile_rows(rows, methods[0], profile).values().filter(|r| r.categories.contains(&cat)).count();
        if n == 0 {
            continue;
        }
        let _ = write!(s, "| {desc} | {n} |");
        for &m in &methods {
            let group: Vec<&Row> = profile_rows(rows, m, profile).into_values().filter(|r| r.categories.contains(&cat)).collect();
            let x = summarize(&group);
            let _ = write!(s, " {:.2} / {:.4} |", x.psnr_srgb, x.ssim_srgb);
        }
        s.push('\n');
    }
    s
}

fn markdown(opts: &BenchOptions, res: &BenchResult) -> String {
    let inputs = inputs_of(&res.rows);
    let primary = primary_input(&inputs);
    let rows = &input_rows(&res.rows, primary);
    let mut s = String::from("# Bokeh benchmark: error against a thin-lens ground truth\n\n");
    let _ = writeln!(s, "Command: `{}`\n", opts.command);
    let threads = rows.first().map(|r| r.threads).unwrap_or(0);
    let size = rows.first().map(|r| format!("{}x{}", r.width, r.height)).unwrap_or_default();
    match &opts.groundtruth {
        Some(d) => {
            let _ = writeln!(
                s,
                "{} cases from the ground-truth scenes in `{}` (Mitsuba 3 thin-lens renders), {size}, {threads} threads.\n",
                res.cases,
                d.display()
            );
        }
        None => {
            let _ = writeln!(
                s,
                "{} generated scenes (seed {}), {size}, 2–5 planes each, ground truth traced by `drbokeh trace` at {} rays per pixel; {threads} threads.",
                res.cases,
                opts.seed,
                opts.spp.next_power_of_two()
            );
            if !res.gt_noise.is_empty() {
                let worst = res.gt_noise.iter().cloned().fold(0.0, f64::max);
                let _ = writeln!(
                    s,
                    "Ground-truth noise (two-halves estimate, linear RMS): mean {:.5}, worst {:.5} (a PSNR ceiling of {:.1} dB linear in the worst scene).\n",
                    mean(res.gt_noise.iter().cloned()),
                    worst,
                    20.0 * (1.0 / worst.max(1e-12)).log10()
                );
            }
        }
    }
    s.push_str(
        "Scores leave out a border of the largest CoC radius (the inputs lack the off-frame content the lens sees there). \
         **Headline: PSNR and SSIM on sRGB-encoded output clipped to [0, 1]** (display-referred, as the paper's 8-bit \
         images); linear-light figures use peak 1 and include HDR highlights (radiance up to 50), which dominate them. \
         SSIM is computed on luminance (Rec. 709) with an 11×11 Gaussian window (σ = 1.5), K1 = 0.01, K2 = 0.03. \
         SI-RMSE is the RMSE after the best scalar gain; ZNCC the zero-normalized cross-correlation over all channels. \
         Times are the median of repeated runs (renders under ~1 s are repeated up to the `--repeats` count) of the render \
         alone; the pipeline method's time includes segmentation, depth filling and inpainting.\n\n",
    );
    let compared = inputs.len() > 1 || primary.is_clipped();
    if compared {
        let _ = writeln!(
            s,
            "Inputs: {}. The sections up to \"Inputs compared\" are on the **{}** input ({}).\n",
            inputs.iter().map(|i| format!("`{}`", i.name())).collect::<Vec<_>>().join(", "),
            primary.name(),
            primary.label()
        );
    } else {
        let _ = writeln!(s, "Input: `{}` ({}).\n", primary.name(), primary.label());
    }
    s.push_str("## Summary (mean over cases)\n\n");
    s.push_str(&summary_table(rows));
    s.push_str("\nMethods: ");
    let names: Vec<String> = Method::ALL.iter().map(|m| format!("`{}` = {}", m.name(), m.label())).collect();
    s.push_str(&names.join("; "));
    s.push_str(". Settings: `exact` = the exact (oracle) kernel, `fast-qN` = the fast kernel at quality N (both the official profile), `physical-exact` = the physical lens profile with the exact kernel, `physical-fast-q2` = the physical profile with the fast kernel at quality 2 (the tool's defaults), `realistic-depth` = the defaults fed a depth map as an estimator gives it (exact depth averaged over 4x4 blocks, upsampled bilinearly, Gaussian σ = 1.5 px; the exact-layer methods have no such variant), `realistic-depth-no-matte` = the pipeline's defaults with that depth map and no matte (segmented from the depth alone), `highlights-off` = the pipeline's defaults with `[highlights] mode = \"off\"` (clipped inputs only).\n\n");
    s.push_str("## Dr.Bokeh (exact 2 layers, exact kernel) against the others\n\n");
    s.push_str(&comparisons(rows));
    s.push_str("\n## Per category (mean PSNR sRGB / SSIM sRGB, official profile, exact kernel)\n\n");
    s.push_str(&category_table(rows, Profile::Official));
    if rows.iter().any(|r| r.variant == Variant::PhysicalExact) {
        s.push_str("\n## Per category (mean PSNR sRGB / SSIM sRGB, physical profile, exact kernel; the gather has no profile)\n\n");
        s.push_str(&category_table(rows, Profile::Physical));
    }
    s.push_str("\n![error vs time](error_vs_time.png)\n");
    if !res.crops.is_empty() {
        s.push_str("\n## Crops (ground truth | methods, sRGB)\n\nThe cases where Dr.Bokeh (exact layers) gains most over the scatter baseline, and the one where it loses most;\neach crop is the window where the scatter's error most exceeds Dr.Bokeh's (or the reverse).\n\n");
        for c in &res.crops {
            let _ = writeln!(s, "- `crops/{}.png`: Dr.Bokeh {:+.2} dB sRGB PSNR against the scatter in this case", c.name, c.gain);
        }
    }
    if compared {
        s.push_str(&super::input_report::section(&res.rows));
    }
    s.push_str(&super::outline::section(&res.rows));
    s
}

/// Picks the `size`² window (inside the scored area) where the scatter baseline's error most
/// exceeds Dr.Bokeh's, and crops every image there.
pub fn crop_panels(case: &Case, images: &[(String, &Image)], ours: Option<&Image>, base: Option<&Image>) -> Vec<(String, Image)> {
    let gt = &case.gt;
    let (w, h) = (gt.width, gt.height);
    let b = case.border.min(w / 4).min(h / 4);
    let size = 96.min(w - 2 * b).min(h - 2 * b).max(1);
    let (mut best, mut at) = (f64::NEG_INFINITY, (b, b));
    if let (Some(o), Some(s)) = (ours, base) {
        let lum = |img: &Image, i: usize| {
            0.2126 * img.data[i * 3] as f64 + 0.7152 * img.data[i * 3 + 1] as f64 + 0.0722 * img.data[i * 3 + 2] as f64
        };
        let (so, ss, sg) = (srgb(o), srgb(s), srgb(gt));
        // Integral image of (scatter error - ours error).
        let mut integ = vec![0f64; (w + 1) * (h + 1)];
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let v = (lum(&ss, i) - lum(&sg, i)).abs() - (lum(&so, i) - lum(&sg, i)).abs();
                integ[(y + 1) * (w + 1) + x + 1] = v + integ[y * (w + 1) + x + 1] + integ[(y + 1) * (w + 1) + x] - integ[y * (w + 1) + x];
            }
        }
        let mut y = b;
        while y + size <= h - b {
            let mut x = b;
            while x + size <= w - b {
                let at_ = |xx: usize, yy: usize| integ[yy * (w + 1) + xx];
                let v = at_(x + size, y + size) - at_(x, y + size) - at_(x + size, y) + at_(x, y);
                if v > best {
                    best = v;
                    at = (x, y);
                }
                x += 4;
            }
            y += 4;
        }
    }
    images
        .iter()
        .map(|(name, img)| {
            let mut c = Image::new(size, size, 3);
            for y in 0..size {
                for x in 0..size {
                    c.pixel_mut(x, y).copy_from_slice(img.pixel(at.0 + x, at.1 + y));
                }
            }
            (name.clone(), c)
        })
        .collect()
}

/// Writes labelled panels (linear RGB, any sizes; non-square ones included) side by side as an
/// 8-bit PNG: sRGB-encoded, clipped, 2× nearest-neighbour zoom when every panel's larger side
/// is at most 128 px, labels cut to the panel width; each panel gets a slot as wide as the
/// widest, white where it is smaller. Nothing to write for no panels.
pub fn write_panels(path: &Path, panels: &[(String, Image)]) -> Result<()> {
    let (pw0, ph0) = panels.iter().fold((0, 0), |(w, h), (_, img)| (w.max(img.width), h.max(img.height)));
    if pw0 == 0 || ph0 == 0 {
        return Ok(());
    }
    let zoom = if pw0.max(ph0) <= 128 { 2 } else { 1 };
    let (pw, ph, gap, head) = (pw0 * zoom, ph0 * zoom, 6usize, 18usize);
    let (w, h) = (panels.len() * (pw + gap) - gap, ph + head);
    let mut buf = vec![255u8; w * h * 3];
    for (k, (name, img)) in panels.iter().enumerate() {
        let ox = k * (pw + gap);
        let enc = srgb(img);
        for y in 0..img.height * zoom {
            for x in 0..img.width * zoom {
                let p = enc.pixel(x / zoom, y / zoom);
                let i = ((y + head) * w + ox + x) * 3;
                for c in 0..3 {
                    buf[i + c] = (p[c.min(enc.channels - 1)] * 255.0).round() as u8;
                }
            }
        }
        let label: String = name.chars().take(pw / 8).collect();
        draw_text(&mut buf, w, h, (ox + pw / 2) as i32 - text_width(&label, 1) / 2, 5, &label, [0, 0, 0], 1);
    }
    let img = Image::from_vec(w, h, 3, buf.iter().map(|&v| v as f32 / 255.0).collect()).expect("size");
    crate::io::write_png(path, &img, 8, crate::color::Transfer::Linear)
}
