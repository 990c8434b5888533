//! The backward pass (`render::backward`) against central finite differences of an f64
//! reference of the same forward (written here from DESIGN.md and the lens terms, and checked
//! against the library's f32 forward first), on seeded random small scenes with pixels near the
//! focal plane and at occlusion boundaries, both profiles; and finiteness on the extreme grid.

use crate::common;

use common::Rng;
use drbokeh::Image;
use drbokeh::render::{Gradients, Kernel, Layer, Profile, RenderSettings, Smoothing, Tape, aperture, render};

// ---------------------------------------------------------------------------------------------
// The f64 reference forward.
// ---------------------------------------------------------------------------------------------

/// A scene in f64: layers `[R, G, B, A, D]` row-major, settings, smoothing.
#[derive(Clone)]
struct Scene {
    w: usize,
    h: usize,
    layers: Vec<Vec<f64>>,
    focus: f64,
    blur: f64,
    lens: usize,
    occlusion: bool,
    profile: Profile,
    smooth: Smoothing,
    /// The physical profile's ray test ([`Tape::record_with`]).
    ray: bool,
}

fn soft_step(a: f64, b: f64) -> f64 {
    1.0 / (1.0 + (-(3.0 * (a - b) - std::f64::consts::LN_10)).exp())
}

fn in_front(dy: f64, dx: f64) -> f64 {
    0.5 + 0.5 * (10.0 * (dy - dx - 0.1)).tanh()
}

