//! The benchmark's outputs: `report.csv` (one row per case × input × method × setting),
//! `report.md` (Table-1-style summary, per-category rows, Dr.Bokeh against the baselines, all
//! on the primary input; then the inputs compared, [`super::input_report`]),
//! `error_vs_time.png` (primary input) and `error_vs_time_<input>.png` (each other input),
//! and side-by-side crops in `crops/`.

use super::inputs::primary_input;
use super::metrics::srgb;
use super::run::{BenchOptions, BenchResult, Method, Row, Variant};
use super::summary::{CATEGORIES, PSNR_CAP, by_method, cap, input_rows, inputs_of, mean, plot_file, summarize, table_head};
use crate::error::{Error, Result};
use crate::image::Image;
use crate::plot::{self, draw_text, text_width};
use crate::render::Profile;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

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
    s.push_str(&outline_section(&res.rows));
    s
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

/// The report's section on edges without a matte (issue 42): per input, the pipeline with the
/// realistic depth map given the exact matte, without a matte (the depth split refined by
/// `stages::matting`), and without a matte unrefined; mean PSNR, outline range violations and
/// alpha error over the cases all three scored. Empty when the run has none of those rows.
fn outline_section(rows: &[Row]) -> String {
    use std::fmt::Write;
    let variants = [Variant::RealisticDepth, Variant::RealisticNoMatte, Variant::RealisticNoMatteRefineOff];
    let mut s = String::new();
    for input in inputs_of(rows) {
        let of = |v: Variant| -> Vec<&Row> {
            rows.iter().filter(|r| r.input == input && r.method == Method::Pipeline && r.variant == v).collect()
        };
        let sets: Vec<Vec<&Row>> = variants.iter().map(|&v| of(v)).collect();
        let n = sets.iter().map(Vec::len).min().unwrap_or(0);
        if n == 0 || sets.iter().any(|set| set.len() != n) {
            continue;
        }
        if s.is_empty() {
            s.push_str(
                "\n### Edges without a matte (issue 42)\n\n\
                 The pipeline fed the realistic depth map, with the exact matte and without one (the depth split refined by \
                 `[segment] refine = \"auto\"`, and unrefined with `\"off\"`). Outline scores over the pixels within 2 px of the \
                 true matte's edge: `violations` = the share whose render leaves the truth's range in the 5x5 window around it \
                 by more than 4/255 (sRGB), `alpha error` = mean |alpha - true alpha| of the pipeline's front layer.\n\n\
                 | input | setting | cases | PSNR sRGB (dB) | PSNR linear (dB) | outline violations | alpha error |\n\
                 | --- | --- | ---: | ---: | ---: | ---: | ---: |\n",
            );
        }
        for (v, set) in variants.iter().zip(&sets) {
            let mean = |f: &dyn Fn(&Row) -> f64| set.iter().map(|r| f(r)).sum::<f64>() / n as f64;
            let alpha = match v {
                Variant::RealisticDepth => "(given)".to_string(),
                _ => format!("{:.4}", mean(&|r| r.outline.alpha_mae.unwrap_or(0.0))),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {n} | {:.2} | {:.2} | {:.4} | {alpha} |",
                input.name(),
                v.name(),
                mean(&|r| r.scores.psnr_srgb.min(PSNR_CAP)),
                mean(&|r| r.scores.psnr.min(PSNR_CAP)),
                mean(&|r| r.outline.violations),
            );
        }
    }
    s
}
