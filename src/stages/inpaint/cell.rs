//! One cell's fill of the Telea march: the weights of the known cells in its disc and the
//! weighted mean, with OpenCV's finish (its gradient "nudge" and rounding) where asked
//! ([`super::OpenCvCompat`]).

use super::*;

/// For OpenCV's finish, the two image differences OpenCV takes at a known tap, as (plus, minus,
/// factor) indices into the data, and the tap's offset `r`.
#[derive(Clone, Copy)]
pub(super) struct GradTap {
    rx: f32,
    ry: f32,
    xp: usize,
    xm: usize,
    xf: f32,
    yp: usize,
    ym: usize,
    yf: f32,
}

pub(super) struct Ctx<'a> {
    pub(super) flags: &'a [u8],
    pub(super) t: &'a [f32],
    pub(super) disc: &'a Disc,
    pub(super) gw: usize,
    /// The image's size.
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) cv: OpenCvCompat,
}

impl Ctx<'_> {
    /// The weights of every disc cell around grid cell `n` for each path asked for (an empty
    /// slice is not computed; see [`Disc::weights`]), and the numbers of the known cells in
    /// `known` (a branchless compaction); returns how many are known.
    #[inline(always)]
    pub(super) fn known_weights<const MODE: u8>(&self, n: usize, (w3, w1): (&mut [f32], &mut [f32]), known: &mut [u32]) -> usize {
        let (flags, t, disc) = (self.flags, self.t, self.disc);
        let settled = |q: usize| flags[q] != INSIDE;
        let g = (known_diff(settled, t, n, 1), known_diff(settled, t, n, self.gw));
        if !w3.is_empty() {
            disc.weights::<MODE, u8>(&disc.dst3, (flags, INSIDE, t), n, g, w3);
        }
        if !w1.is_empty() {
            disc.weights::<MODE, u8>(&disc.dst1, (flags, INSIDE, t), n, g, w1);
        }
        let wts: &[f32] = if w3.is_empty() { w1 } else { w3 };
        let mut m = 0;
        for (k, &wgt) in wts.iter().enumerate() {
            known[m] = k as u32;
            m += !wgt.is_sign_negative() as usize;
        }
        m
    }

    /// Computes the value of hole pixel (x, y) (image coordinates; grid cell `n`) from the
    /// known cells of its disc, reading and writing `data` (`ch` channels; for `CV_INT`, the
    /// image as codes), with the cells' `weights` and the `known` cell numbers of
    /// [`Ctx::known_weights`]. `EDGE`: some tap may lie on the image's first/last row or column
    /// (or outside it); only OpenCV's finish cares.
    ///
    /// The sums run over the known cells in OpenCV's order, all channels and the weight total
    /// in one pass (independent chains in registers), so the result is bit-identical to
    /// OpenCV's per-tap accumulation. `grads` is scratch for OpenCV's finish, reused.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    pub(super) fn pixel<const MODE: u8, const EDGE: bool>(
        &self,
        data: &mut [f32],
        ch: usize,
        (weights, known): (&[f32], &[u32]),
        grads: &mut Vec<GradTap>,
        n: usize,
        y: isize,
        x: isize,
    ) {
        let (flags, gw, cv, disc) = (self.flags, self.gw, self.cv, self.disc);
        let (wi, hi) = (self.w as isize, self.h as isize);
        let centre = (y * wi + x) as usize * ch;
        // A known tap lies inside the image, so its plain offset is always valid.
        let src = |k: u32| (centre as isize + disc.pixel[k as usize] * ch as isize) as usize;
        let at = |yy: isize, xx: isize| (yy.clamp(0, hi - 1) * wi + xx.clamp(0, wi - 1)) as usize * ch;
        let row = self.w * ch;
        grads.clear();
        let mut s = 1.0e-20f32;
        for &k in known {
            let k = k as usize;
            s += weights[k];
            let src = src(k as u32);
            let (dy, dx) = disc.offsets[k];
            let qc = (n as isize + dy * gw as isize + dx) as usize;
            let mut gt = GradTap { rx: disc.rx[k], ry: disc.ry[k], xp: src, xm: src, xf: 0.0, yp: src, ym: src, yf: 0.0 };
            // The colour comes from the tap itself, but OpenCV reads the image gradient through
            // indices shifted inwards on the image's first and last rows/columns.
            let (sy, sx) = (y + dy, x + dx);
            let (km, kp, lm, lp) = if EDGE {
                (sy + (sy == 0) as isize, sy - (sy == hi - 1) as isize, sx + (sx == 0) as isize, sx - (sx == wi - 1) as isize)
            } else {
                (sy, sy, sx, sx)
            };
            let (mid, right, left, down, up) = if EDGE {
                (at(km, lm), at(km, lp + 1), at(km, lm - 1), at(kp + 1, lm), at(km - 1, lm))
            } else {
                (src, src + ch, src - ch, src + row, src - row)
            };
            // The centre of a one-sided difference is also read at the shifted indices.
            let (xc, yc) = if EDGE { (at(km, lp), at(kp, lm)) } else { (src, src) };
            // (plus, minus, factor) of each difference; factor 0 when both sides are unknown.
            (gt.xp, gt.xm, gt.xf) = match (flags[qc + 1] != INSIDE, flags[qc - 1] != INSIDE) {
                (true, true) => (right, left, 2.0),
                (true, false) => (right, mid, 1.0),
                (false, true) => (xc, left, 1.0),
                (false, false) => (mid, mid, 0.0),
            };
            (gt.yp, gt.ym, gt.yf) = match (flags[qc + gw] != INSIDE, flags[qc - gw] != INSIDE) {
                (true, true) => (down, up, 2.0),
                (true, false) => (down, mid, 1.0),
                (false, true) => (yc, up, 1.0),
                (false, false) => (mid, mid, 0.0),
            };
            grads.push(gt);
        }
        for c in 0..ch {
            let (mut ia, mut jx, mut jy) = (0.0f32, 0.0f32, 0.0f32);
            for (&k, gt) in known.iter().zip(grads.iter()) {
                let wgt = weights[k as usize];
                let gx = if gt.xf == 0.0 { 0.0 } else { (data[gt.xp + c] - data[gt.xm + c]) * gt.xf };
                let gy = if gt.yf == 0.0 { 0.0 } else { (data[gt.yp + c] - data[gt.ym + c]) * gt.yf };
                ia += wgt * data[src(k) + c];
                jx -= wgt * (gx * gt.rx);
                jy -= wgt * (gy * gt.ry);
            }
            let mean = ia / s;
            // OpenCV's nudge: the component sum of a unit vector, in code values.
            let nudge = (jx + jy) / ((jx * jx + jy * jy).sqrt() + 1.0e-20);
            data[centre + c] = if MODE == CV_INT {
                let max = cv.max_code.unwrap_or(f32::MAX) as f64;
                // Integer types get +0.5 before rounding (OpenCV's `round_cast`).
                round_even_f64((mean + nudge) as f64 + 0.5).clamp(0.0, max) as f32
            } else {
                mean + cv.unit * nudge
            };
        }
    }
}