fn smoothstep_cov(r: f64, rho: f64, width: f64) -> f64 {
    let t = ((r - rho) / width + 0.5).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Lattice sum of the smooth coverage, point by point (the library uses ring tables).
fn smooth_norm(r: f64, width: f64) -> f64 {
    if r + width / 2.0 > 65.0 {
        return std::f64::consts::PI * (r * r + width * width / 20.0);
    }
    let reach = (r + width).ceil() as i64;
    let mut s = 0.0;
    for dy in -reach..=reach {
        for dx in -reach..=reach {
            s += smoothstep_cov(r, ((dx * dx + dy * dy) as f64).sqrt(), width);
        }
    }
    s
}

fn fill_min(x: f64, w: f64) -> f64 {
    if x <= 1.0 - w {
        x.min(1.0)
    } else if x >= 1.0 + w {
        1.0
    } else {
        x - (x - 1.0 + w).powi(2) / (4.0 * w)
    }
}

impl Scene {
    fn px(&self, l: usize, x: i64, y: i64) -> &[f64] {
        let (x, y) = (x.clamp(0, self.w as i64 - 1) as usize, y.clamp(0, self.h as i64 - 1) as usize);
        let i = y * self.w + x;
        &self.layers[l][i * 5..i * 5 + 5]
    }

    /// Per layer, per pixel `[X_r, X_g, X_b, W, V]` (colour sums, weight, visibility).
    fn raw(&self, l: usize) -> Vec<[f64; 5]> {
        let taps = aperture::disk_taps(self.lens);
        let p = (self.lens / 2) as i64;
        let mut out = Vec::with_capacity(self.w * self.h);
        let ew = self.smooth.edge_width as f64;
        let norms: Vec<f64> =
            (0..self.w * self.h).map(|j| smooth_norm((self.layers[l][j * 5 + 4] - self.focus).abs() * self.blur, ew)).collect();
        for y in 0..self.h as i64 {
            for x in 0..self.w as i64 {
                let dx = self.px(l, x, y)[4] - self.focus;
                match self.profile {
                    Profile::Official => {
                        let c = dx.abs() * self.blur;
                        let q = if !self.occlusion || c >= 2.5 { 1.0 } else { 1.0 - (-3.0 * c * c).exp() };
                        let mut acc = [0f64; 4];
                        for t in &taps {
                            let s = self.px(l, x + t.dj as i64, y + t.di as i64);
                            let sigma = (s[4] - self.focus).abs() * self.blur + 1.0;
                            let r = ((t.di * t.di + t.dj * t.dj) as f64).sqrt();
                            let e = soft_step(sigma, r) / (sigma * sigma);
                            let v =
                                if (t.di == 0 && t.dj == 0) || q == 1.0 { 1.0 } else { q + (1.0 - q) * in_front(s[4] - self.focus, dx) };
                            let k = s[3] * e * v;
                            for c in 0..3 {
                                acc[c] += k * s[c];
                            }
                            acc[3] += k;
                        }
                        let sigma = dx.abs() * self.blur + 1.0;
                        let n = ((sigma / 2.0).trunc() as i64).min(p);
                        let mut box_sum = 0.0;
                        for yy in y - n..=y + n {
                            for xx in x - n..=x + n {
                                box_sum += self.px(l, xx, yy)[3];
                            }
                        }
                        out.push([acc[0], acc[1], acc[2], acc[3], box_sum / ((2 * n + 1) * (2 * n + 1)) as f64]);
                    }
                    Profile::Physical => {
                        let fw = self.smooth.fill_width as f64;
                        let mut groups = [[0f64; 4]; 3];
                        for t in &taps {
                            let s = self.px(l, x + t.dj as i64, y + t.di as i64);
                            let ds = s[4] - self.focus;
                            let radius = ds.abs() * self.blur;
                            let rho = ((t.di * t.di + t.dj * t.dj) as f64).sqrt();
                            let j = ((y + t.di as i64).clamp(0, self.h as i64 - 1) * self.w as i64
                                + (x + t.dj as i64).clamp(0, self.w as i64 - 1)) as usize;
                            let wt = s[3] * smoothstep_cov(radius, rho, ew) / norms[j];
                            let split = if (t.di == 0 && t.dj == 0) || !self.occlusion {
                                [0.0, 1.0, 0.0]
                            } else {
                                let (f, b) = (in_front(ds, dx), in_front(dx, ds));
                                let clear = if self.ray { self.ray_clear(l, (x, y), (t.dj, t.di), dx, ds) } else { 1.0 };
                                [f, 1.0 - f - b, b * clear]
                            };
                            for g in 0..3 {
                                for c in 0..3 {
                                    groups[g][c] += wt * split[g] * s[c];
                                }
                                groups[g][3] += wt * split[g];
                            }
                        }
                        // The fill, front to back.
                        let (mut pr, mut cum, mut m_cum) = ([0f64; 3], 0f64, 0f64);
                        for g in &groups {
                            if g[3] <= 0.0 {
                                continue;
                            }
                            let m_next = fill_min(cum + g[3], fw);
                            for c in 0..3 {
                                pr[c] += g[c] * (m_next - m_cum) / g[3];
                            }
                            cum += g[3];
                            m_cum = m_next;
                        }
                        let backdrop = l + 1 == self.layers.len();
                        let vis = if backdrop { m_cum.max(self.px(l, x, y)[3]) } else { m_cum };
                        out.push([pr[0], pr[1], pr[2], m_cum, vis]);
                    }
                }
            }
        }
        out
    }

    /// The ray test from target `(x, y)` (relative disparity `ep`) to the source at offset `off`
    /// (`es`): the ray crosses the target's depth at `t = ep/es` of the offset, clamped to
    /// `lens/2 - 1` pixels per axis and to the image; clear where the layer's relative
    /// disparity there (bilinear) is below `ep - 0.1`, a smoothstep 0.05 wide.
    fn ray_clear(&self, l: usize, (x, y): (i64, i64), off: (i32, i32), ep: f64, es: f64) -> f64 {
        let t = ep / es;
        if !t.is_finite() || t.abs() > 1e6 {
            return 1.0;
        }
        let reach = (self.lens / 2) as i64 - 1;
        let coord = |p: i64, o: i32, n: usize| {
            let (lo, hi) = ((p - reach).max(0) as f64, ((p + reach).min(n as i64 - 1) as f64).max((p - reach).max(0) as f64));
            (p as f64 + t * o as f64).clamp(lo, hi)
        };
        let (qx, qy) = (coord(x, off.0, self.w), coord(y, off.1, self.h));
        let (x0, y0) = (qx.floor(), qy.floor());
        let (fx, fy) = (qx - x0, qy - y0);
        let d = |xx: f64, yy: f64| self.px(l, xx as i64, yy as i64)[4] - self.focus;
        let dq =
            (d(x0, y0) * (1.0 - fx) + d(x0 + 1.0, y0) * fx) * (1.0 - fy) + (d(x0, y0 + 1.0) * (1.0 - fx) + d(x0 + 1.0, y0 + 1.0) * fx) * fy;
        let u = ((ep - 0.1 - dq) / 0.05 + 0.5).clamp(0.0, 1.0);
        u * u * (3.0 - 2.0 * u)
    }

    /// The composited linear RGB (eq. 2), unclamped colours.
    fn render(&self) -> Vec<f64> {
        let raws: Vec<Vec<[f64; 5]>> = (0..self.layers.len()).map(|l| self.raw(l)).collect();
        let mut out = vec![0f64; self.w * self.h * 3];
        for i in 0..self.w * self.h {
            let mut t = 1.0;
            for raw in &raws {
                let p = raw[i];
                if p[3] > 0.0 {
                    for c in 0..3 {
                        out[i * 3 + c] += p[c] / p[3] * p[4] * t;
                    }
                }
                t *= 1.0 - p[4];
            }
        }
        out
    }

    fn loss(&self, cot: &[f64]) -> f64 {
        self.render().iter().zip(cot).map(|(a, b)| a * b).sum()
    }

    fn library_layers(&self) -> Vec<Layer<'static>> {
        self.layers
            .iter()
            .map(|l| Layer::new(Image::from_vec(self.w, self.h, 5, l.iter().map(|&v| v as f32).collect()).unwrap(), "test").unwrap())
            .collect()
    }

    fn settings(&self) -> RenderSettings {
        RenderSettings {
            blur: self.blur as f32,
            focus: self.focus as f32,
            lens: self.lens,
            occlusion: self.occlusion,
            profile: self.profile,
            aperture: drbokeh::render::Aperture::DISC,
        }
    }
}

