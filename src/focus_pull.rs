//! Focus pulls: a sequence of frames refocused from one photo, the layers built once.
//!
//! Contract:
//! - Frame `i` of `n` has focus `from + (to − from)·e(t)` and blur `blur_from + (blur_to −
//!   blur_from)·e(t)` (the configured blur when no blur range is given), `t = i / (n − 1)`
//!   (`t = 0` for a single frame), `e` the easing: linear, or smoothstep `3t² − 2t³` (no jump
//!   in speed at either end). Foci are normalized disparity (0 far … 1 near).
//! - The layers are built once ([`FocusPull::build_settings`]: the frame whose circles of
//!   confusion reach farthest, so what any frame reveals behind the subject is filled), then
//!   every frame is [`crate::refocus::Refocuser::render_with_blur`] of them: frame `i` equals
//!   `drbokeh render --layer ... --focus f_i --blur k_i` of those layers (`--save-layers`
//!   writes them), bit for bit.
//! - Frame files come from a pattern with one `%d` or `%0Nd` (N ≤ 9): `frames/%04d.png`.
//! - A batch of video frames gets its focus over time here too: keyframes interpolated
//!   ([`interpolate_keyframes`]) and smoothed ([`smooth_foci`]).

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// Most frames of one pull.
pub const MAX_FRAMES: usize = 100_000;

/// How the focus moves between the first frame and the last.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Easing {
    /// Evenly spaced.
    Linear,
    /// Smoothstep: slow at both ends, as a focus puller's hand moves.
    #[default]
    Smooth,
}

impl Easing {
    /// The eased fraction of `t` in [0, 1].
    pub fn apply(self, t: f32) -> f32 {
        match self {
            Easing::Linear => t,
            Easing::Smooth => t * t * (3.0 - 2.0 * t),
        }
    }
}

/// A focus pull (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct FocusPull {
    /// The first frame's focus.
    pub from: f32,
    /// The last frame's focus.
    pub to: f32,
    /// Frames, 1 ..= [`MAX_FRAMES`].
    pub frames: usize,
    /// The first and last frame's blur K; None: the configured blur for every frame.
    pub blur: Option<(f32, f32)>,
    /// How the values move between the ends.
    pub easing: Easing,
}

impl FocusPull {
    /// Checks the values: finite foci, 1 ..= [`MAX_FRAMES`] frames, blurs that are finite
    /// numbers ≥ 0. Errors name the flag (`--focus-from`, `--frames`, `--blur-to`...).
    pub fn check(&self) -> Result<()> {
        for (v, flag) in [(self.from, "--focus-from"), (self.to, "--focus-to")] {
            if !v.is_finite() {
                return Err(Error::usage(format!("{flag} {v}: a focus must be a finite normalized disparity")));
            }
        }
        if self.frames == 0 || self.frames > MAX_FRAMES {
            return Err(Error::usage(format!("--frames {}: give 1 ..= {MAX_FRAMES} frames", self.frames)));
        }
        if let Some((a, b)) = self.blur {
            crate::render::check_blur("--blur-from", a)?;
            crate::render::check_blur("--blur-to", b)?;
        }
        Ok(())
    }

    /// Frame `i`'s focus and blur (`blur` the configured one, used without a blur range).
    pub fn frame(&self, i: usize, blur: f32) -> (f32, f32) {
        let t = if self.frames > 1 { i as f32 / (self.frames - 1) as f32 } else { 0.0 };
        let e = self.easing.apply(t);
        let lerp = |a: f32, b: f32| a + (b - a) * e;
        let k = self.blur.map_or(blur, |(a, b)| lerp(a, b));
        (lerp(self.from, self.to), k)
    }

    /// The focus and blur the layers are built with: the frame whose largest circle of
    /// confusion over normalized disparity in [0, 1] is the largest, `K·max(f, 1 − f)`.
    pub fn build_settings(&self, blur: f32) -> (f32, f32) {
        (0..self.frames).map(|i| self.frame(i, blur)).max_by(|a, b| reach(*a).total_cmp(&reach(*b))).expect("at least one frame")
    }
}

