//! Closed-form matting (Levin, Lischinski and Weiss 2008) on a trimap's unknown pixels.
//!
//! In every 3×3 window alpha is taken as a linear function of colour; eliminating the
//! per-window coefficients leaves the quadratic form `αᵀ L α` with the matting Laplacian
//! `L_ij = Σ_k [δ_ij − (1 + (I_i − μ_k)ᵀ (Σ_k + ε/9·U)⁻¹ (I_j − μ_k)) / 9]` over the windows `k`
//! holding both pixels. With the known pixels fixed, the unknown ones solve `L_UU α_U = −L_UK α_K`,
//! here by conjugate gradients with a Jacobi preconditioner, `L` applied without being stored:
//! each window keeps its mean colour and its inverted 3×3 (`(L v)_i = Σ_k v_i − v̄_k −
//! (I_i − μ_k)ᵀ Δ_k s_k`, `s_k` the window's colour-weighted mean of `v`).
//!
//! Colours are the photo's linear values clipped to [0, 1] (as [`super::matting`] uses them).
//! Cost: the windows touching an unknown pixel (about 3× the unknown count), 12 f64 each, a
//! `u32` index over the trimap's box; each iteration is two passes over them, in parallel.

use rayon::prelude::*;

/// Regularization of the window covariances (colour units squared, as PyMatting's default).
pub const EPS: f64 = 1e-6;
/// Iterations at most: the band is a few pixels wide, and CG converges in a few times that.
const MAX_ITERATIONS: usize = 2000;
/// Stop when the preconditioned residual has fallen by this factor.
const TOLERANCE: f64 = 1e-6;

/// One window: its mean colour and `(Σ + ε/9·U)⁻¹` (symmetric, 6 entries: xx xy xz yy yz zz).
#[derive(Clone, Copy)]
struct Window {
    centre: usize,
    mu: [f64; 3],
    inv: [f64; 6],
}

/// Solves the unknown pixels of a frame `w` wide: `unknown` marks them (frame-sized), `value`
/// gives the known pixels' alpha and the unknown ones' start (frame-sized), `colour(i)` pixel
/// `i`'s colour. Unknown pixels on the frame's border rows and columns (where no 3×3 window
/// fits on both sides) are solved like the rest from the windows that fit. Returns the unknown
/// pixels' (frame index, alpha in [0, 1]).
pub fn solve(w: usize, h: usize, unknown: &[bool], value: &[f32], colour: &(dyn Fn(usize) -> [f32; 3] + Sync)) -> Vec<(usize, f32)> {
    let idx: Vec<usize> = (0..w * h).into_par_iter().filter(|&i| unknown[i]).collect();
    if idx.is_empty() || w < 3 || h < 3 {
        return idx.iter().map(|&i| (i, value[i].clamp(0.0, 1.0))).collect();
    }
    // Window centres: pixels at least 1 from the border within 1 of an unknown pixel.
    let mut is_centre = vec![false; w * h];
    for &i in &idx {
        let (x, y) = (i % w, i / w);
        for cy in y.saturating_sub(1).max(1)..(y + 2).min(h - 1) {
            for cx in x.saturating_sub(1).max(1)..(x + 2).min(w - 1) {
                is_centre[cy * w + cx] = true;
            }
        }
    }
    let windows: Vec<Window> = (0..w * h)
        .into_par_iter()
        .filter(|&c| is_centre[c])
        .map(|c| {
            let px: Vec<[f64; 3]> = neighbours(c, w).map(|j| colour(j).map(f64::from)).collect();
            let mu: [f64; 3] = std::array::from_fn(|a| px.iter().map(|p| p[a]).sum::<f64>() / 9.0);
            let cov = |a: usize, b: usize| px.iter().map(|p| (p[a] - mu[a]) * (p[b] - mu[b])).sum::<f64>() / 9.0;
            let e = EPS / 9.0;
            let m = [cov(0, 0) + e, cov(0, 1), cov(0, 2), cov(1, 1) + e, cov(1, 2), cov(2, 2) + e];
            Window { centre: c, mu, inv: inverse(m) }
        })
        .collect();
    drop(is_centre);
    let mut slot = vec![u32::MAX; w * h];
    for (k, win) in windows.iter().enumerate() {
        slot[win.centre] = k as u32;
    }
    // The windows holding unknown pixel i: centres within 1 of it.
    let around = |i: usize| {
        let (x, y) = (i % w, i / w);
        let slot = &slot;
        (y.saturating_sub(1)..(y + 2).min(h))
            .flat_map(move |cy| (x.saturating_sub(1)..(x + 2).min(w)).map(move |cx| cy * w + cx))
            .filter_map(move |c| {
                let k = slot[c];
                (k != u32::MAX).then_some(k as usize)
            })
    };
    let col: Vec<[f64; 3]> = idx.par_iter().map(|&i| colour(i).map(f64::from)).collect();
    // Jacobi preconditioner: L_ii = Σ_k 1 − (1 + dᵀΔd)/9.
    let diag: Vec<f64> = idx
        .par_iter()
        .zip(&col)
        .map(|(&i, c)| {
            around(i)
                .map(|k| {
                    let win = &windows[k];
                    let d = sub(c, &win.mu);
                    1.0 - (1.0 + quad(&win.inv, &d, &d)) / 9.0
                })
                .sum::<f64>()
                .max(1e-12)
        })
        .collect();
    // L applied to the frame vector `v`, at the unknown pixels.
    let apply = |v: &[f64]| -> Vec<f64> {
        let per_window: Vec<(f64, [f64; 3])> = windows
            .par_iter()
            .map(|win| {
                let (mut mean, mut s) = (0.0, [0.0; 3]);
                for j in neighbours(win.centre, w) {
                    let d = sub(&colour(j).map(f64::from), &win.mu);
                    mean += v[j];
                    for a in 0..3 {
                        s[a] += d[a] * v[j];
                    }
                }
                (mean / 9.0, mat_vec(&win.inv, &s.map(|x| x / 9.0)))
            })
            .collect();
        idx.par_iter()
            .zip(&col)
            .map(|(&i, c)| {
                around(i)
                    .map(|k| {
                        let (mean, t) = &per_window[k];
                        let d = sub(c, &windows[k].mu);
                        v[i] - mean - (d[0] * t[0] + d[1] * t[1] + d[2] * t[2])
                    })
                    .sum()
            })
            .collect()
    };
    // x: the frame vector with the known values; r = −(L x)_U.
    let mut x: Vec<f64> = value.par_iter().map(|&a| a as f64).collect();
    let mut r: Vec<f64> = apply(&x).into_iter().map(|v| -v).collect();
    let mut z: Vec<f64> = r.iter().zip(&diag).map(|(r, d)| r / d).collect();
    let mut p = z.clone();
    let mut rz: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
    let start = rz.abs();
    let mut frame_p = vec![0.0f64; w * h];
    for _ in 0..MAX_ITERATIONS {
        // Converged, or a NaN (which no comparison passes).
        if rz.abs().partial_cmp(&(start * TOLERANCE * TOLERANCE)) != Some(std::cmp::Ordering::Greater) {
            break;
        }
        for (&i, &pv) in idx.iter().zip(&p) {
            frame_p[i] = pv;
        }
        let ap = apply(&frame_p);
        let pap: f64 = p.iter().zip(&ap).map(|(a, b)| a * b).sum();
        // L is positive semi-definite: p·Lp ≤ 0 (or NaN) means rounding took over.
        if pap.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            break;
        }
        let step = rz / pap;
        for (k, &i) in idx.iter().enumerate() {
            x[i] += step * p[k];
            r[k] -= step * ap[k];
        }
        z.iter_mut().zip(&r).zip(&diag).for_each(|((z, r), d)| *z = r / d);
        let next: f64 = r.iter().zip(&z).map(|(a, b)| a * b).sum();
        let beta = next / rz;
        rz = next;
        p.iter_mut().zip(&z).for_each(|(p, z)| *p = z + beta * *p);
    }
    idx.iter().map(|&i| (i, if x[i].is_finite() { x[i].clamp(0.0, 1.0) as f32 } else { value[i].clamp(0.0, 1.0) })).collect()
}