/// A random `w × h` two-layer scene: a front layer with a soft-edged blob (alpha exactly 0
/// outside it, exactly 1 in its core) at disparity ~0.75, a backdrop slanted in disparity with
/// a hard step; the focus on a random pixel of a random layer, nudged off it by `0.02/K` so
/// that some pixels sit just off the focal plane (|d|·K ~ 0.02).
fn random_scene(seed: u64, profile: Profile, w: usize, h: usize) -> Scene {
    let mut rng = Rng::new(seed);
    let mut r = || rng.next_f32() as f64;
    let lens = [9usize, 11, 13, 15][(r() * 4.0) as usize % 4];
    let blur = 3.0 + 9.0 * r();
    let (cx, cy, rad) = (w as f64 * (0.3 + 0.4 * r()), h as f64 * (0.3 + 0.4 * r()), w as f64 * (0.2 + 0.15 * r()));
    let step = (w as f64 * (0.3 + 0.4 * r())) as usize;
    let mut front = Vec::new();
    let mut back = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let dist = ((x as f64 - cx).powi(2) + (y as f64 - cy).powi(2)).sqrt();
            let a = ((rad - dist) / 2.0 + 0.5).clamp(0.0, 1.0);
            front.extend_from_slice(&[r() * 1.5, r(), r(), a, 0.7 + 0.1 * r()]);
            let dback = if x < step { 0.2 + 0.01 * y as f64 } else { 0.45 } + 0.02 * r();
            // Backdrop alpha below 1: its visibility max(coverage, α) then never ties at 1.
            back.extend_from_slice(&[r(), r() * 2.0, r(), 0.9 + 0.09 * r(), dback]);
        }
    }
    let layers = vec![front, back];
    let pick = (r() * (w * h) as f64) as usize % (w * h);
    let l = if r() < 0.5 { 0 } else { 1 };
    let focus = layers[l][pick * 5 + 4] + 0.02 / blur;
    Scene { w, h, layers, focus, blur, lens, occlusion: true, profile, smooth: Smoothing { edge_width: 1.0, fill_width: 0.1 }, ray: false }
}

// ---------------------------------------------------------------------------------------------
// Finite-difference checks.
// ---------------------------------------------------------------------------------------------

#[derive(Clone, Copy, Debug, PartialEq)]
enum Param {
    Channel(usize, usize, usize),
    Focus,
    Blur,
}

fn perturbed(sc: &Scene, p: Param, delta: f64) -> Scene {
    let mut s = sc.clone();
    match p {
        Param::Channel(l, i, c) => s.layers[l][i * 5 + c] += delta,
        Param::Focus => s.focus += delta,
        Param::Blur => s.blur += delta,
    }
    s
}

fn analytic(g: &Gradients, p: Param) -> f64 {
    match p {
        Param::Channel(l, i, c) => g.layers[l].data[i * 5 + c] as f64,
        Param::Focus => g.focus as f64,
        Param::Blur => g.blur as f64,
    }
}

/// Step per kind of parameter: colours enter linearly; disparities meet tanh(10·) and soft
/// steps of slope 3K, so their step is small (the reference is f64).
fn step(p: Param) -> f64 {
    match p {
        Param::Channel(_, _, c) if c < 3 => 1e-3,
        Param::Channel(_, _, 3) => 1e-5,
        Param::Channel(..) | Param::Focus => 1e-6,
        Param::Blur => 1e-5,
    }
}

/// Per kind of parameter (R, G, B, A in (0, 1], D, focus, K, A = 0): how many were compared,
/// how many skipped as not smooth there, and the largest relative error.
#[derive(Default, Debug)]
struct Report {
    compared: [usize; KINDS],
    skipped: [usize; KINDS],
    max_rel: [f64; KINDS],
}

const KINDS: usize = 8;
/// The kind of alpha exactly 0, where the official model jumps: a layer with no weight at a
/// target but some box visibility there (a transparent window inside a box with visible
/// corners) composites black, and the first ε of alpha among its taps makes it that tap's
/// colour.
const ALPHA_ZERO: usize = 7;

fn kind(sc: &Scene, p: Param) -> usize {
    match p {
        Param::Channel(l, i, 3) if sc.layers[l][i * 5 + 3] == 0.0 => ALPHA_ZERO,
        Param::Channel(_, _, c) => c,
        Param::Focus => 5,
        Param::Blur => 6,
    }
}

