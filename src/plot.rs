//! Line plots against a logarithmic x axis (plotters, bitmap backend) and a tiny text
//! renderer: the bench's error-versus-run-time figure and `drbokeh dfd`'s loss curves.
//!
//! plotters draws text only through a font backend (system fonts or a bundled TTF), which
//! this crate does not depend on: the plot area, grid, series and markers are drawn with
//! plotters, and every label is drawn afterwards with the public-domain 8×8 bitmap font of
//! `font8x8` straight into the RGB buffer, so the figure renders the same on any machine.

use crate::error::{Error, Result};
use plotters::prelude::*;
use std::path::Path;

/// Draws `text` (ASCII) into an RGB8 buffer of width `w` at (x, y) (top-left), each font
/// pixel `scale`×`scale`. Off-buffer pixels are clipped.
#[allow(clippy::too_many_arguments)]
pub fn draw_text(buf: &mut [u8], w: usize, h: usize, x: i32, y: i32, text: &str, rgb: [u8; 3], scale: i32) {
    for (k, ch) in text.chars().enumerate() {
        let glyph = font8x8::legacy::BASIC_LEGACY[if (ch as usize) < 128 { ch as usize } else { b'?' as usize }];
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..8 {
                if bits >> col & 1 == 0 {
                    continue;
                }
                for sy in 0..scale {
                    for sx in 0..scale {
                        let px = x + (k as i32 * 8 + col) * scale + sx;
                        let py = y + row as i32 * scale + sy;
                        if px >= 0 && py >= 0 && (px as usize) < w && (py as usize) < h {
                            let i = (py as usize * w + px as usize) * 3;
                            buf[i..i + 3].copy_from_slice(&rgb);
                        }
                    }
                }
            }
        }
    }
}

/// Width in pixels of `text` drawn at `scale`.
pub fn text_width(text: &str, scale: i32) -> i32 {
    text.chars().count() as i32 * 8 * scale
}

/// One point of a series: x (see [`XAxis`]), value, label.
#[derive(Clone, Debug)]
pub struct Point {
    /// The x coordinate (the axis is logarithmic; values below 1e-3 are drawn at 1e-3), in the
    /// unit of the plot's [`XAxis`]: median run time in ms, or an iteration count.
    pub x: f64,
    /// The measure plotted (the y axis, linear), e.g. PSNR in dB or a loss.
    pub value: f64,
    /// Text drawn beside the point (the setting, e.g. "q2").
    pub label: String,
}

/// One method's settings.
#[derive(Clone, Debug)]
pub struct Series {
    /// The legend entry.
    pub name: String,
    /// The points, joined by a line in this order.
    pub points: Vec<Point>,
}

const PALETTE: [RGBColor; 10] = [
    RGBColor(214, 39, 40),
    RGBColor(31, 119, 180),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
    RGBColor(188, 189, 34),
    RGBColor(127, 127, 127),
];

/// What the x axis of a [`line_plot`] shows (always on a log scale).
#[derive(Clone, Copy, Debug)]
pub struct XAxis<'a> {
    /// The axis title, drawn under it.
    pub title: &'a str,
    /// How the decade ticks are written.
    pub ticks: Ticks,
}

/// How the x axis's tick values are written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ticks {
    /// Milliseconds, switching to seconds from 1000 ("1s").
    Milliseconds,
    /// Plain numbers (counts such as iterations).
    Plain,
}

/// Series with more points than this are drawn as lines without markers (a loss curve);
/// at most this many get a marker per point.
const MAX_MARKED_POINTS: usize = 40;

/// Writes a PNG plot of `value` (y, linear) against run time (x, log scale), one line and
/// marker colour per series, settings labelled next to their points.
pub fn error_vs_time(path: &Path, title: &str, y_label: &str, series: &[Series]) -> Result<()> {
    let x = XAxis { title: "median run time per render (ms, log scale)", ticks: Ticks::Milliseconds };
    line_plot(path, title, &x, y_label, series)
}