/// The largest CoC radius of focus `f` and blur `k` over disparities in [0, 1].
fn reach((f, k): (f32, f32)) -> f32 {
    k * f.clamp(0.0, 1.0).max(1.0 - f.clamp(0.0, 1.0))
}

/// The frame files' pattern, checked: one `%d` or `%0Nd` (1 ≤ N ≤ 9) in the file name.
#[derive(Clone, Debug, PartialEq)]
pub struct FramePattern {
    prefix: String,
    suffix: String,
    width: usize,
}

impl FramePattern {
    /// Parses `path` (`frames/%04d.png`); a usage error naming `--output` otherwise.
    pub fn parse(path: &Path) -> Result<FramePattern> {
        let s = path.to_str().ok_or_else(|| Error::usage(format!("--output {}: not UTF-8", path.display())))?;
        let bad = || {
            Error::usage(format!("--output {s}: a focus pull writes one file per frame: put %d or %04d in the file name (frames/%04d.png)"))
        };
        let at = s.find('%').ok_or_else(bad)?;
        let rest = &s[at + 1..];
        let digits: String = rest.chars().take_while(|c| c.is_ascii_digit()).collect();
        if !rest[digits.len()..].starts_with('d') {
            return Err(bad());
        }
        let width = match digits.as_str() {
            "" => 0,
            d if d.starts_with('0') && d.len() == 2 && d != "00" => d[1..].parse().map_err(|_| bad())?,
            _ => return Err(bad()),
        };
        let suffix = rest[digits.len() + 1..].to_owned();
        if suffix.contains('%') || suffix.contains('/') {
            return Err(bad());
        }
        Ok(FramePattern { prefix: s[..at].to_owned(), suffix, width })
    }

    /// The file of frame `i` (numbered from 0).
    pub fn path(&self, i: usize) -> PathBuf {
        PathBuf::from(format!("{}{:0w$}{}", self.prefix, i, self.suffix, w = self.width))
    }
}

/// The focus of every frame from the keyframes among them (`Some(focus)` where a batch's
/// manifest gives one, in the batch's order): linear between the keyframes around an image, the
/// nearest keyframe's before the first and after the last. None without any keyframe.
pub fn interpolate_keyframes(keys: &[Option<f32>]) -> Option<Vec<f32>> {
    let known: Vec<(usize, f32)> = keys.iter().enumerate().filter_map(|(i, k)| k.map(|f| (i, f))).collect();
    let (&(first_i, first_f), &(last_i, last_f)) = (known.first()?, known.last()?);
    let mut next = 0;
    Some(
        (0..keys.len())
            .map(|i| {
                if i <= first_i {
                    return first_f;
                }
                if i >= last_i {
                    return last_f;
                }
                // A keyframe starts the next segment: its own frame takes its focus exactly
                // (as the end of a segment, `fa + (fb − fa)` can round off `fb`).
                while known[next + 1].0 <= i {
                    next += 1;
                }
                let ((a, fa), (b, fb)) = (known[next], known[next + 1]);
                fa + (fb - fa) * (i - a) as f32 / (b - a) as f32
            })
            .collect(),
    )
}