/// Compares every parameter of `sc` (every channel of every pixel of every layer, focus, K)
/// with central differences of the f64 reference. A parameter is skipped as not smooth where
/// the differences at steps h and h/4 disagree (a kink or jump within h: the visibility box's
/// `trunc`, a weight leaving 0); the relative error is `|analytic - fd| / max(|fd|, floor)`
/// with `floor` 1e-3 of the largest |fd| of that kind.
fn check_scene(sc: &Scene, seed: u64) -> Report {
    let mut rng = Rng::new(seed ^ 0xC07);
    let cot: Vec<f64> = (0..sc.w * sc.h * 3).map(|_| rng.next_f32() as f64 * 2.0 - 1.0).collect();
    let layers = sc.library_layers();
    let tape = Tape::record_with(&layers, &sc.settings(), sc.smooth, sc.ray).unwrap();
    // The reference is the library's function: same image to f32 precision.
    let want = sc.render();
    let worst = tape.image().data.iter().zip(&want).map(|(&a, &b)| (a as f64 - b).abs() / b.abs().max(1.0)).fold(0.0, f64::max);
    assert!(worst < 2e-5, "f64 reference and library forward differ by {worst:e}");
    let cot_img = Image::from_vec(sc.w, sc.h, 3, cot.iter().map(|&v| v as f32).collect()).unwrap();
    let g = tape.vjp(&cot_img).unwrap();
    // The f32 cotangent is what the library saw; use the same in the reference.
    let cot: Vec<f64> = cot_img.data.iter().map(|&v| v as f64).collect();

    let mut params: Vec<Param> = vec![Param::Focus, Param::Blur];
    for l in 0..sc.layers.len() {
        for i in 0..sc.w * sc.h {
            for c in 0..5 {
                params.push(Param::Channel(l, i, c));
            }
        }
    }
    let base = sc.loss(&cot);
    // Central differences; at alpha = 0, the edge of alpha's domain [0, 1] (where a source
    // starts to count: one-sided), forward differences with a Richardson step (error O(h²)).
    let fd = |p: Param, h: f64| {
        if matches!(p, Param::Channel(l, i, 3) if sc.layers[l][i * 5 + 3] == 0.0) {
            // Small: near a target that this source alone would light, the loss bends on the
            // scale of that target's tiny weight.
            let d = |h: f64| (perturbed(sc, p, h * 1e-2).loss(&cot) - base) / (h * 1e-2);
            2.0 * d(h / 2.0) - d(h)
        } else {
            (perturbed(sc, p, h).loss(&cot) - perturbed(sc, p, -h).loss(&cot)) / (2.0 * h)
        }
    };
    let results: Vec<(Param, f64, f64, bool)> = params
        .iter()
        .map(|&p| {
            let h = step(p);
            let (f1, f4) = (fd(p, h), fd(p, h / 4.0));
            let smooth = (f1 - f4).abs() <= 1e-4 * f4.abs().max(1e-3);
            (p, analytic(&g, p), f4, smooth)
        })
        .collect();
    let mut scale = [0f64; KINDS];
    for &(p, _, f, _) in &results {
        scale[kind(sc, p)] = scale[kind(sc, p)].max(f.abs());
    }
    let mut rep = Report::default();
    let mut failures = Vec::new();
    for &(p, a, f, smooth) in &results {
        let k = kind(sc, p);
        if !smooth {
            if std::env::var_os("FD_VERBOSE").is_some() {
                let v = if let Param::Channel(l, i, c) = p { sc.layers[l][i * 5 + c] } else { 0.0 };
                eprintln!("skipped {p:?} value {v} analytic {a:e} fd {f:e}");
            }
            rep.skipped[k] += 1;
            continue;
        }
        rep.compared[k] += 1;
        let rel = (a - f).abs() / f.abs().max(1e-3 * scale[k]).max(1e-12);
        rep.max_rel[k] = rep.max_rel[k].max(rel);
        if rel > 1e-3 {
            failures.push(format!("{p:?}: analytic {a:e} fd {f:e} rel {rel:e}"));
        }
    }
    assert!(
        failures.is_empty(),
        "{:?} seed {seed}: {} of {} parameters disagree:\n{}",
        sc.profile,
        failures.len(),
        results.len(),
        failures.join("\n")
    );
    rep
}

fn check_profile(profile: Profile) {
    let unchanged: fn(&mut Scene) = |_| {};
    check_variants(profile, &[unchanged; 4]);
}

/// [`check_scene`] on seeded scenes of `profile`, one per variant (seeds 1, 2, …), each
/// modified by its variant; asserts that at most 5% of each kind were skipped as not smooth.
fn check_variants(profile: Profile, variants: &[fn(&mut Scene)]) {
    let mut total = Report::default();
    for (n, variant) in variants.iter().enumerate() {
        let seed = n as u64 + 1;
        let mut sc = random_scene(seed, profile, 12, 12);
        variant(&mut sc);
        let rep = check_scene(&sc, seed);
        for k in 0..KINDS {
            total.compared[k] += rep.compared[k];
            total.skipped[k] += rep.skipped[k];
            total.max_rel[k] = total.max_rel[k].max(rep.max_rel[k]);
        }
    }
    eprintln!("{profile:?} [R, G, B, A, D, focus, K, A = 0]: {total:?}");
    // At most 5% of each kind is skipped as not smooth; alpha at 0 in the official profile
    // may jump (see ALPHA_ZERO) wherever a large box reaches visible pixels beyond the taps.
    for k in 0..KINDS {
        let bar = if k == ALPHA_ZERO && profile == Profile::Official { 2 } else { 20 };
        assert!(total.skipped[k] * bar <= total.compared[k] + total.skipped[k], "kind {k}: too many non-smooth points: {total:?}");
    }
}

