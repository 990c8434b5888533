//! The outputs of `drbokeh bench --dfd` ([`super::dfd_eval`]): `report.csv` (one row per
//! case × method or reference), `report.md` (Table-2-style means, overall and per source,
//! the acceptance checks, per-case errors) and `figures/SCENE.png` (photo, target,
//! estimated disparities, truth).

use super::dfd_eval::{CaseSource, DfdBenchOptions, DfdBenchResult, DfdMethod, DfdRow, RowKind, TEXTURE_THRESHOLD, TEXTURE_WINDOW};
use super::inputs::{Input, primary_input};
use super::report::write_panels;
use super::summary::{mean, median, table_head};
use crate::error::{Error, Result};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// PSNR values are capped here before averaging (identical images give +inf).
const PSNR_CAP: f64 = 100.0;

/// The re-render margin of the acceptance check: the estimate's re-render PSNR must be within
/// this many dB of the true disparity's.
pub const ACCEPT_DB: f64 = 2.0;

/// Writes every output of a run into `opts.out` (created if missing): report.csv, report.md
/// and figures/.
pub fn write_all(opts: &DfdBenchOptions, res: &DfdBenchResult) -> Result<()> {
    std::fs::create_dir_all(&opts.out).map_err(|e| Error::io(&opts.out, e))?;
    write_text(&opts.out.join("report.csv"), &csv(&res.rows))?;
    write_text(&opts.out.join("report.md"), &markdown(opts, res))?;
    let dir = opts.out.join("figures");
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(&dir, e))?;
    for (scene, panels) in &res.figures {
        write_panels(&dir.join(format!("{scene}.png")), panels)?;
    }
    Ok(())
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    crate::io::atomic::write_atomic(path, |w| w.write_all(text.as_bytes()).map_err(|e| Error::io(path, e)))
}

/// One row per case × method or reference.
pub fn csv(rows: &[DfdRow]) -> String {
    let mut s = String::from(
        "scene,source,method,width,height,blur,focus,rerender_focus,border_px,textured_fraction,disparity_mae,disparity_mae_textured,\
         rerender_psnr_srgb,rerender_ssim_srgb,rerender_psnr_linear,rerender_ssim_linear,time_ms,\
         depth_abs_rel,depth_rmse,depth_delta1,inverse_depth_abs_rel,inverse_depth_rmse,inverse_depth_delta1,input\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{:.4},{:.4},{:.4},{},{:.4},{:.6},{:.6},{:.4},{:.6},{:.4},{:.6},{:.1},{},{}",
            r.scene,
            r.source.name(),
            r.kind.name(),
            r.width,
            r.height,
            r.blur,
            r.focus,
            r.other_focus,
            r.border,
            r.textured_fraction,
            r.mae,
            r.mae_textured,
            r.rerender.psnr_srgb,
            r.rerender.ssim_srgb,
            r.rerender.psnr,
            r.rerender.ssim,
            r.time_ms,
            // Empty cells where the scene states no depth range.
            match r.depth {
                Some(e) => [e.depth, e.inverse].map(|q| format!("{:.6},{:.6},{:.6}", q.abs_rel, q.rmse, q.delta1)).join(","),
                None => ",,,,,".to_string(),
            },
            // Last, so that the reports written before it had the column read the same.
            r.input.name()
        );
    }
    s
}

/// The rows of each kind, in report order (methods, then the references).
fn by_kind<'a>(rows: impl Iterator<Item = &'a DfdRow>) -> BTreeMap<RowKind, Vec<&'a DfdRow>> {
    let mut m: BTreeMap<RowKind, Vec<&DfdRow>> = BTreeMap::new();
    for r in rows {
        m.entry(r.kind).or_default().push(r);
    }
    m
}