/// The 9 pixels of the window centred at `c` (not on the border) in a frame `w` wide.
fn neighbours(c: usize, w: usize) -> impl Iterator<Item = usize> {
    (0..3).flat_map(move |dy| (0..3).map(move |dx| c + dy * w + dx - w - 1))
}

fn sub(a: &[f64; 3], b: &[f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `m·v` for a symmetric 3×3 stored as xx xy xz yy yz zz.
fn mat_vec(m: &[f64; 6], v: &[f64; 3]) -> [f64; 3] {
    [m[0] * v[0] + m[1] * v[1] + m[2] * v[2], m[1] * v[0] + m[3] * v[1] + m[4] * v[2], m[2] * v[0] + m[4] * v[1] + m[5] * v[2]]
}

/// `aᵀ m b`.
fn quad(m: &[f64; 6], a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let mb = mat_vec(m, b);
    a[0] * mb[0] + a[1] * mb[1] + a[2] * mb[2]
}

/// Inverse of a symmetric positive definite 3×3 (xx xy xz yy yz zz) by its adjugate.
fn inverse(m: [f64; 6]) -> [f64; 6] {
    let [a, b, c, d, e, f] = m;
    let (c00, c01, c02) = (d * f - e * e, c * e - b * f, b * e - c * d);
    let det = a * c00 + b * c01 + c * c02;
    let (c11, c12, c22) = (a * f - c * c, b * c - a * e, a * d - b * b);
    [c00 / det, c01 / det, c02 / det, c11 / det, c12 / det, c22 / det]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_times_matrix_is_identity() {
        let m = [4.0, 1.0, 0.5, 3.0, 0.2, 2.0];
        let inv = inverse(m);
        for k in 0..3 {
            let e: [f64; 3] = std::array::from_fn(|j| (j == k) as u8 as f64);
            let back = mat_vec(&m, &mat_vec(&inv, &e));
            assert!(back.iter().zip(e).all(|(a, b)| (a - b).abs() < 1e-12), "{back:?}");
        }
    }

    /// Two flat colours with a mixed column: closed-form matting gives the mixed pixels their
    /// share (the colour line holds exactly).
    #[test]
    fn a_mixed_edge_gets_its_share() {
        let (w, h) = (24, 10);
        let (fg, bg) = ([0.6f32, 0.3, 0.1], [0.05f32, 0.2, 0.5]);
        let cover = |x: usize| (11.4 - x as f32).clamp(0.0, 1.0);
        let photo: Vec<[f32; 3]> =
            (0..w * h).map(|i| std::array::from_fn(|c| cover(i % w) * fg[c] + (1.0 - cover(i % w)) * bg[c])).collect();
        let unknown: Vec<bool> = (0..w * h).map(|i| (8..15).contains(&(i % w))).collect();
        let value: Vec<f32> = (0..w * h).map(|i| if unknown[i] { 0.5 } else { ((i % w) < 8) as u8 as f32 }).collect();
        let out = solve(w, h, &unknown, &value, &|i| photo[i]);
        for (i, a) in out {
            assert!((a - cover(i % w)).abs() < 0.01, "pixel {i}: {a} vs {}", cover(i % w));
        }
    }
}