#[test]
fn official_matches_finite_differences() {
    check_profile(Profile::Official);
}

#[test]
fn physical_matches_finite_differences() {
    check_profile(Profile::Physical);
}

#[test]
fn variants_match_finite_differences() {
    // Occlusion off (the classical scatter baseline); the physical profile's hard fill
    // (fill_width 0: kinks where the groups' coverage reaches 1 are skipped as not smooth) and
    // a narrower edge; a larger blur.
    check_variants(Profile::Official, &[|s| s.occlusion = false, |s| s.blur = 25.0]);
    check_variants(
        Profile::Physical,
        &[
            |s| s.occlusion = false,
            |s| s.smooth.fill_width = 0.0,
            |s| s.smooth = Smoothing { edge_width: 0.6, fill_width: 0.3 },
            |s| s.blur = 25.0,
        ],
    );
}

/// The physical profile with the ray test ([`Tape::record_with`]): both layers of the random
/// scene; the backdrop alone (one surface with a depth step, as depth from defocus renders
/// it); the backdrop alone with a larger blur, so that rays cross the step far from their
/// targets.
#[test]
fn ray_test_matches_finite_differences() {
    check_variants(
        Profile::Physical,
        &[
            |s| s.ray = true,
            |s| {
                s.ray = true;
                s.layers.remove(0);
            },
            |s| {
                s.ray = true;
                s.layers.remove(0);
                s.blur = 25.0;
            },
        ],
    );
    // The test is not vacuous: it changes the backdrop's render (rays stopped at the step).
    let mut sc = random_scene(3, Profile::Physical, 12, 12);
    sc.layers.remove(0);
    sc.blur = 25.0;
    let layers = sc.library_layers();
    let with = |ray| Tape::record_with(&layers, &sc.settings(), sc.smooth, ray).unwrap().image().clone();
    let (plain, ray) = (with(false), with(true));
    let changed = plain.data.iter().zip(&ray.data).filter(|(a, b)| (*a - *b).abs() > 1e-3).count();
    eprintln!("ray test changes {changed} of {} values", plain.data.len());
    assert!(changed * 10 >= plain.data.len(), "the ray test changed only {changed} values");
}

/// Checks the gradients `g` of `loss(scene, cotangent)` at `sc` along three random directions
/// over every parameter at once (colours and alpha ±1, disparity ±0.1, focus ±0.1, K ±1; alpha
/// only where it is inside (0, 1), so no step leaves its domain): `<Jᵀ·cotangent, v>` against
/// central differences of the f64 reference, relative error below 1e-3.
fn check_random_directions(sc: &Scene, g: &Gradients, rng: &mut Rng, cot: &[f64], loss: &dyn Fn(&Scene, &[f64]) -> f64, label: &str) {
    check_directions(sc, g, rng, cot, loss, label, 1e-6, 1e-3);
}

/// [`check_random_directions`] with central differences of step `h` (in units of each
/// direction) and relative tolerance `tol`.
#[allow(clippy::too_many_arguments)]
fn check_directions(
    sc: &Scene,
    g: &Gradients,
    rng: &mut Rng,
    cot: &[f64],
    loss: &dyn Fn(&Scene, &[f64]) -> f64,
    label: &str,
    h: f64,
    tol: f64,
) {
    for _ in 0..3 {
        let mut dir: Vec<Vec<f64>> = sc.layers.iter().map(|l| vec![0.0; l.len()]).collect();
        let mut predicted = 0.0;
        for (l, d) in dir.iter_mut().enumerate() {
            for (k, v) in d.iter_mut().enumerate() {
                let c = k % 5;
                let a = sc.layers[l][k - c + 3];
                let scale = match c {
                    3 if a <= 0.0 || a >= 1.0 => 0.0,
                    4 => 0.1,
                    _ => 1.0,
                };
                *v = (rng.next_f32() as f64 * 2.0 - 1.0) * scale;
                predicted += *v * g.layers[l].data[k] as f64;
            }
        }
        let (df, dk) = (0.1 * (rng.next_f32() as f64 * 2.0 - 1.0), rng.next_f32() as f64 * 2.0 - 1.0);
        predicted += df * g.focus as f64 + dk * g.blur as f64;
        let at = |t: f64| {
            let mut p = sc.clone();
            for (l, d) in dir.iter().enumerate() {
                p.layers[l].iter_mut().zip(d).for_each(|(x, dx)| *x += t * dx);
            }
            p.focus += t * df;
            p.blur += t * dk;
            loss(&p, cot)
        };
        let fd = (at(h) - at(-h)) / (2.0 * h);
        let rel = (predicted - fd).abs() / fd.abs().max(1e-6);
        eprintln!("{label}: directional derivative {fd:e}, predicted {predicted:e}, rel {rel:e}");
        assert!(rel < tol, "{label}: fd {fd:e} vs predicted {predicted:e}");
    }
}