/// The Table-2-style means over `rows` (the part of report.md that README shows).
pub fn summary_table<'a>(rows: impl Iterator<Item = &'a DfdRow>) -> String {
    let mut s = String::from(
        "| method | disparity MAE | MAE, textured | re-render PSNR sRGB (dB) | SSIM sRGB | PSNR linear (dB) | median time (s) | what |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |\n",
    );
    for (k, g) in by_kind(rows) {
        let time = if matches!(k, RowKind::Estimate(_)) {
            format!("{:.1}", median(g.iter().map(|r| r.time_ms / 1e3).collect()))
        } else {
            "-".into()
        };
        let _ = writeln!(
            s,
            "| {} | {:.4} | {:.4} | {:.2} | {:.4} | {:.2} | {} | {} |",
            k.name(),
            mean(g.iter().map(|r| r.mae)),
            mean(g.iter().map(|r| r.mae_textured)),
            mean(g.iter().map(|r| r.rerender.psnr_srgb.min(PSNR_CAP))),
            mean(g.iter().map(|r| r.rerender.ssim_srgb)),
            mean(g.iter().map(|r| r.rerender.psnr.min(PSNR_CAP))),
            time,
            k.label()
        );
    }
    s
}

/// The depth-from-defocus literature's measures, means over the cases of `rows` with a depth
/// range (empty when none has one).
pub fn depth_table(rows: &[DfdRow]) -> String {
    let with: Vec<&DfdRow> = rows.iter().filter(|r| r.depth.is_some()).collect();
    if with.is_empty() {
        return String::new();
    }
    let cases = with.iter().filter(|r| r.kind == RowKind::TrueDisparity).count();
    let mut s = format!(
        "Means over the {cases} cases whose scene states its depth range (`z_min`, `z_max` of params.json: disparity 1 and 0; \
         estimates clamped to [0, 1] first), same border. AbsRel = mean |estimate − truth| / truth, RMSE in the scene's units \
         (inverse depth: their inverse), δ1 = fraction of pixels with max(estimate / truth, truth / estimate) < 1.25.\n\n\
         | method | depth AbsRel | depth RMSE | depth δ1 | inverse depth AbsRel | inverse depth RMSE | inverse depth δ1 |\n\
         | --- | ---: | ---: | ---: | ---: | ---: | ---: |\n"
    );
    for (k, g) in by_kind(with.into_iter()) {
        let m = |f: fn(&super::depth_metrics::DepthErrors) -> f64| mean(g.iter().filter_map(|r| r.depth.as_ref()).map(f));
        let _ = writeln!(
            s,
            "| {} | {:.4} | {:.3} | {:.4} | {:.4} | {:.4} | {:.4} |",
            k.name(),
            m(|e| e.depth.abs_rel),
            m(|e| e.depth.rmse),
            m(|e| e.depth.delta1),
            m(|e| e.inverse.abs_rel),
            m(|e| e.inverse.rmse),
            m(|e| e.inverse.delta1)
        );
    }
    s
}

/// Rows of one kind keyed by scene.
fn rows_of(rows: &[DfdRow], k: RowKind) -> BTreeMap<&str, &DfdRow> {
    rows.iter().filter(|r| r.kind == k).map(|r| (r.scene.as_str(), r)).collect()
}

/// One re-render check of [`Acceptance`]: per case, the true disparity's re-render PSNR minus
/// the default method's (each capped at 100 dB), in one encoding.
#[derive(Clone, Debug)]
pub struct RerenderCheck {
    /// The encoding: "sRGB" or "linear".
    pub what: &'static str,
    /// Per case: (the gap in dB, positive where the true map re-renders better; the scene).
    pub gaps: Vec<(f64, String)>,
}

impl RerenderCheck {
    /// The mean gap, dB (NaN without cases).
    pub fn mean(&self) -> f64 {
        mean(self.gaps.iter().map(|g| g.0))
    }

    /// The largest gap and its scene (-inf and "" without cases).
    pub fn worst(&self) -> (f64, &str) {
        self.gaps.iter().fold((f64::NEG_INFINITY, ""), |a, g| if g.0 > a.0 { (g.0, g.1.as_str()) } else { a })
    }

    /// Cases whose gap is at most [`ACCEPT_DB`].
    pub fn within(&self) -> usize {
        self.gaps.iter().filter(|g| g.0 <= ACCEPT_DB).count()
    }