/// Writes a 1100×640 PNG plot of `value` (y, linear) against `x` (log scale, whole decades),
/// one line and colour per series with a legend; series of at most 40 points
/// get markers and their points' labels. Non-finite points are left out. Cost: one
/// 2 MB RGB buffer, O(points).
pub fn line_plot(path: &Path, title: &str, x_axis: &XAxis, y_label: &str, series: &[Series]) -> Result<()> {
    let (w, h) = (1100usize, 640usize);
    let mut buf = vec![255u8; w * h * 3];
    let pts = series.iter().flat_map(|s| s.points.iter()).filter(|p| p.x.is_finite() && p.value.is_finite());
    let (mut tmin, mut tmax, mut vmin, mut vmax) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for p in pts {
        tmin = tmin.min(p.x.max(1e-3));
        tmax = tmax.max(p.x.max(1e-3));
        vmin = vmin.min(p.value);
        vmax = vmax.max(p.value);
    }
    if !tmin.is_finite() {
        (tmin, tmax, vmin, vmax) = (1.0, 10.0, 0.0, 1.0);
    }
    // Whole decades on x; 8% headroom on y.
    let (tmin, tmax) = (10f64.powf(tmin.log10().floor()), 10f64.powf(tmax.log10().ceil().max(tmin.log10().floor() + 1.0)));
    // A flat series (one value) gets a band of ±5% of its value (±0.05 around 0).
    let pad = if vmax > vmin { (vmax - vmin) * 0.08 } else { (vmax.abs() * 0.05).max(0.05) };
    let (vmin, vmax) = (vmin - pad, vmax + pad);
    let (left, right, top, bottom) = (80i32, 260i32, 50i32, 60i32);

    let mut labels: Vec<(i32, i32, String, [u8; 3], i32)> = Vec::new();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w as u32, h as u32)).into_drawing_area();
        let err = |e: &dyn std::fmt::Display| Error::io(path, std::io::Error::other(format!("plot: {e}")));
        let mut chart = ChartBuilder::on(&root)
            .margin_left(left as u32)
            .margin_right(right as u32)
            .margin_top(top as u32)
            .margin_bottom(bottom as u32)
            .build_cartesian_2d((tmin..tmax).log_scale(), vmin..vmax)
            .map_err(|e| err(&e))?;
        let grey = RGBColor(225, 225, 225);
        // Grid: decades and 2, 5 subdivisions on x; ~6 round steps on y.
        let mut decade = tmin;
        while decade <= tmax * 1.0001 {
            for (m, major) in [(1.0, true), (2.0, false), (5.0, false)] {
                let t = decade * m;
                if t < tmin * 0.9999 || t > tmax * 1.0001 {
                    continue;
                }
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(t, vmin), (t, vmax)],
                        if major { RGBColor(190, 190, 190) } else { grey },
                    )))
                    .map_err(|e| err(&e))?;
                let (x, y) = chart.backend_coord(&(t, vmin));
                let s = match x_axis.ticks {
                    Ticks::Milliseconds => fmt_ms(t),
                    Ticks::Plain => format!("{t}"),
                };
                labels.push((x - text_width(&s, 1) / 2, y + 8, s, [60, 60, 60], 1));
            }
            decade *= 10.0;
        }
        let step = nice_step((vmax - vmin) / 6.0);
        let mut v = (vmin / step).ceil() * step;
        while v <= vmax {
            chart.draw_series(std::iter::once(PathElement::new(vec![(tmin, v), (tmax, v)], grey))).map_err(|e| err(&e))?;
            let (x, y) = chart.backend_coord(&(tmin, v));
            // As many decimals as the step needs (0.05 → 2, 0.002 → 3).
            let decimals = (-step.log10().floor()).max(0.0) as usize;
            // A tick at zero that accumulated rounding (-1e-18) is written "0", not "-0.00".
            let shown = if v.abs() < step * 1e-6 { 0.0 } else { v };
            let s = format!("{shown:.decimals$}");
            labels.push((x - 8 - text_width(&s, 1), y - 4, s, [60, 60, 60], 1));
            v += step;
        }
        let (x0, y0) = chart.backend_coord(&(tmin, vmax));
        let (x1, y1) = chart.backend_coord(&(tmax, vmin));
        root.draw(&Rectangle::new([(x0, y0), (x1, y1)], BLACK.stroke_width(1))).map_err(|e| err(&e))?;

        for (k, s) in series.iter().enumerate() {
            let color = PALETTE[k % PALETTE.len()];
            let mut p: Vec<&Point> = s.points.iter().filter(|p| p.x.is_finite() && p.value.is_finite()).collect();
            p.sort_by(|a, b| a.x.total_cmp(&b.x));
            let coords: Vec<(f64, f64)> = p.iter().map(|p| (p.x.max(1e-3), p.value)).collect();
            chart.draw_series(LineSeries::new(coords.clone(), color.stroke_width(2))).map_err(|e| err(&e))?;
            let marked = p.len() <= MAX_MARKED_POINTS;
            if marked {
                chart.draw_series(coords.iter().map(|&c| Circle::new(c, 5, color.filled()))).map_err(|e| err(&e))?;
            }
            for (pt, c) in p.iter().zip(&coords) {
                if marked && p.len() > 1 {
                    let (x, y) = chart.backend_coord(c);
                    labels.push((x + 7, y - 12, pt.label.clone(), [color.0 / 2 + 40, color.1 / 2 + 40, color.2 / 2 + 40], 1));
                }
            }
            // Legend entry.
            let (lx, ly) = (w as i32 - right + 20, top + 10 + k as i32 * 22);
            root.draw(&Rectangle::new([(lx, ly), (lx + 14, ly + 10)], color.filled())).map_err(|e| err(&e))?;
            labels.push((lx + 20, ly + 1, s.name.clone(), [20, 20, 20], 1));
        }
        root.present().map_err(|e| err(&e))?;
        let x_title = x_axis.title;
        labels.push(((x0 + x1) / 2 - text_width(x_title, 1) / 2, y1 + 30, x_title.into(), [20, 20, 20], 1));
        labels.push((x0, 16, title.into(), [0, 0, 0], 2));
        labels.push((8, y0 - 16, y_label.into(), [20, 20, 20], 1));
    }
    for (x, y, s, c, scale) in labels {
        draw_text(&mut buf, w, h, x, y, &s, c, scale);
    }
    let img = crate::image::Image::from_vec(w, h, 3, buf.iter().map(|&v| v as f32 / 255.0).collect()).expect("size");
    crate::io::write_png(path, &img, 8, crate::color::Transfer::Linear)
}

fn fmt_ms(t: f64) -> String {
    if t >= 1000.0 {
        format!("{}s", t / 1000.0)
    } else if t >= 1.0 {
        format!("{t:.0}")
    } else {
        format!("{t}")
    }
}

fn nice_step(raw: f64) -> f64 {
    let p = 10f64.powf(raw.max(1e-9).log10().floor());
    let m = raw / p;
    p * if m <= 1.0 {
        1.0
    } else if m <= 2.0 {
        2.0
    } else if m <= 5.0 {
        5.0
    } else {
        10.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_writes_a_png() {
        let dir = std::env::temp_dir().join(format!("drbokeh-plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("p.png");
        let s = vec![
            Series {
                name: "a".into(),
                points: vec![Point { x: 3.0, value: 30.0, label: "q1".into() }, Point { x: 40.0, value: 33.0, label: "exact".into() }],
            },
            Series { name: "b".into(), points: vec![Point { x: 0.5, value: 25.0, label: "x".into() }] },
        ];
        error_vs_time(&p, "title", "PSNR", &s).unwrap();
        assert!(std::fs::metadata(&p).unwrap().len() > 1000);
        std::fs::remove_dir_all(&dir).ok();
    }
}