/// `<cotangent, J·v>` for random directions `v` over every parameter at once (all layers'
/// channels, focus, K) against `<Jᵀ·cotangent, v>`.
#[test]
fn random_directions_match() {
    for (seed, profile) in [(11u64, Profile::Official), (12, Profile::Physical), (13, Profile::Physical)] {
        let sc = random_scene(seed, profile, 10, 10);
        let mut rng = Rng::new(seed);
        let cot: Vec<f32> = (0..sc.w * sc.h * 3).map(|_| rng.next_f32() * 2.0 - 1.0).collect();
        let cot_img = Image::from_vec(sc.w, sc.h, 3, cot.clone()).unwrap();
        let cot: Vec<f64> = cot.iter().map(|&v| v as f64).collect();
        let layers = sc.library_layers();
        let g = Tape::record(&layers, &sc.settings(), sc.smooth).unwrap().vjp(&cot_img).unwrap();
        check_random_directions(&sc, &g, &mut rng, &cot, &|p, cot| p.loss(cot), &format!("{profile:?} seed {seed}"));
    }
}

/// Chromatic aberration ([`drbokeh::render::Aperture::with_chromatic`]): channel `c` of the
/// image is the reference rendered with K scaled by `[1 + C, 1, 1 − C][c]`. The tape's image
/// is that, and its gradients (every layer input, focus, K) match random directional
/// derivatives of the per-channel f64 reference.
#[test]
fn chromatic_aberration_matches_random_directions() {
    let chromatic = 0.1;
    let scales = [1.0 + chromatic, 1.0, 1.0 - chromatic];
    // Σ over channels of the cotangent times that channel of the render at its own K.
    let loss = |sc: &Scene, cot: &[f64]| -> f64 {
        scales
            .iter()
            .enumerate()
            .map(|(c, &k)| {
                let one = Scene { blur: sc.blur * k, ..sc.clone() }.render();
                one.iter().zip(cot).skip(c).step_by(3).map(|(a, b)| a * b).sum::<f64>()
            })
            .sum()
    };
    for (seed, profile) in [(31u64, Profile::Official), (32, Profile::Physical)] {
        let sc = random_scene(seed, profile, 10, 10);
        let layers = sc.library_layers();
        let s = RenderSettings { aperture: drbokeh::render::Aperture::DISC.with_chromatic(chromatic as f32).unwrap(), ..sc.settings() };
        let tape = Tape::record(&layers, &s, sc.smooth).unwrap();
        // The forward: each channel from its own K.
        for (c, &k) in scales.iter().enumerate() {
            let want = Scene { blur: sc.blur * k, ..sc.clone() }.render();
            let worst = tape.image().data.iter().zip(&want).skip(c).step_by(3).map(|(&a, &b)| (a as f64 - b).abs()).fold(0.0, f64::max);
            assert!(worst < 2e-5, "{profile:?} channel {c}: tape and per-channel reference differ by {worst:e}");
        }
        let mut rng = Rng::new(seed);
        let cot: Vec<f32> = (0..sc.w * sc.h * 3).map(|_| rng.next_f32() * 2.0 - 1.0).collect();
        let cot_img = Image::from_vec(sc.w, sc.h, 3, cot.clone()).unwrap();
        let cot: Vec<f64> = cot.iter().map(|&v| v as f64).collect();
        let g = tape.vjp(&cot_img).unwrap();
        check_random_directions(&sc, &g, &mut rng, &cot, &loss, &format!("chromatic {profile:?} seed {seed}"));
    }
}