    /// The check: the mean gap is at most [`ACCEPT_DB`].
    pub fn holds(&self) -> bool {
        self.mean() <= ACCEPT_DB
    }
}

/// One disparity-error comparison of [`Acceptance`]: the default method against `base`, means
/// over the cases both have.
#[derive(Clone, Debug)]
pub struct MaeCheck {
    /// What the default method is compared with.
    pub base: RowKind,
    /// Cases compared.
    pub cases: usize,
    /// Mean disparity MAE of the default method and of `base`, overall.
    pub ours: f64,
    /// The same for `base`.
    pub theirs: f64,
    /// Mean disparity MAE of the default method over the textured pixels.
    pub ours_textured: f64,
    /// The same for `base`.
    pub theirs_textured: f64,
    /// Cases where the default method's MAE is lower, overall.
    pub wins: usize,
    /// The same over the textured pixels.
    pub wins_textured: usize,
}

impl MaeCheck {
    /// The check, overall: the default method's mean MAE is lower.
    pub fn beats(&self) -> bool {
        self.ours < self.theirs
    }

    /// The check over the textured pixels.
    pub fn beats_textured(&self) -> bool {
        self.ours_textured < self.theirs_textured
    }
}

/// The acceptance checks on the default method ([`DfdMethod::Physical`]): its
/// re-render within [`ACCEPT_DB`] of the true disparity's (sRGB and linear PSNR), and its
/// disparity error against the no-occlusion and Gaussian-PSF ablations and the start.
#[derive(Clone, Debug)]
pub struct Acceptance {
    /// sRGB, then linear.
    pub rerender: [RerenderCheck; 2],
    /// Against each of no occlusion, Gaussian PSF and the start that has rows.
    pub disparity: Vec<MaeCheck>,
}

impl Acceptance {
    /// The checks of `rows`; None without rows of the default method.
    pub fn of(rows: &[DfdRow]) -> Option<Acceptance> {
        let ours = rows_of(rows, RowKind::Estimate(DfdMethod::Physical));
        if ours.is_empty() {
            return None;
        }
        let truth = rows_of(rows, RowKind::TrueDisparity);
        let pairs: Vec<(&DfdRow, &DfdRow)> = ours.iter().filter_map(|(k, o)| truth.get(k).map(|t| (*o, *t))).collect();
        let check = |what, get: fn(&DfdRow) -> f64| RerenderCheck {
            what,
            gaps: pairs.iter().map(|(o, t)| (get(t).min(PSNR_CAP) - get(o).min(PSNR_CAP), o.scene.clone())).collect(),
        };
        let rerender = [check("sRGB", |r| r.rerender.psnr_srgb), check("linear", |r| r.rerender.psnr)];
        let mut disparity = Vec::new();
        for base in [RowKind::Estimate(DfdMethod::NoOcclusion), RowKind::Estimate(DfdMethod::GaussPsf), RowKind::Init] {
            let theirs = rows_of(rows, base);
            let p: Vec<(&DfdRow, &DfdRow)> = ours.iter().filter_map(|(k, o)| theirs.get(k).map(|t| (*o, *t))).collect();
            if p.is_empty() {
                continue;
            }
            disparity.push(MaeCheck {
                base,
                cases: p.len(),
                ours: mean(p.iter().map(|x| x.0.mae)),
                theirs: mean(p.iter().map(|x| x.1.mae)),
                ours_textured: mean(p.iter().map(|x| x.0.mae_textured)),
                theirs_textured: mean(p.iter().map(|x| x.1.mae_textured)),
                wins: p.iter().filter(|x| x.0.mae < x.1.mae).count(),
                wins_textured: p.iter().filter(|x| x.0.mae_textured < x.1.mae_textured).count(),
            });
        }
        Some(Acceptance { rerender, disparity })
    }

    /// The comparison with `base`, if it has rows.
    pub fn against(&self, base: RowKind) -> Option<&MaeCheck> {
        self.disparity.iter().find(|c| c.base == base)
    }
}

