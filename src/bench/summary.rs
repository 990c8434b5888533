//! What the bench's reports share: the categories, the summary of a group of rows (means with
//! PSNR capped, the median time), the rows of one input, and the Markdown table head. Used by
//! [`super::report`], [`super::input_report`] and [`super::dfd_report`].

use super::inputs::{Input, primary_input};
use super::run::{Method, Row, Variant};
use std::collections::BTreeMap;
use std::fmt::Write as _;

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
pub fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (mut s, mut n) = (0.0, 0usize);
    for x in v.filter(|x| !x.is_nan()) {
        s += x;
        n += 1;
    }
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// Median (mean of the middle two for an even count); NaN for no values.
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// `p` capped at [`PSNR_CAP`].
pub fn cap(p: f64) -> f64 {
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

/// The inputs present in `rows`, in report order.
pub fn inputs_of(rows: &[Row]) -> Vec<Input> {
    Input::ALL.into_iter().filter(|i| rows.iter().any(|r| r.input == *i)).collect()
}

/// The rows rendered from `input` (copies).
pub fn input_rows(rows: &[Row], input: Input) -> Vec<Row> {
    rows.iter().filter(|r| r.input == input).cloned().collect()
}

/// The rows of the primary input ([`primary_input`] of the inputs present): what the method
/// tables and [`super::report::comparisons`] read.
pub fn primary_rows(rows: &[Row]) -> Vec<Row> {
    input_rows(rows, primary_input(&inputs_of(rows)))
}

/// The error-versus-time figure of a non-primary input: `error_vs_time_<input>.png`.
pub fn plot_file(input: Input) -> String {
    format!("error_vs_time_{}.png", input.name())
}

/// A markdown table's header: the fixed columns (`head`, and their alignment row `align`),
/// then one right-aligned column per name. Ends with a newline.
pub fn table_head<'a>(head: &str, align: &str, names: impl Iterator<Item = &'a str>) -> String {
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