/// Apertures other than the disc (issue 36): a hexagon, a 5-point star image, a rounded
/// anamorphic 7-blade with a bubble, a 9-blade cat's eye, and a cat's eye on a bubble disc
/// and on the star image. The hexagon is turned 15° so no
/// edge is parallel to the pixel rows or columns: such an edge makes every tap's coverage
/// kinked in the CoC wherever it crosses a side of the coverage's sub-squares (a hexagon at 0°
/// crosses one every ~1e-3 of a direction here), and the differences then measure a mean of
/// slopes instead of the derivative (0.7% off at 3e-4 on seed 41, moving with the step).
/// The shape has no f64 reference here, so the function differentiated is the library's own
/// forward ([`drbokeh::render::render_differentiable`], f32 pixels summed in f64): its
/// directional differences against `<Jᵀ·cotangent, v>`, within 1% (measured: 0.3% at most;
/// the disc's scenes, whose gradients match the f64 reference above, give up to 0.1% this
/// way). The step, 3e-4 of each direction, is where the disc's differences settle (at 1e-3
/// the depth groups' steep steps still bend one of them by 20%; at 1e-4 f32 rounding moves
/// them ~1e-3). The tape's image is the exact kernel's
/// render of that shape up to the fill's smoothing.
#[test]
fn shaped_apertures_match_directional_differences() {
    let (n, star) = common::star_mask();
    let shapes = [
        ("hexagon", aperture::Aperture::new(&aperture::ShapeSpec::parse("blades:6,rotation=15", "test").unwrap(), 1.0, "test").unwrap()),
        ("star image", aperture::Aperture::from_mask(n, n, &star, 1.0, "star").unwrap()),
        (
            "7 rounded blades, anamorphic 1.4, bubble 0.5",
            aperture::Aperture::with_bubble(
                &aperture::ShapeSpec::parse("blades:7,rotation=10,curvature=0.5", "test").unwrap(),
                1.4,
                0.5,
                "test",
            )
            .unwrap(),
        ),
        (
            "9 blades, cat's eye 0.8",
            aperture::Aperture::new(&aperture::ShapeSpec::parse("blades:9", "test").unwrap(), 1.0, "test")
                .unwrap()
                .with_cat_eye(0.8)
                .unwrap(),
        ),
        (
            "disc, bubble -0.5, cat's eye 0.8",
            aperture::Aperture::with_bubble(&aperture::ShapeSpec::Disc, 1.0, -0.5, "test").unwrap().with_cat_eye(0.8).unwrap(),
        ),
        ("star image, cat's eye 0.7", aperture::Aperture::from_mask(n, n, &star, 1.0, "star").unwrap().with_cat_eye(0.7).unwrap()),
    ];
    for (k, (name, a)) in shapes.into_iter().enumerate() {
        let seed = 41 + k as u64;
        let mut sc = random_scene(seed, Profile::Physical, 10, 10);
        // An opaque backdrop: its visibility max(A, α) is kinked where the spread alpha equals
        // its own, which a shape's exact unit flux meets across a uniform region (the f64
        // checks above skip such points; a directional difference cannot).
        sc.layers[1].chunks_exact_mut(5).for_each(|px| px[3] = 1.0);
        let s = RenderSettings { aperture: a, ..sc.settings() };
        let layers = sc.library_layers();
        let tape = Tape::record(&layers, &s, sc.smooth).unwrap();
        let exact = render(&layers, &s, Kernel::Exact).unwrap();
        let mean = exact.data.iter().zip(&tape.image().data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / exact.data.len() as f64;
        assert!(mean < 0.02, "{name}: tape vs exact kernel, mean abs difference {mean}");
        let loss = |p: &Scene, cot: &[f64]| -> f64 {
            let img =
                drbokeh::render::render_differentiable(&p.library_layers(), &RenderSettings { aperture: a, ..p.settings() }, p.smooth)
                    .unwrap();
            img.data.iter().zip(cot).map(|(&v, c)| v as f64 * c).sum()
        };
        let mut rng = Rng::new(seed);
        let cot: Vec<f32> = (0..sc.w * sc.h * 3).map(|_| rng.next_f32() * 2.0 - 1.0).collect();
        let cot_img = Image::from_vec(sc.w, sc.h, 3, cot.clone()).unwrap();
        let cot: Vec<f64> = cot.iter().map(|&v| v as f64).collect();
        let g = tape.vjp(&cot_img).unwrap();
        check_directions(&sc, &g, &mut rng, &cot, &loss, name, 3e-4, 1e-2);
    }
}

// ---------------------------------------------------------------------------------------------
// The forward being differentiated, and finiteness.
// ---------------------------------------------------------------------------------------------

/// The official tape renders what `render` renders; the physical tape's smooth edges stay close
/// to the hard kernel's render.
#[test]
fn tape_forward_is_the_exact_kernel() {
    for profile in [Profile::Official, Profile::Physical] {
        let sc = random_scene(21, profile, 24, 24);
        let layers = sc.library_layers();
        let s = sc.settings();
        let exact = render(&layers, &s, Kernel::Exact).unwrap();
        let tape = Tape::record(&layers, &s, Smoothing::default()).unwrap();
        let mean = exact.data.iter().zip(&tape.image().data).map(|(a, b)| (a - b).abs() as f64).sum::<f64>() / exact.data.len() as f64;
        match profile {
            Profile::Official => assert_eq!(tape.image(), &exact),
            Profile::Physical => assert!(mean < 0.02, "smooth vs hard physical render: mean abs difference {mean}"),
        }
        eprintln!("{profile:?}: mean |smooth - hard| = {mean:e}");
    }
}

/// A scene for the extreme grid: hard depth steps (blocks at disparity 0 and 1), HDR colours
/// (1e4 highlights next to black), alpha exactly 0 and 1 (and one 1e-30), front and backdrop.
fn extreme_layers(w: usize, h: usize) -> Vec<Layer<'static>> {
    let mut front = Vec::new();
    let mut back = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let block = ((x / 7) + (y / 5)) % 2 == 0;
            let hdr = if (x * 7 + y * 3) % 11 == 0 { 1e4 } else { 0.0 };
            let a = if x < w / 2 {
                1.0
            } else if x == w - 3 && y == h / 2 {
                1e-30
            } else {
                0.0
            };
            front.extend_from_slice(&[hdr, 0.5, 1.0, a, if block { 1.0 } else { 0.0 }]);
            back.extend_from_slice(&[0.2, hdr, 0.0, 1.0, if block { 0.0 } else { 1.0 }]);
        }
    }
    [front, back].into_iter().map(|l| Layer::new(Image::from_vec(w, h, 5, l).unwrap(), "extreme").unwrap()).collect()
}