/// The acceptance checks ([`Acceptance`]) as report.md's list, one line each (empty without
/// rows of the default method).
pub fn acceptance(rows: &[DfdRow]) -> String {
    let mut s = String::new();
    let Some(a) = Acceptance::of(rows) else {
        return s;
    };
    let yes = |b: bool| if b { "yes" } else { "no" };
    for c in &a.rerender {
        let (worst, scene) = c.worst();
        let _ = writeln!(
            s,
            "- Re-render PSNR {}, true disparity minus **{}**: mean {:.2} dB, worst {:.2} dB ({}); within {ACCEPT_DB} dB in {}/{} cases; mean within {ACCEPT_DB} dB: **{}**.",
            c.what,
            DfdMethod::Physical.name(),
            c.mean(),
            worst,
            scene,
            c.within(),
            c.gaps.len(),
            yes(c.holds())
        );
    }
    for c in &a.disparity {
        let _ = writeln!(
            s,
            "- Disparity MAE, **{}** vs **{}**: {:.4} vs {:.4} overall (lower in {}/{} cases), {:.4} vs {:.4} in textured regions \
             (lower in {}/{}); beats it on the mean: **{}** overall, **{}** textured.",
            DfdMethod::Physical.name(),
            c.base.name(),
            c.ours,
            c.theirs,
            c.wins,
            c.cases,
            c.ours_textured,
            c.theirs_textured,
            c.wins_textured,
            c.cases,
            yes(c.beats()),
            yes(c.beats_textured())
        );
    }
    s
}

/// Disparity MAE (overall / textured) per case and method.
fn per_case_table(rows: &[DfdRow]) -> String {
    let kinds: Vec<RowKind> = by_kind(rows.iter()).into_keys().collect();
    let mut s = table_head("| scene | source | K | textured |", "| --- | --- | ---: | ---: |", kinds.iter().map(|k| k.name()));
    let mut scenes: Vec<(&str, &DfdRow)> = Vec::new();
    for r in rows {
        if !scenes.iter().any(|(n, _)| *n == r.scene) {
            scenes.push((&r.scene, r));
        }
    }
    for (scene, first) in scenes {
        let _ = write!(s, "| {scene} | {} | {:.2} | {:.2} |", first.source.name(), first.blur, first.textured_fraction);
        for k in &kinds {
            match rows.iter().find(|r| r.scene == scene && r.kind == *k) {
                Some(r) => {
                    let _ = write!(s, " {:.3} / {:.3} |", r.mae, r.mae_textured);
                }
                None => s.push_str(" - |"),
            }
        }
        s.push('\n');
    }
    s
}

