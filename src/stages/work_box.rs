//! The part of the frame that one peel (fill depth, inpaint, soft-edge colour) can touch, and
//! the frame-sized results of a peel run on that part only.
//!
//! Every stage of a peel reads and writes near the layer's visible pixels: the foreground's
//! disparity matters only within its visibility reach of them, the background fill's holes
//! lie under them, and the tests and carries around the outline read a few pixels further.
//! A subject that covers a third of a 12 MP frame leaves most of the frame untouched, and the
//! stages' frame-sized masks and copies were most of their cost there, so the pipeline runs
//! the peel on the visible pixels' box grown by [`margin`] and widens the answer again
//! ([`widen_layer`], [`Image::paste`]).

use super::background::InpaintOptions;
use super::depth_edges::EdgeWidths;
use super::fill_depth::FillDepthOptions;
use super::foreground::CARRY_PX;
use super::highlights::WINDOW_HALF;
use crate::image::Image;
use crate::render::layer::{A, CHANNELS, D};
use rayon::prelude::*;

/// A window of the frame, `(x0, y0, x1, y1)` with exclusive ends.
pub type Window = (usize, usize, usize, usize);

/// Largest share of the frame a work box may cover: beyond it, cropping and widening cost
/// more than the frame-sized scans they save.
pub const MAX_SHARE: f64 = 0.8;

/// How far (pixels) around the visible pixels a peel's stages read or write something that
/// reaches the render, for the largest CoC radius `max_coc` and the measured depth-edge ramp:
/// the foreground's visibility reach (≤ `max_coc/2 + 2`) plus its depth fill's Telea disc;
/// the ramp model's background fill and Gaussian weights (≤ 3 ramp widths); the background
/// fill's mask growth, its edge-band test windows (2 × growth + 3), highlight windows and the
/// cut highlights' disc fits (within the discs' term); the
/// carried colour's reach; and a margin for the fills' discs and rounding. Generous on
/// purpose: a larger box only costs time.
pub fn margin(max_coc: f32, edges: &EdgeWidths, fill_depth: &FillDepthOptions, inpaint: &InpaintOptions) -> f32 {
    let visibility = max_coc.max(0.0) / 2.0 + 4.0;
    let ramp = 3.0 * (edges.inside_px + edges.outside_px) + 2.0;
    let background = 3.0 * inpaint.dilate.max(0.0) + 3.0 + WINDOW_HALF as f32;
    let discs = fill_depth.radius.max(0.0) + inpaint.radius.max(0.0) + 16.0;
    visibility + ramp + background + CARRY_PX + discs
}

/// The box of `alpha > 0` grown by `margin`, when it is non-empty and covers at most
/// [`MAX_SHARE`] of the frame; None otherwise (run the peel on the whole frame).
pub fn work_box(alpha: &Image, margin: f32) -> Option<Window> {
    if !margin.is_finite() {
        return None;
    }
    let b @ (x0, y0, x1, y1) = super::mask::visible_box(alpha, margin)?;
    let share = ((x1 - x0) * (y1 - y0)) as f64 / (alpha.width * alpha.height).max(1) as f64;
    (share <= MAX_SHARE).then_some(b)
}

/// The frame-sized RGBAD layer of a peel run on window `b`: the photo's colour everywhere
/// (`photo`, linear RGB, frame-sized), the window's `alpha` and `disparity` (one channel each,
/// window-sized) inside it; outside, alpha 0 and disparity `quiet` (the value the depth fill
/// gives pixels no blur can show), or the frame's own `disp` without one. Rows in parallel;
/// allocates the frame (the soft edge's colour is pasted over it after).
pub fn widen_layer(photo: &Image, disp: &Image, alpha: &Image, disparity: &Image, b: Window, quiet: Option<f32>) -> Image {
    let (x0, iw) = (b.0, b.2 - b.0);
    debug_assert_eq!((alpha.width, alpha.height, disparity.width, disparity.height), (iw, b.3 - b.1, iw, b.3 - b.1));
    frame_layer(
        photo,
        b,
        |i, px| put(px, &photo.data[i * 3..i * 3 + 3], 0.0, quiet.unwrap_or(disp.data[i])),
        |y, row| {
            let i0 = (b.1 + y) * photo.width + x0;
            for (x, px) in row.chunks_exact_mut(CHANNELS).enumerate() {
                let (i, j) = (i0 + x, y * iw + x);
                put(px, &photo.data[i * 3..i * 3 + 3], alpha.data[j], disparity.data[j]);
            }
        },
    )
}