/// Finite render and gradients for every finite input: K from 0 to 1e4, lens up to 71 (the
/// official training config; its CUDA soft-step derivative is NaN at window corners ~30 px
/// from an in-focus pixel), focus on a layer (d = 0 exactly) and outside [0, 1], HDR, alpha
/// 0/1/1e-30, both profiles, occlusion on and off, hard and smooth fills, cotangents up to
/// 1e20 (gradients saturate at f32::MAX).
#[test]
fn gradients_are_finite_on_the_extreme_grid() {
    let (w, h) = (40, 40);
    let layers = extreme_layers(w, h);
    let mut rng = Rng::new(5);
    let mut cases = 0;
    // The physical profile twice: without and with the ray test.
    for (profile, ray) in [(Profile::Official, false), (Profile::Physical, false), (Profile::Physical, true)] {
        for (lens, blurs) in [(9usize, &[0.0f32, 1.0, 1e4][..]), (71, &[0.0, 30.0, 1e4][..])] {
            for &blur in blurs {
                for (focus, occlusion, fill) in [(1.0f32, true, 0.0f32), (0.0, false, 0.5), (0.5, true, 0.1), (-3.0, true, 0.0)] {
                    let s = RenderSettings { blur, focus, lens, occlusion, profile, aperture: drbokeh::render::Aperture::DISC };
                    let sm = Smoothing { edge_width: 1.0, fill_width: fill };
                    let scale = if cases % 3 == 0 { 1e20 } else { 1.0 };
                    let cot = Image::from_vec(w, h, 3, (0..w * h * 3).map(|_| (rng.next_f32() * 2.0 - 1.0) * scale).collect()).unwrap();
                    let tape = Tape::record_with(&layers, &s, sm, ray).unwrap();
                    assert!(tape.image().all_finite(), "{s:?}");
                    let g = tape.vjp(&cot).unwrap();
                    for (l, img) in g.layers.iter().enumerate() {
                        if let Some(k) = img.data.iter().position(|v| !v.is_finite()) {
                            panic!("{s:?} {sm:?}: layer {l} gradient {} at pixel {} channel {}", img.data[k], k / 5, k % 5);
                        }
                    }
                    assert!(g.focus.is_finite() && g.blur.is_finite(), "{s:?}: focus {} K {}", g.focus, g.blur);
                    cases += 1;
                }
            }
        }
    }
    assert_eq!(cases, 72);
}

/// The API's errors name what is wrong.
#[test]
fn bad_cotangent_and_smoothing_are_usage_errors() {
    let sc = random_scene(3, Profile::Physical, 8, 8);
    let layers = sc.library_layers();
    let tape = Tape::record(&layers, &sc.settings(), Smoothing::default()).unwrap();
    let e = tape.vjp(&Image::new(8, 7, 3)).unwrap_err().to_string();
    assert!(e.contains("cotangent") && e.contains("8x7"), "{e}");
    let e = tape.vjp(&Image::filled(8, 8, 3, f32::NAN)).unwrap_err().to_string();
    assert!(e.contains("non-finite"), "{e}");
    for sm in [Smoothing { edge_width: 0.0, fill_width: 0.0 }, Smoothing { edge_width: 1.0, fill_width: 0.7 }] {
        let e = Tape::record(&layers, &sc.settings(), sm).err().unwrap().to_string();
        assert!(e.contains("smoothing."), "{e}");
    }
}

/// The smallest legal inputs: a 1×1 image, lens 1 (no taps: the layers have no weight), one
/// layer or two.
#[test]
fn tiny_images_and_lens_one() {
    for profile in [Profile::Official, Profile::Physical] {
        for (w, h, lens, n) in [(1usize, 1usize, 1usize, 1usize), (1, 1, 3, 2), (3, 2, 1, 2), (3, 2, 5, 1)] {
            let layers: Vec<Layer<'static>> = (0..n)
                .map(|k| {
                    let px: Vec<f32> = (0..w * h).flat_map(|i| [0.5, 1e4, 0.0, (i % 2) as f32, k as f32 * 0.5]).collect();
                    Layer::new(Image::from_vec(w, h, 5, px).unwrap(), "tiny").unwrap()
                })
                .collect();
            let s = RenderSettings { blur: 10.0, focus: 0.25, lens, occlusion: true, profile, aperture: drbokeh::render::Aperture::DISC };
            let tape = Tape::record(&layers, &s, Smoothing::default()).unwrap();
            if profile == Profile::Official {
                assert_eq!(tape.image(), &render(&layers, &s, Kernel::Exact).unwrap());
            }
            let g = tape.vjp(&Image::filled(w, h, 3, 1.0)).unwrap();
            assert!(
                g.layers.iter().all(|l| l.all_finite()) && g.focus.is_finite() && g.blur.is_finite(),
                "{profile:?} {w}x{h} lens {lens}"
            );
        }
    }
}