/// `foci` (one per frame, in order) smoothed by a Gaussian of `sigma` frames, its weights
/// renormalized at the ends (a still focus stays as it is; `sigma` 0 changes nothing). The
/// kernel reaches 3σ.
pub fn smooth_foci(foci: &[f32], sigma: f32) -> Vec<f32> {
    if sigma <= 0.0 || foci.len() < 2 {
        return foci.to_vec();
    }
    let reach = (3.0 * sigma).ceil() as usize;
    let w: Vec<f64> = (0..=reach).map(|d| (-0.5 * (d as f64 / sigma as f64).powi(2)).exp()).collect();
    (0..foci.len())
        .map(|i| {
            let (lo, hi) = (i.saturating_sub(reach), (i + reach).min(foci.len() - 1));
            let (sum, norm) = (lo..=hi).fold((0.0f64, 0.0f64), |(s, n), j| {
                let k = w[i.abs_diff(j)];
                (s + k * foci[j] as f64, n + k)
            });
            (sum / norm) as f32
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_move_from_one_end_to_the_other() {
        let p = FocusPull { from: 0.2, to: 0.8, frames: 5, blur: None, easing: Easing::Linear };
        let f: Vec<f32> = (0..5).map(|i| p.frame(i, 10.0).0).collect();
        assert!(f.iter().zip([0.2, 0.35, 0.5, 0.65, 0.8]).all(|(a, b)| (a - b).abs() < 1e-6), "{f:?}");
        assert!((0..5).all(|i| p.frame(i, 10.0).1 == 10.0));
        let s = FocusPull { easing: Easing::Smooth, blur: Some((4.0, 12.0)), ..p.clone() };
        assert_eq!((s.frame(0, 10.0), s.frame(4, 10.0)), ((0.2, 4.0), (0.8, 12.0)));
        // Smoothstep: slower than linear near the start, symmetric about the middle.
        assert!(s.frame(1, 10.0).0 < p.frame(1, 10.0).0);
        assert!((s.frame(2, 10.0).0 - 0.5).abs() < 1e-6);
        let one = FocusPull { frames: 1, ..p.clone() };
        assert_eq!(one.frame(0, 3.0), (0.2, 3.0));
        // Built at the frame that reaches farthest: focus 0.8 reaches 0.8·K, 0.2 too; the
        // blur range decides.
        assert_eq!(s.build_settings(10.0), (0.8, 12.0));
        let near = FocusPull { from: 0.5, to: 1.0, frames: 3, blur: None, easing: Easing::Linear };
        assert_eq!(near.build_settings(7.0), (1.0, 7.0));
        // The reach is K·max(f, 1 − f), a product: focus 1 at K 6 reaches 6 px, focus 0.5 at
        // K 10 only 5 (a sum of the two would pick the latter), and the farthest frame is
        // the first, not the last.
        let pull = FocusPull { from: 1.0, to: 0.5, frames: 2, blur: Some((6.0, 10.0)), easing: Easing::Linear };
        assert_eq!(pull.frame(1, 0.0), (0.5, 10.0));
        assert_eq!(pull.build_settings(0.0), (1.0, 6.0));
    }

    #[test]
    fn checks_name_the_flag() {
        let p = FocusPull { from: 0.2, to: 0.8, frames: 5, blur: None, easing: Easing::Linear };
        assert!(p.check().is_ok());
        // The range's ends are allowed: one frame, and MAX_FRAMES.
        for frames in [1, MAX_FRAMES] {
            assert!(FocusPull { frames, ..p.clone() }.check().is_ok(), "{frames} frames");
        }
        for (bad, flag) in [
            (FocusPull { from: f32::NAN, ..p.clone() }, "--focus-from"),
            (FocusPull { to: f32::INFINITY, ..p.clone() }, "--focus-to"),
            (FocusPull { frames: 0, ..p.clone() }, "--frames"),
            (FocusPull { frames: MAX_FRAMES + 1, ..p.clone() }, "--frames"),
            (FocusPull { blur: Some((-1.0, 2.0)), ..p.clone() }, "--blur-from"),
            (FocusPull { blur: Some((1.0, f32::NAN)), ..p.clone() }, "--blur-to"),
        ] {
            let e = bad.check().unwrap_err().to_string();
            assert!(e.contains(flag), "{flag}: {e}");
        }
    }

    #[test]
    fn patterns() {
        let p = FramePattern::parse(Path::new("frames/%04d.png")).unwrap();
        assert_eq!(p.path(7), PathBuf::from("frames/0007.png"));
        assert_eq!(p.path(12345), PathBuf::from("frames/12345.png"));
        let p = FramePattern::parse(Path::new("f%d.exr")).unwrap();
        assert_eq!(p.path(3), PathBuf::from("f3.exr"));
        for bad in ["out.png", "f%s.png", "f%4d.png", "f%00d.png", "f%d%d.png", "a%d/b.png", "f%123d.png"] {
            let e = FramePattern::parse(Path::new(bad)).unwrap_err().to_string();
            assert!(e.contains("--output") && e.contains("%04d"), "{bad}: {e}");
        }
    }

    #[test]
    fn keyframes_interpolate_and_hold_at_the_ends() {
        assert_eq!(interpolate_keyframes(&[None, None]), None);
        let f = interpolate_keyframes(&[None, Some(0.2), None, None, Some(0.8), None]).unwrap();
        let want = [0.2, 0.2, 0.4, 0.6, 0.8, 0.8];
        assert!(f.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-6), "{f:?}");
        assert_eq!(interpolate_keyframes(&[Some(0.5), None, None]).unwrap(), vec![0.5; 3]);
        let f = interpolate_keyframes(&[Some(0.0), None, Some(1.0), None, Some(0.0)]).unwrap();
        assert_eq!(f, vec![0.0, 0.5, 1.0, 0.5, 0.0]);
        // Every keyframe's frame has its focus exactly: 0.7 + (0.1 - 0.7) is 0.100000024 in f32.
        let f = interpolate_keyframes(&[Some(0.7), None, Some(0.1), None, Some(0.5)]).unwrap();
        assert_eq!([f[0], f[2], f[4]], [0.7, 0.1, 0.5]);
    }

    #[test]
    fn smoothing_removes_jitter_and_keeps_a_still_focus() {
        assert_eq!(smooth_foci(&[0.3; 10], 4.0), vec![0.3; 10]);
        assert_eq!(smooth_foci(&[0.1, 0.9, 0.1], 0.0), vec![0.1, 0.9, 0.1]);
        // Frame-to-frame jitter of ±0.05 around a slow ramp: the smoothed steps are far smaller.
        let jittery: Vec<f32> = (0..60).map(|i| 0.2 + 0.01 * i as f32 + if i % 2 == 0 { 0.05 } else { -0.05 }).collect();
        let s = smooth_foci(&jittery, 3.0);
        let worst = |v: &[f32]| v.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0f32, f32::max);
        assert!(worst(&jittery) > 0.08 && worst(&s[5..55]) < 0.02, "{} -> {}", worst(&jittery), worst(&s[5..55]));
        // The ramp itself is kept in the middle.
        assert!((s[30] - (0.2 + 0.30)).abs() < 0.02, "{}", s[30]);
        // The shortest sequence that can be smoothed, two frames: each moves toward the other
        // by the weight e^(-1/2) of its neighbour; one frame stays as it is.
        let two = smooth_foci(&[0.0, 1.0], 1.0);
        let k = (-0.5f64).exp();
        assert!((two[0] as f64 - k / (1.0 + k)).abs() < 1e-6 && (two[1] as f64 - 1.0 / (1.0 + k)).abs() < 1e-6, "{two:?}");
        assert_eq!(smooth_foci(&[0.4], 2.0), vec![0.4]);
    }

    /// Each smoothed focus is the Gaussian-weighted mean of the foci within 3σ frames (the
    /// weights renormalized where the sequence ends), written out here from the definition.
    #[test]
    fn smoothing_is_a_gaussian_mean_over_three_sigma() {
        let foci: Vec<f32> = (0..40).map(|i| if i < 20 { 0.1 } else { 0.9 } + 0.003 * (i % 7) as f32).collect();
        for sigma in [1.3f32, 3.0] {
            let reach = (3.0 * sigma).ceil() as i64;
            let got = smooth_foci(&foci, sigma);
            for (i, &g) in got.iter().enumerate() {
                let (mut sum, mut norm) = (0.0f64, 0.0f64);
                for (j, &f) in foci.iter().enumerate() {
                    let d = i as i64 - j as i64;
                    if d.abs() <= reach {
                        let wt = (-(d as f64).powi(2) / (2.0 * (sigma as f64).powi(2))).exp();
                        (sum, norm) = (sum + wt * f as f64, norm + wt);
                    }
                }
                assert!((g as f64 - sum / norm).abs() < 1e-6, "sigma {sigma}, frame {i}: {g} against {}", sum / norm);
            }
        }
    }
}