/// The opaque RGBAD layer of the scene behind a peel run on window `b`: the inpainted colour
/// `rgb` and disparity `disparity` (window-sized) inside it, the peel's input `photo` and
/// `disp` (frame-sized) outside; alpha 1 everywhere. Rows in parallel; allocates the frame
/// (and nothing else: no frame-sized copy of the photo or alpha plane on the way).
pub fn opaque_layer(rgb: &Image, disparity: &Image, photo: &Image, disp: &Image, b: Window) -> Image {
    let iw = b.2 - b.0;
    debug_assert_eq!((rgb.width, rgb.height, disparity.width, disparity.height), (iw, b.3 - b.1, iw, b.3 - b.1));
    frame_layer(
        photo,
        b,
        |i, px| put(px, &photo.data[i * 3..i * 3 + 3], 1.0, disp.data[i]),
        |y, row| {
            for (x, px) in row.chunks_exact_mut(CHANNELS).enumerate() {
                let j = y * iw + x;
                put(px, &rgb.data[j * 3..j * 3 + 3], 1.0, disparity.data[j]);
            }
        },
    )
}

/// Writes one RGBAD pixel.
#[inline(always)]
fn put(px: &mut [f32], rgb: &[f32], alpha: f32, disparity: f32) {
    px[..3].copy_from_slice(rgb);
    px[A] = alpha;
    px[D] = disparity;
}

/// A frame-sized RGBAD image (the size of `photo`) written row by row in parallel: each pixel
/// outside the window `b` by `outside(pixel index, pixel)`, each window row by `inside(row
/// of the window, the row's window part)`.
fn frame_layer(
    photo: &Image,
    (x0, y0, x1, y1): Window,
    outside: impl Fn(usize, &mut [f32]) + Sync,
    inside: impl Fn(usize, &mut [f32]) + Sync,
) -> Image {
    let w = photo.width;
    let mut out = Image::new(w, photo.height, CHANNELS);
    if w == 0 {
        return out;
    }
    out.data.par_chunks_exact_mut(w * CHANNELS).enumerate().for_each(|(y, row)| {
        let around = |row: &mut [f32], xs: std::ops::Range<usize>| {
            for x in xs {
                outside(y * w + x, &mut row[x * CHANNELS..(x + 1) * CHANNELS]);
            }
        };
        if (y0..y1).contains(&y) {
            around(row, 0..x0);
            inside(y - y0, &mut row[x0 * CHANNELS..x1 * CHANNELS]);
            around(row, x1..w);
        } else {
            around(row, 0..w);
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_box_is_the_visible_pixels_grown_and_none_when_too_large() {
        let mut alpha = Image::new(100, 80, 1);
        alpha.data[30 * 100 + 40] = 0.5;
        alpha.data[40 * 100 + 50] = 1.0;
        assert_eq!(work_box(&alpha, 5.0), Some((40 - 6, 30 - 6, 51 + 6, 41 + 6)));
        // Grown past the frame's edges: clipped, then too large a share.
        assert_eq!(work_box(&alpha, 60.0), None);
        assert_eq!(work_box(&Image::new(10, 10, 1), 1.0), None);
        assert_eq!(work_box(&alpha, f32::INFINITY), None);
    }

    #[test]
    fn widening_puts_the_window_back_and_the_photo_around_it() {
        let (w, h) = (7, 5);
        let photo = Image::from_vec(w, h, 3, (0..w * h * 3).map(|v| v as f32).collect()).unwrap();
        let disp = Image::from_vec(w, h, 1, (0..w * h).map(|v| v as f32 / 100.0).collect()).unwrap();
        let b = (2, 1, 5, 4);
        let alpha = Image::from_vec(3, 3, 1, (0..9).map(|v| v as f32 / 8.0).collect()).unwrap();
        let disparity = Image::from_vec(3, 3, 1, (0..9).map(|v| 0.5 + v as f32 / 100.0).collect()).unwrap();
        for quiet in [Some(0.25), None] {
            let out = widen_layer(&photo, &disp, &alpha, &disparity, b, quiet);
            for y in 0..h {
                for x in 0..w {
                    let (px, i) = (&out.data[(y * w + x) * CHANNELS..][..CHANNELS], y * w + x);
                    assert_eq!(&px[..3], &photo.data[i * 3..i * 3 + 3]);
                    if (2..5).contains(&x) && (1..4).contains(&y) {
                        let j = (y - 1) * 3 + x - 2;
                        assert_eq!((px[A], px[D]), (alpha.data[j], disparity.data[j]));
                    } else {
                        assert_eq!((px[A], px[D]), (0.0, quiet.unwrap_or(disp.data[i])));
                    }
                }
            }
        }
        // The opaque layer: the window's colour and disparity inside, the frame's outside.
        let (rgb, d) = (Image::filled(3, 3, 3, 7.0), Image::filled(3, 3, 1, 0.5));
        let out = opaque_layer(&rgb, &d, &photo, &disp, b);
        for y in 0..h {
            for x in 0..w {
                let (px, i) = (&out.data[(y * w + x) * CHANNELS..][..CHANNELS], y * w + x);
                let inside = (2..5).contains(&x) && (1..4).contains(&y);
                assert_eq!(&px[..3], if inside { &[7.0; 3][..] } else { &photo.data[i * 3..i * 3 + 3] });
                assert_eq!(px[A], 1.0);
                assert_eq!(px[D], if inside { 0.5 } else { disp.data[i] });
            }
        }
    }
}