fn markdown(opts: &DfdBenchOptions, res: &DfdBenchResult) -> String {
    let primary = primary_input(&opts.inputs);
    let rows: &Vec<DfdRow> = &res.rows.iter().filter(|r| r.input == primary).cloned().collect();
    let mut s = String::from("# Depth from defocus: disparity error and re-render accuracy (paper Table 2)\n\n");
    let _ = writeln!(s, "Command: `{}`\n", opts.command);
    let generated = rows.iter().filter(|r| r.source == CaseSource::Generated && r.kind == RowKind::TrueDisparity).count();
    let gt = rows.iter().filter(|r| r.source == CaseSource::GroundTruth && r.kind == RowKind::TrueDisparity).count();
    let _ = writeln!(
        s,
        "{} cases: {generated} generated scenes (seed {}, {}x{}, radiance clipped to [0, 1], K = {}, truths traced by `drbokeh trace` at {} rays per pixel){}. \
         Every estimate: `dfd::estimate` from the all-in-focus photo and the target, {} levels × {} Adam steps, start {} everywhere; {} threads.\n",
        res.cases,
        opts.seed,
        opts.width,
        opts.height,
        match opts.blur {
            Some(k) => format!("{k}"),
            None => format!("{:.1}", super::dfd_eval::default_blur(opts.width, opts.height)),
        },
        opts.spp.next_power_of_two(),
        if gt > 0 {
            format!(
                " and {gt} shared Mitsuba scenes from `{}` (box-downsampled to about {} px wide, K divided by the factor)",
                opts.groundtruth.as_ref().map(|p| p.display().to_string()).unwrap_or_default(),
                opts.width
            )
        } else {
            String::new()
        },
        opts.levels,
        opts.iters,
        crate::diff::dfd::DfdOptions::default().init,
        rayon::current_num_threads()
    );
    let _ = writeln!(
        s,
        "**Target**: the thin-lens truth focused on the nearest plane (every relative disparity has one sign). **Disparity MAE**: \
         mean |estimate − truth| in normalized disparity over the frame less a border of ceil(K) px (the lens sees off-frame \
         content there that the photo lacks); **textured**: only where the mean over a {TEXTURE_WINDOW}×{TEXTURE_WINDOW} window of the \
         gradient magnitude (central differences) of the photo's sRGB luminance is at least {TEXTURE_THRESHOLD} per pixel. \
         **Re-render**: the photo as one opaque layer over the disparity, rendered at the farthest plane's focus as `drbokeh render \
         --layer` does (physical profile, default kernel), against the thin-lens truth there; PSNR/SSIM on sRGB-encoded output \
         clipped to [0, 1] (SSIM on luminance, 11×11 Gaussian window), PSNR linear with peak 1, same border. `true-disparity` \
         re-renders the true map (the best one opaque layer can do), `init` the optimiser's start. Time: wall time of one estimate.\n"
    );
    if opts.inputs != [Input::Linear] {
        let names: Vec<String> = opts.inputs.iter().map(|i| format!("`{}`", i.name())).collect();
        let _ = writeln!(
            s,
            "**Inputs**: {} (`--inputs`). The tables up to the acceptance checks, the per-case table and the figures are for `{}`; \
             each other input has its own section after them.\n",
            names.join(", "),
            primary.name()
        );
    }
    let _ = writeln!(s, "## All cases (mean over {} cases)\n", res.cases);
    s.push_str(&summary_table(rows.iter()));
    if generated > 0 && gt > 0 {
        let _ = writeln!(s, "\n## Generated scenes (mean over {generated})\n");
        s.push_str(&summary_table(rows.iter().filter(|r| r.source == CaseSource::Generated)));
        let _ = writeln!(s, "\n## Shared Mitsuba scenes (mean over {gt})\n");
        s.push_str(&summary_table(rows.iter().filter(|r| r.source == CaseSource::GroundTruth)));
    }
    let depth = depth_table(rows);
    if !depth.is_empty() {
        s.push_str("\n## Depth and inverse depth (AbsRel, RMSE, δ < 1.25)\n\n");
        s.push_str(&depth);
    }
    s.push_str("\n## Acceptance (issue 13)\n\n");
    s.push_str(&acceptance(rows));
    for &input in opts.inputs.iter().filter(|&&i| i != primary) {
        let of: Vec<DfdRow> = res.rows.iter().filter(|r| r.input == input).cloned().collect();
        let _ = writeln!(
            s,
            "\n## Input `{}`: {} (mean over {} cases)\n\nBoth photos (all-in-focus and target) as the camera stores them; \
             the estimates and every re-render start from that all-in-focus photo, against the same linear truths.\n",
            input.name(),
            input.label(),
            res.cases
        );
        s.push_str(&summary_table(of.iter()));
        let depth = depth_table(&of);
        if !depth.is_empty() {
            let _ = writeln!(s, "\n### Depth and inverse depth, input `{}`\n", input.name());
            s.push_str(&depth);
        }
        let _ = writeln!(s, "\n### Acceptance, input `{}`\n", input.name());
        s.push_str(&acceptance(&of));
    }
    s.push_str("\n## Per case: disparity MAE overall / textured\n\n");
    s.push_str(&per_case_table(rows));
    s.push_str("\n## Figures (all-in-focus photo | target | estimated disparities | true disparity; 0 black, 1 white)\n\n");
    for (scene, _) in &res.figures {
        let _ = writeln!(s, "- `figures/{scene}.png`");
    }
    s
}
