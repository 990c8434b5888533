//! The aperture's shape: what a point source's bokeh looks like, defined once for every kernel.
//!
//! Conventions (README "Aperture shapes", `--help`):
//! - The shape's circumradius is the circle of confusion `r = K·|d - f|` (pixels); with an
//!   anamorphic aspect `A` the shape is squeezed horizontally by `1/A` (`A > 1`, taller than
//!   wide) or vertically by `A` (`A < 1`), so it still fits the CoC's circle.
//! - Coordinates are the output's, y up: `rotation` puts a blade's vertex at that many degrees
//!   counterclockwise from +x; an aperture image is read with its top row up.
//! - A source behind the focal plane shows the shape as specified, one in front of it the
//!   shape point-reflected, as a thin lens images its aperture.
//! - Every shape carries unit flux: a pixel's weight is the shape integrated over the source's
//!   and the target's pixel squares ([`Geometry::coverage`], the shape convolved with the
//!   tent `box ⊗ box`) over the shape's whole area ([`Geometry::norm`]), which is also the
//!   exact lattice sum of the coverages. A CoC below [`POINT_COC_PX`] leaves a source in its
//!   pixel.
//!
//! The disc is not a [`Geometry`]: the kernels keep their own radial-ramp disc
//! (`lens::disk_coverage`), so a disc render is unchanged by this module. Every other shape
//! is a convex polygon (blades, rounded blades, an anamorphic disc) or a grey mask (an image),
//! both evaluated here as areas; the exact kernel calls [`Geometry::coverage`] tap by tap and
//! the fast kernel builds its per-row spans and rim taps from it (`fast::binned`).
//!
//! A [`Geometry`] is interned (built once per distinct shape, kept for the process's life), so
//! [`Aperture`] is a `Copy` handle that render settings can carry.

use super::polygon::{
    Area, CURVE_VERTICES, Clip, Poly, Sectors, blades, circle, clip_convex, clip_half_plane, half_planes, polygon_circle_area,
    polygon_rect_area, rect_reach, shoelace,
};
use crate::error::{Error, Result};
use rayon::prelude::*;
use std::path::Path;
use std::sync::Mutex;

/// Below this CoC (pixels) a shape is a point: its source stays in its pixel.
pub const POINT_COC_PX: f32 = 1e-3;

/// Accepted radial intensity profiles (`--bubble`).
pub const BUBBLE: std::ops::RangeInclusive<f32> = -1.0..=1.0;

/// The bubble profile `1 + B·(2t² − 1)` at relative radius `t` (clamped to the outline).
fn profile(bubble: f32, t: f64) -> f64 {
    let t = t.min(1.0);
    1.0 + bubble as f64 * (2.0 * t * t - 1.0)
}

/// CoCs (px) below which a bubble's weights are its profile's exact integral
/// ([`Geometry::bubble_integral`], five areas per pixel square), above which one intensity per
/// square (one area), blended between: large bokeh have many pixels, and with six Gauss nodes
/// and no shortcut for wide squares the exact integral at every CoC made the bundled example
/// at `--blur 60` ten times slower. At 6 px a square is 1/12 of the bokeh's radius: the
/// midpoint rule's error in the profile is then ~B·0.2% (`|∇t|²·h²/3` of `t²`).
const BUBBLE_EXACT_BELOW: Blend = Blend { from: 4.0, to: 6.0 };

/// A smooth step from 0 (at and below `from`) to 1 (at and above `to`), C¹.
struct Blend {
    from: f32,
    to: f32,
}

impl Blend {
    fn blend(&self, r: f32) -> f64 {
        let u = (((r - self.from) / (self.to - self.from)) as f64).clamp(0.0, 1.0);
        u * u * (3.0 - 2.0 * u)
    }
}

/// CoCs (px) below which a cut bubble's profile integral ([`Geometry::bubble_integral`]) takes
/// [`FLUX_PANELS`] panels of nodes, above which one (8 times fewer areas), blended between.
const CUT_PANELS_BELOW: Blend = Blend { from: 2.0, to: 4.0 };

/// Gauss–Legendre nodes on [0, 1] and their weights (summing to 1): exact for polynomials of
/// degree 7; [`Geometry::bubble_integral`]'s rule in the shape's scale.
const GAUSS_LEGENDRE: [(f64, f64); 4] = [
    (0.069_431_844_202_973_71, 0.173_927_422_568_726_84),
    (0.330_009_478_207_571_87, 0.326_072_577_431_273_1),
    (0.669_990_521_792_428_1, 0.326_072_577_431_273_1),
    (0.930_568_155_797_026_2, 0.173_927_422_568_726_84),
];

/// `∫ f` over `[a, b]` by [`GAUSS_LEGENDRE`]'s nodes on `panels` equal panels.
fn gauss_legendre(a: f64, b: f64, panels: usize, f: impl Fn(f64) -> f64) -> f64 {
    let width = (b - a) / panels as f64;
    let f = &f;
    (0..panels).flat_map(|k| GAUSS_LEGENDRE.iter().map(move |&(u, w)| w * f(a + (k as f64 + u) * width))).sum::<f64>() * width
}

/// Panels of [`GAUSS_LEGENDRE`]'s nodes in [`Geometry::flux_in_circle`]'s profile integral: its
/// area `P(s)` has kinks where the scaled outline's vertices cross the circle.
const FLUX_PANELS: usize = 8;

/// Fewest and most blades `--aperture blades:N` accepts.
pub const BLADES: std::ops::RangeInclusive<u32> = 3..=64;
/// Largest side of an aperture image, pixels.
pub const MAX_IMAGE_SIDE: usize = 1024;
/// Accepted cat's-eye strengths (`--cat-eye`): 0 = off, 1 = a corner's bokeh cut to a lens
/// shape half as wide as it is tall.
pub const CAT_EYE: std::ops::RangeInclusive<f32> = 0.0..=1.0;
/// Accepted longitudinal chromatic aberrations (`--chromatic`): blue's circle of confusion
/// keeps at least half its size.
pub const CHROMATIC: std::ops::RangeInclusive<f32> = -0.5..=0.5;
/// Accepted anamorphic aspect ratios.
pub const ANAMORPHIC: std::ops::RangeInclusive<f32> = 0.1..=10.0;
/// What the user asked for, as they spelled it (also what reports print).
#[derive(Clone, Debug, PartialEq)]
pub enum ShapeSpec {
    /// The uniform disc (the default).
    Disc,
    /// `n` straight (curvature 0) or rounded blades, a vertex at `rotation` degrees.
    Blades {
        /// Number of blades, [`BLADES`].
        n: u32,
        /// Degrees counterclockwise from +x (y up) of a vertex.
        rotation: f32,
        /// 0 = straight blades, 1 = a circle.
        curvature: f32,
    },
    /// A grey mask read from an image (bright = open), its longer side spanning the diameter.
    Image {
        /// The file, as given.
        path: String,
    },
}

impl ShapeSpec {
    /// Parses `disc`, `blades:N[,rotation=DEG][,curvature=C]` or `image:PATH`; `what` names
    /// the flag or key in the message.
    pub fn parse(spec: &str, what: &str) -> Result<ShapeSpec> {
        let bad = |msg: String| Error::usage(format!("{what} {spec:?}: {msg}"));
        let s = spec.trim();
        if s.eq_ignore_ascii_case("disc") || s.eq_ignore_ascii_case("disk") {
            return Ok(ShapeSpec::Disc);
        }
        if let Some(path) = s.strip_prefix("image:") {
            if path.is_empty() {
                return Err(bad("image: needs a file, e.g. image:star.png".into()));
            }
            return Ok(ShapeSpec::Image { path: path.to_string() });
        }
        let Some(rest) = s.strip_prefix("blades:") else {
            return Err(bad("expected disc, blades:N[,rotation=DEG][,curvature=C] or image:PATH".into()));
        };
        let mut parts = rest.split(',');
        let n_str = parts.next().unwrap_or("").trim();
        let n: u32 = n_str.parse().map_err(|_| bad(format!("the blade count {n_str:?} is not a whole number")))?;
        if !BLADES.contains(&n) {
            return Err(bad(format!("{n} blades: a lens has {} to {}", BLADES.start(), BLADES.end())));
        }
        let (mut rotation, mut curvature) = (0f32, 0f32);
        for part in parts {
            let (key, value) = part.split_once('=').ok_or_else(|| bad(format!("{part:?} is not key=value")))?;
            let v: f32 = value.trim().parse().map_err(|_| bad(format!("{} {value:?} is not a number", key.trim())))?;
            if !v.is_finite() {
                return Err(bad(format!("{} must be finite", key.trim())));
            }
            match key.trim() {
                "rotation" => rotation = v,
                "curvature" => {
                    if !(0.0..=1.0).contains(&v) {
                        return Err(bad(format!("curvature {v} is outside [0, 1] (0 straight blades, 1 a circle)")));
                    }
                    curvature = v;
                }
                other => return Err(bad(format!("unknown blade option {other:?} (rotation, curvature)"))),
            }
        }
        Ok(ShapeSpec::Blades { n, rotation, curvature })
    }

    /// The spec as `--aperture` spells it.
    pub fn label(&self) -> String {
        match self {
            ShapeSpec::Disc => "disc".into(),
            ShapeSpec::Blades { n, rotation, curvature } => format!("blades:{n},rotation={rotation},curvature={curvature}"),
            ShapeSpec::Image { path } => format!("image:{path}"),
        }
    }
}

/// The aperture a render uses: the disc (`Aperture::DISC`, the default) or a [`Geometry`],
/// and its longitudinal chromatic aberration (see [`Aperture::with_chromatic`]). A `Copy`
/// handle; equal handles are equal apertures (geometries are interned).
#[derive(Clone, Copy, Default)]
pub struct Aperture {
    shape: Option<&'static Geometry>,
    /// `C`: red's circle of confusion scaled by `1 + C`, blue's by `1 − C`; 0 = none.
    chromatic: f32,
    /// Optical vignetting's strength (see [`Aperture::with_cat_eye`]); 0 = none.
    cat_eye: f32,
}

impl PartialEq for Aperture {
    fn eq(&self, other: &Self) -> bool {
        let same_shape = match (self.shape, other.shape) {
            (None, None) => true,
            (Some(a), Some(b)) => std::ptr::eq(a, b),
            _ => false,
        };
        same_shape && self.chromatic.to_bits() == other.chromatic.to_bits() && self.cat_eye.to_bits() == other.cat_eye.to_bits()
    }
}

impl std::fmt::Debug for Aperture {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.label())
    }
}

impl Aperture {
    /// The uniform disc.
    pub const DISC: Aperture = Aperture { shape: None, chromatic: 0.0, cat_eye: 0.0 };

    /// The aperture of `spec` with anamorphic aspect `anamorphic` (1 = none); an image is read
    /// from its path (relative to the working directory). Errors name `what` (the flag or
    /// key) or the file.
    pub fn new(spec: &ShapeSpec, anamorphic: f32, what: &str) -> Result<Aperture> {
        Aperture::with_bubble(spec, anamorphic, 0.0, what)
    }

    /// [`Aperture::new`] with a radial intensity profile `bubble` in [`BUBBLE`]: `I(t) = 1 +
    /// B·(2t² − 1)` at relative radius `t` (0 at the centre, 1 on the outline), so B > 0
    /// brightens the rim (an over-corrected lens's "soap bubble"), B < 0 the centre, 0 is
    /// uniform; the flux stays one (`I` averages to 1 over any shape scaled from the centre).
    pub fn with_bubble(spec: &ShapeSpec, anamorphic: f32, bubble: f32, what: &str) -> Result<Aperture> {
        Aperture::check_values(anamorphic, bubble, 0.0, 0.0)?;
        let kind = match spec {
            ShapeSpec::Disc if anamorphic == 1.0 && bubble == 0.0 => return Ok(Aperture::DISC),
            ShapeSpec::Disc => Kind::polygon(circle(CURVE_VERTICES)),
            ShapeSpec::Blades { n, rotation, curvature } => {
                if !BLADES.contains(n) || !(0.0..=1.0).contains(curvature) || !rotation.is_finite() {
                    return Err(Error::usage(format!("{what}: invalid blades {}", spec.label())));
                }
                Kind::polygon(blades(*n, *rotation as f64, *curvature as f64))
            }
            ShapeSpec::Image { path } => return Aperture::from_image_file(spec, path, anamorphic, bubble),
        };
        Ok(Aperture::from_kind(spec.clone(), anamorphic, bubble, kind))
    }

    /// An image aperture, read once per file version: the viewer and the bench resolve the
    /// configuration for every render, and a 1024² mask's decode, summed-area tables and
    /// interning comparison cost milliseconds each time. Keyed by the path as given, the
    /// file's length and modification time (an edited file is read again), and the squeeze
    /// and bubble.
    fn from_image_file(spec: &ShapeSpec, path: &str, anamorphic: f32, bubble: f32) -> Result<Aperture> {
        type Key = (String, u64, Option<std::time::SystemTime>, u32, u32);
        static READ: Mutex<Vec<(Key, Aperture)>> = Mutex::new(Vec::new());
        let meta = std::fs::metadata(path).ok();
        let key: Option<Key> = meta.map(|m| (path.to_string(), m.len(), m.modified().ok(), anamorphic.to_bits(), bubble.to_bits()));
        if let Some(k) = &key
            && let Some((_, a)) = READ.lock().unwrap_or_else(|e| e.into_inner()).iter().find(|(old, _)| old == k)
        {
            return Ok(*a);
        }
        let a = Aperture::from_kind(spec.clone(), anamorphic, bubble, Kind::Mask(Mask::read(Path::new(path))?));
        if let Some(k) = key {
            READ.lock().unwrap_or_else(|e| e.into_inner()).push((k, a));
        }
        Ok(a)
    }

    /// An image aperture from grey values (row-major, top row first, bright = open), for the
    /// library and tests; checked as an image file is (`name` in messages).
    pub fn from_mask(width: usize, height: usize, values: &[f32], anamorphic: f32, name: &str) -> Result<Aperture> {
        let mask = Mask::new(width, height, values).map_err(|msg| Error::usage(format!("aperture image {name}: {msg}")))?;
        Aperture::check_values(anamorphic, 0.0, 0.0, 0.0)?;
        Ok(Aperture::from_kind(ShapeSpec::Image { path: name.to_string() }, anamorphic, 0.0, Kind::Mask(mask)))
    }

    fn from_kind(spec: ShapeSpec, anamorphic: f32, bubble: f32, kind: Kind) -> Aperture {
        let g = Geometry::new(spec, anamorphic, bubble, kind);
        static INTERNED: Mutex<Vec<&'static Geometry>> = Mutex::new(Vec::new());
        let mut all = INTERNED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(&old) = all.iter().find(|old| ***old == g) {
            return Aperture { shape: Some(old), ..Aperture::DISC };
        }
        // Leaked on purpose: a handful per process (one per distinct shape asked for).
        let g: &'static Geometry = Box::leak(Box::new(g));
        all.push(g);
        Aperture { shape: Some(g), ..Aperture::DISC }
    }

    /// Checks the numeric settings' ranges (anamorphic aspect, bubble, chromatic aberration,
    /// cat's eye) without building a shape: what a configuration file is checked with.
    pub fn check_values(anamorphic: f32, bubble: f32, chromatic: f32, cat_eye: f32) -> Result<()> {
        in_range("aperture.anamorphic", anamorphic, &ANAMORPHIC, "1 = round bokeh, 1.5 = taller than wide")?;
        in_range("aperture.bubble", bubble, &BUBBLE, "0 = uniform, > 0 a bright rim, < 0 a bright centre")?;
        in_range(
            "aperture.chromatic",
            chromatic,
            &CHROMATIC,
            "0 = none, 0.05 = red's circle of confusion 5% larger and blue's 5% smaller",
        )?;
        in_range("aperture.cat_eye", cat_eye, &CAT_EYE, "0 = off, 1 = strong optical vignetting")?;
        Ok(())
    }

    /// This aperture with longitudinal chromatic aberration `c` in [`CHROMATIC`]: each colour
    /// channel is rendered with its own circle of confusion, red's `(1 + c)·K·|d − f|`, green's
    /// unchanged, blue's `(1 − c)·K·|d − f|` (c > 0: red fringes outside, blue inside; c < 0
    /// the reverse; 0 = none). The shape is the same in every channel, its flux one in each.
    pub fn with_chromatic(self, c: f32) -> Result<Aperture> {
        Aperture::check_values(1.0, 0.0, c, 0.0)?;
        Ok(Aperture { chromatic: c, ..self })
    }

    /// This aperture with optical vignetting ("cat's eye") of strength `s` in [`CAT_EYE`]:
    /// a ray is clipped by a second circle of the shape's circumradius, displaced toward the
    /// frame's centre by `s` times the distance of the pixel it lands on from the centre over
    /// the half-diagonal (see [`CatEye`]): a bokeh is round in the middle of the frame and cut
    /// on the side away from the centre toward the corners, as a real lens's barrel clips its
    /// pupil off axis; each pixel's light is normalized by the share of the lens it sees, so a
    /// surface stays uniform ([`CatEye::cut`], [`Geometry::cat_gain`]). Every shape: the
    /// disc, blades, an image, with or without a bubble profile (whose light is weighted by
    /// the profile in the cut as in the gain, [`Geometry::flux_in_circle`]); 0 = off.
    pub fn with_cat_eye(self, s: f32) -> Result<Aperture> {
        Aperture::check_values(1.0, 0.0, 0.0, s)?;
        if s == 0.0 {
            return Ok(self);
        }
        // The disc as a polygon (the kernels' radial ramp has no cut).
        let shape = self.shape.or_else(|| Aperture::from_kind(ShapeSpec::Disc, 1.0, 0.0, Kind::polygon(circle(CURVE_VERTICES))).shape);
        Ok(Aperture { shape, cat_eye: s, ..self })
    }

    /// The cat's eye of a `width × height` frame; None without one.
    pub fn cat_eye(self, width: usize, height: usize) -> Option<CatEye> {
        (self.cat_eye > 0.0).then(|| CatEye::new(self.cat_eye, width, height))
    }

    /// The radius the fast kernel draws a larger CoC with in a window of half-size `p` (see
    /// [`Geometry::drawn_cap`]); None for the disc. A cat's eye cuts the shape down to a
    /// sliver off axis: twice the window's radius.
    pub fn drawn_cap(self, p: usize) -> Option<f32> {
        let g = self.shape?;
        Some(if self.cat_eye > 0.0 { 2.0 * (p as f32 + 1.0) } else { g.drawn_cap(p) })
    }

    /// The longitudinal chromatic aberration `C` (0 = none).
    pub fn chromatic(self) -> f32 {
        self.chromatic
    }

    /// The scale of each colour channel's circle of confusion, `[1 + C, 1, 1 − C]`; None
    /// without chromatic aberration (one pass renders every channel).
    pub fn channel_scales(self) -> Option<[f32; 3]> {
        (self.chromatic != 0.0).then_some([1.0 + self.chromatic, 1.0, 1.0 - self.chromatic])
    }

    /// The largest of [`Aperture::channel_scales`] (1 without aberration): what a lens window
    /// sized from K must grow by.
    pub fn max_channel_scale(self) -> f32 {
        1.0 + self.chromatic.abs()
    }

    /// The same shape without chromatic aberration: what one channel's pass renders.
    pub fn achromatic(self) -> Aperture {
        Aperture { chromatic: 0.0, ..self }
    }

    /// The geometry; None for the disc, which the kernels draw themselves.
    pub fn geometry(self) -> Option<&'static Geometry> {
        self.shape
    }

    /// Whether the shape is the plain disc (whatever the chromatic aberration).
    pub fn is_disc(self) -> bool {
        self.shape.is_none()
    }

    /// How reports name it: `disc`, `blades:6,rotation=0,curvature=0`, `image:star.png`, with
    /// `,anamorphic=A`, `,bubble=B`, `,cat_eye=S` and `,chromatic=C` when set.
    pub fn label(self) -> String {
        let mut s = match self.shape {
            None => "disc".into(),
            Some(g) => {
                let mut s = g.spec.label();
                if g.anamorphic != 1.0 {
                    s += &format!(",anamorphic={}", g.anamorphic);
                }
                if g.bubble != 0.0 {
                    s += &format!(",bubble={}", g.bubble);
                }
                s
            }
        };
        if self.cat_eye != 0.0 {
            s += &format!(",cat_eye={}", self.cat_eye);
        }
        if self.chromatic != 0.0 {
            s += &format!(",chromatic={}", self.chromatic);
        }
        s
    }
}

/// A non-disc aperture: its outline (unit circumradius, centred, y up, the anamorphic squeeze
/// applied) and the figures the kernels need.
#[derive(Debug, PartialEq)]
pub struct Geometry {
    spec: ShapeSpec,
    anamorphic: f32,
    /// The radial intensity profile's `B` (see [`Aperture::with_bubble`]).
    bubble: f32,
    kind: Kind,
    /// The outline's area in the unit frame.
    area: f64,
    /// Radius of the largest centred disc inside the outline (unit frame).
    inradius: f64,
    /// Whether the outline equals its point reflection (then foreground and background bokeh
    /// are the same and the fast kernel shares their templates).
    symmetric: bool,
    /// Whether the outline equals its mirror image in x (x → −x) and in y (y → −y): the fast
    /// kernel then builds a cat's eye's cut templates for one side of each such axis and
    /// mirrors them for the other.
    mirrors: [bool; 2],
}

#[derive(Debug, PartialEq)]
enum Kind {
    /// A convex polygon, counterclockwise, its edges' half-planes `n·p ≤ c` (unit `n`), its
    /// bounding box and the radii of its inscribed and circumscribed centred circles (a
    /// rectangle inside the one or outside the other needs no plane: most pixels).
    Polygon { pts: Vec<[f64; 2]>, planes: Vec<[f64; 3]>, bbox: [f64; 4], radii: [f64; 2], sectors: Sectors },
    /// A grey mask: the unit frame's rectangle `[-hw, hw] × [-hh, hh]` holds `w × h` cells.
    Mask(Mask),
}

impl Kind {
    fn polygon(pts: Vec<[f64; 2]>) -> Kind {
        let planes = half_planes(&pts);
        let fold = |f: fn(f64, f64) -> f64, init: f64, k: usize| pts.iter().map(|p| p[k]).fold(init, f);
        let bbox = [
            fold(f64::min, f64::INFINITY, 0),
            fold(f64::max, f64::NEG_INFINITY, 0),
            fold(f64::min, f64::INFINITY, 1),
            fold(f64::max, f64::NEG_INFINITY, 1),
        ];
        let inner = planes.iter().map(|p: &[f64; 3]| p[2]).fold(f64::INFINITY, f64::min);
        let outer = pts.iter().map(|p| (p[0] * p[0] + p[1] * p[1]).sqrt()).fold(0.0, f64::max);
        let sectors = Sectors::new(&pts);
        Kind::Polygon { pts, planes, bbox, radii: [inner, outer], sectors }
    }
}

impl Geometry {
    fn new(spec: ShapeSpec, anamorphic: f32, bubble: f32, kind: Kind) -> Geometry {
        let (sx, sy) = squeeze(anamorphic);
        let kind = match kind {
            Kind::Polygon { pts, .. } => Kind::polygon(pts.iter().map(|p| [p[0] * sx, p[1] * sy]).collect()),
            Kind::Mask(mut m) => {
                m.hw *= sx;
                m.hh *= sy;
                // A mask's radial profile is by distance from the centre (the circumscribed
                // circle's radius is 1).
                if bubble != 0.0 {
                    m.profiled = m.table(|v, x, y| v * profile(bubble, x.hypot(y)));
                }
                Kind::Mask(m)
            }
        };
        let (area, inradius, symmetric, mirrors) = match &kind {
            Kind::Polygon { pts, planes, .. } => {
                let area = shoelace(pts);
                let inradius = planes.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min).max(0.0);
                // Whether every vertex's image under (x, y) → (sx·x, sy·y) is a vertex.
                let maps = |sx: f64, sy: f64| {
                    pts.iter().all(|p| pts.iter().any(|q| (sx * p[0] - q[0]).abs() < 1e-9 && (sy * p[1] - q[1]).abs() < 1e-9))
                };
                (area, inradius, maps(-1.0, -1.0), [maps(-1.0, 1.0), maps(1.0, -1.0)])
            }
            // Its flux is the profile-weighted sum of its cells.
            Kind::Mask(m) => (
                m.total(if bubble == 0.0 { &m.sat } else { &m.profiled }) * (4.0 * m.hw * m.hh) / (m.w * m.h) as f64,
                0.0,
                m.symmetric(),
                // A cat's eye's cut templates of an image are never mirrored.
                [false; 2],
            ),
        };
        Geometry { spec, anamorphic, bubble, kind, area, inradius, symmetric, mirrors }
    }

    /// Whether foreground and background bokeh are the same shape.
    pub fn symmetric(&self) -> bool {
        self.symmetric
    }

    /// Whether the outline is its own mirror image in x (x → −x) and in y (y → −y): the
    /// disc's polygon both, a hexagon at 0° both, a pentagon at 90° in x only.
    pub fn mirrors(&self) -> [bool; 2] {
        self.mirrors
    }

    /// The flux of a source of CoC `r` (pixels) spread by coverage: the shape's area
    /// `area·r²` in pixels, the lattice sum of [`Geometry::coverage`]; 1 below
    /// [`POINT_COC_PX`] (the source stays in its pixel).
    pub fn norm(&self, r: f32) -> f32 {
        if r < POINT_COC_PX { 1.0 } else { (self.area * r as f64 * r as f64) as f32 }
    }

    /// The weight of the pixel centred `(x, y)` pixels from a source (output coordinates,
    /// y up) in the source's bokeh of CoC `r`, before [`Geometry::norm`]; `flip` for a source
    /// in front of the focal plane (the shape point-reflected).
    ///
    /// Both squares are integrated: the source's (a texel is the mean radiance over its
    /// square) and the target's (a pixel averages over its square), so the weight is the
    /// shape convolved with the tent `box ⊗ box`, the footprint a thin lens gives box texels
    /// (and what `drbokeh trace` renders). With only the target's square, the fine textures
    /// blurred by a hexagon came out 8 dB further from the tracer than the disc's radial ramp
    /// (bench scene s004, seed 1). The tent is integrated as the mean of the target square's
    /// coverage ([`Geometry::square_area`]) over 4 × 4 offsets of the square: each offset's
    /// coverages tile the plane, so the lattice sum is the shape's area exactly, whatever the
    /// quadrature error. Exactly 1 where the 2 × 2 px neighbourhood lies inside the shape.
    /// Unlike the disc's ramp, a shape has no in-focus threshold: as the CoC shrinks its
    /// weights tend continuously to the source's own pixel (the quadrature's tent is a
    /// staircase: a neighbour gets light from a CoC of 1/8 px on); below [`POINT_COC_PX`] the
    /// source's own pixel alone (1).
    pub fn coverage(&self, r: f32, x: f32, y: f32, flip: bool) -> f32 {
        self.coverage_cut(r, x, y, flip, None)
    }

    /// [`Geometry::coverage`] of the shape intersected with the circle `cut` (unit frame, y
    /// up, before the point reflection: a cat's eye's second circle as one source's bokeh
    /// meets it, [`CatEye::cut`]); None is the whole shape.
    pub fn coverage_cut(&self, r: f32, x: f32, y: f32, flip: bool, cut: Option<CutCircle>) -> f32 {
        self.coverage_cut_f64(r, x, y, flip, cut) as f32
    }

    /// [`Geometry::coverage_cut`] before its rounding to f32: what differences in `r` take
    /// ([`super::sources`]).
    pub(crate) fn coverage_cut_f64(&self, r: f32, x: f32, y: f32, flip: bool, cut: Option<CutCircle>) -> f64 {
        if r < POINT_COC_PX {
            return if x == 0.0 && y == 0.0 { 1.0 } else { 0.0 };
        }
        let (x, y) = if flip { (-x, -y) } else { (x, y) };
        if let Some(CutCircle { centre: [vx, vy], radius }) = cut {
            let (x, y, r) = (x as f64, y as f64, r as f64);
            // Wholly outside the cut circle: most of the window off axis.
            let (dx, dy) = (x - vx as f64 * r, y - vy as f64 * r);
            if (dx * dx + dy * dy).sqrt() - std::f64::consts::SQRT_2 > radius as f64 * r {
                return 0.0;
            }
            // Well inside both outlines (the cut circle is `radius − |v|` from the centre at
            // its nearest): no clipping, most of a large bokeh's pixels (uniform ones only).
            let inner = self.inradius.min(radius as f64 - ((vx * vx + vy * vy) as f64).sqrt()) * r;
            if self.bubble == 0.0 && (x * x + y * y).sqrt() + std::f64::consts::SQRT_2 < inner {
                return 1.0;
            }
        }
        let cut = cut.map(|c| ([c.centre[0] as f64, c.centre[1] as f64], c.radius as f64));
        match self.square_area(r, x, y, 1.0, cut) {
            Area::Inside if self.bubble == 0.0 => return 1.0,
            Area::Part(0.0) => return 0.0,
            _ => {}
        }
        // A cat's eye's cut shape (the outline's polygon, then the exact cut circle per
        // offset) is built into a template per source class: 2 × 2 offsets (the tiling, hence
        // the flux, stays exact; the outline's half-maximum stays on it: tests/aperture.rs).
        let n = if cut.is_some() { 2 } else { 4 };
        let mut acc = 0f64;
        for i in 0..n {
            for j in 0..n {
                let (ox, oy) = ((i as f32 + 0.5) / n as f32 - 0.5, (j as f32 + 0.5) / n as f32 - 0.5);
                let area = || match self.square_area(r, x + ox, y + oy, 0.5, cut) {
                    Area::Inside => 1.0,
                    Area::Part(a) => a * r as f64 * r as f64,
                };
                acc += if self.bubble == 0.0 {
                    area()
                } else {
                    // The exact profile integral on small shapes, the midpoint rule (the
                    // square's centre's intensity) on large polygons, blended between; an
                    // image's is exact and as cheap at every CoC.
                    let w = if matches!(self.kind, Kind::Mask(_)) { 0.0 } else { BUBBLE_EXACT_BELOW.blend(r) };
                    let exact = if w < 1.0 { self.bubble_integral(r, x + ox, y + oy, 0.5, cut) } else { 0.0 };
                    let midpoint = if w > 0.0 { area() * self.intensity((x + ox) / r, (y + oy) / r) as f64 } else { 0.0 };
                    (1.0 - w) * exact + w * midpoint
                };
            }
        }
        // A bubble's rim (or centre) is brighter than 1.
        (acc / (n * n) as f64).clamp(0.0, (1.0 + self.bubble.abs()) as f64)
    }

    /// The bubble profile's integral over the shape (circumradius `r` px) inside the square of
    /// half-side `half` px centred `(x, y)` px from the source (y up, not reflected), in square
    /// pixels: the area the square's light comes from, each point weighted by the profile.
    ///
    /// One intensity per square (its centre's) is far off once the shape is a few pixels wide:
    /// a 0.3 px disc took the profile's rim value for all its light, 1.4 times its flux for a
    /// bright rim (9.5 dB from the thin-lens truth on bench scene s003 of seed 1 at
    /// `--bubble -0.5`). Exact instead, through the shape's scaling: the points of gauge at
    /// most `s` are the shape scaled by `s`, so with `P(s)` the square's area inside it,
    /// `∫ t² = P(1) − 2∫₀¹ s·P(s) ds` and the profile's integral is
    /// `P(1) + B·(P(1) − 4∫₀¹ s·P(s) ds)`. `P` is 0 below the square's least gauge and the
    /// square's area above its corners' greatest (the shape is convex); between, Gauss–Legendre
    /// nodes. For a square that holds the whole shape the rule is exact (`P(s) = area·r²·s²`,
    /// `∫ s³ = 1/4`): a shape inside one pixel keeps its light there at every CoC, with no
    /// slope in the CoC (which would be a false gradient near the focal plane). An image's profile is in its
    /// weighted table ([`Mask::profiled_integral`]), exact at every CoC.
    ///
    /// A cat's eye's `cut` (unit frame, as [`Geometry::square_area`]'s) restricts the square
    /// to the part inside its circle: the same rule holds for that region (`P(s)` its area
    /// inside the shape scaled by `s`, the whole region's above the corners' gauge).
    fn bubble_integral(&self, r: f32, x: f32, y: f32, half: f32, cut: Option<([f64; 2], f64)>) -> f64 {
        let outer = match &self.kind {
            Kind::Polygon { radii: [_, outer], .. } => *outer,
            Kind::Mask(m) => {
                let (s, (x, y, h)) = (1.0 / r as f64, (x as f64, y as f64, half as f64));
                let rect = [(x - h) * s, (x + h) * s, (y - h) * s, (y + h) * s];
                let sum = match cut {
                    None => m.profiled_integral(rect),
                    Some(_) if m.rect_sum(&m.sat, rect) <= 0.0 => 0.0,
                    Some((v, radius)) => m.circle_sum(&m.profiled, rect, v, radius).max(0.0),
                };
                return sum * r as f64 * r as f64;
            }
        };
        let (rf, xf, yf, h) = (r as f64, x as f64, y as f64, half as f64);
        // The square's area inside the cut (px²).
        let full = match cut {
            None => 4.0 * h * h,
            Some((v, radius)) => {
                let square = [[xf - h, yf - h], [xf + h, yf - h], [xf + h, yf + h], [xf - h, yf + h]];
                polygon_circle_area(&square, [v[0] * rf, v[1] * rf], radius * rf)
            }
        };
        if full <= 0.0 {
            return 0.0;
        }
        // The cut circle in the unit frame of the shape scaled by `s`.
        let within = |s: f64| match self.square_area((rf * s) as f32, x, y, half, cut.map(|(v, radius)| ([v[0] / s, v[1] / s], radius / s)))
        {
            Area::Inside => full,
            Area::Part(a) => a * (rf * s) * (rf * s),
        };
        // The square's nearest point to the centre bounds its least gauge from below.
        let near = ((xf.abs() - h).max(0.0).hypot((yf.abs() - h).max(0.0))) / (rf * outer);
        if near >= 1.0 {
            return 0.0;
        }
        let corners = [(-h, -h), (h, -h), (-h, h), (h, h)];
        let far = corners.iter().map(|&(dx, dy)| self.gauge((xf + dx) / rf, (yf + dy) / rf)).fold(0.0, f64::max);
        // The region is also inside the cut's circle: its gauges lie within the circle's.
        let (near, far) = match cut {
            Some((v, radius)) => {
                let (lo, hi) = self.circle_gauges(v, radius, outer);
                (near.max(lo), far.min(hi))
            }
            None => (near, far),
        };
        if near >= 1.0 {
            return 0.0;
        }
        let (a, b) = (near, far.min(1.0));
        // Under a cut `P(s)` is no longer `∝ s²` where the square holds the shape: below
        // [`CUT_PANELS_BELOW`] the nodes of [`Geometry::flux_in_circle`]'s panels (the same
        // band there) keep a tiny bokeh's light in its pixel as the gains count it (one panel
        // was 0.3% off, a false slope in the CoC); above, one panel, blended between.
        let w = if cut.is_some() { CUT_PANELS_BELOW.blend(r) } else { 1.0 };
        let fine = if w < 1.0 { gauss_legendre(a, b, FLUX_PANELS, |s| s * within(s)) } else { 0.0 };
        let coarse = if w > 0.0 { gauss_legendre(a, b, 1, |s| s * within(s)) } else { 0.0 };
        let band = (1.0 - w) * fine + w * coarse;
        let moment = band + if far < 1.0 { full * 0.5 * (1.0 - far * far) } else { 0.0 };
        let p1 = if far <= 1.0 { full } else { within(1.0) };
        (p1 + self.bubble as f64 * (p1 - 4.0 * moment)).max(0.0)
    }

    /// Bounds on the gauges of the points of the circle of radius `radius` centred `v` (unit
    /// frame), for a polygon whose circumradius is `outer`: `(|v| − radius)/outer` (at least
    /// 0) below, `(|v| + radius)/inradius` above (the whole circle is inside the shape scaled
    /// by that).
    fn circle_gauges(&self, v: [f64; 2], radius: f64, outer: f64) -> (f64, f64) {
        let d = v[0].hypot(v[1]);
        (((d - radius) / outer).max(0.0), (d + radius) / self.inradius.max(1e-12))
    }

    /// The gauge of the unit-frame point `(x, y)` (y up): the scale of the outline through it,
    /// `max n·p / c` over the polygon's edges; for an image, the distance from the centre.
    fn gauge(&self, x: f64, y: f64) -> f64 {
        match &self.kind {
            Kind::Polygon { planes, sectors, .. } => {
                sectors.planes(planes, [x, x, y, y]).map(|&[nx, ny, c]| (nx * x + ny * y) / c).fold(0.0, f64::max)
            }
            Kind::Mask(_) => (x * x + y * y).sqrt(),
        }
    }

    /// The bubble profile's intensity at the unit-frame point `(x, y)` (y up, not reflected):
    /// `1 + B·(2t² − 1)` where `t` is the point's relative radius, the scale of the outline
    /// through it (the polygon's gauge, `max n·p / c` over its edges; for an image, the
    /// distance from the centre). 1 without a bubble.
    pub fn intensity(&self, x: f32, y: f32) -> f32 {
        if self.bubble == 0.0 {
            return 1.0;
        }
        profile(self.bubble, self.gauge(x as f64, y as f64)) as f32
    }

    /// The unit-frame area of the shape (circumradius `r` px), cut by the circle `cut`
    /// (centre, radius) if any, inside the square of half-side `half` px centred `(x, y)` px from the
    /// source (y up, not reflected). O(1) inside and outside the shape, O(vertices) on its
    /// outline.
    fn square_area(&self, r: f32, x: f32, y: f32, half: f32, cut: Option<([f64; 2], f64)>) -> Area {
        let s = 1.0 / r as f64;
        let (x, y, h) = (x as f64, y as f64, half as f64);
        let rect = [(x - h) * s, (x + h) * s, (y - h) * s, (y + h) * s];
        match (&self.kind, cut) {
            (Kind::Polygon { pts, planes, bbox, radii, sectors }, cut) => {
                let [x0, x1, y0, y1] = rect;
                // The rectangle seen from the cut circle's centre: wholly outside it, nothing;
                // wholly inside, the shape's area as without a cut.
                let cut = match cut {
                    Some((v, radius)) => {
                        let (near, far) = rect_reach([x0 - v[0], x1 - v[0], y0 - v[1], y1 - v[1]]);
                        if near >= radius * radius {
                            return Area::Part(0.0);
                        }
                        (far > radius * radius).then_some((v, radius))
                    }
                    None => None,
                };
                let whole = x0 <= bbox[0] && x1 >= bbox[1] && y0 <= bbox[2] && y1 >= bbox[3];
                if whole && cut.is_none() {
                    return Area::Part(self.area);
                }
                // The part of `poly` (the shape, clipped) inside the cut circle, if any.
                let in_cut = |poly: &[[f64; 2]]| match cut {
                    _ if poly.len() < 3 => 0.0,
                    None => shoelace(poly).max(0.0),
                    Some((v, radius)) => polygon_circle_area(poly, v, radius),
                };
                // A rectangle as wide as half the shape meets many edges: clipping the polygon
                // by the rectangle's four sides is O(vertices), the rectangle by each edge that
                // cuts it O(edges²) (most of the time of a small bubble's exact profile, which
                // asks for pixels at small scales of the shape; a cut bubble's 12 times over).
                let disjoint = x1 <= bbox[0] || x0 >= bbox[1] || y1 <= bbox[2] || y0 >= bbox[3];
                if whole || !disjoint && (x1 - x0).max(y1 - y0) > 0.5 * radii[1] && rect_reach(rect).1 >= radii[0] * radii[0] {
                    // Only by the sides that cross the shape's box: the others clip nothing
                    // (none when the rectangle holds the shape, as at a cut bubble's small
                    // scales).
                    let sides = [
                        ([-1.0, 0.0, -x0], x0 > bbox[0]),
                        ([1.0, 0.0, x1], x1 < bbox[1]),
                        ([0.0, -1.0, -y0], y0 > bbox[2]),
                        ([0.0, 1.0, y1], y1 < bbox[3]),
                    ];
                    if !sides.iter().any(|&(_, crosses)| crosses) {
                        return Area::Part(in_cut(pts));
                    }
                    // Per-thread scratch: a small bubble's profile asks for millions of these.
                    thread_local!(static SCRATCH: std::cell::RefCell<[Vec<[f64; 2]>; 2]> = const { std::cell::RefCell::new([Vec::new(), Vec::new()]) });
                    return SCRATCH.with_borrow_mut(|[poly, next]| {
                        let mut clipped = false;
                        for (side, _) in sides.into_iter().filter(|&(_, crosses)| crosses) {
                            next.clear();
                            clip_half_plane(if clipped { poly } else { pts }, side, next);
                            std::mem::swap(poly, next);
                            clipped = true;
                        }
                        Area::Part(in_cut(poly))
                    });
                }
                if cut.is_none() {
                    return polygon_rect_area(planes, bbox, *radii, sectors, rect);
                }
                let mut poly: Poly = smallvec::smallvec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
                let mut next = Poly::new();
                match clip_convex(planes, bbox, *radii, sectors, [0.0; 2], rect, &mut poly, &mut next) {
                    Clip::Empty => Area::Part(0.0),
                    _ => Area::Part(in_cut(&poly)),
                }
            }
            (Kind::Mask(m), None) => m.integral(rect),
            (Kind::Mask(m), Some((v, radius))) => {
                let [x0, x1, y0, y1] = rect;
                let (near, far) = rect_reach([x0 - v[0], x1 - v[0], y0 - v[1], y1 - v[1]]);
                if far <= radius * radius {
                    return m.integral(rect);
                }
                // Across the circle's outline: nothing where the mask is closed, the exact
                // circle where it is wholly open, else the mask's bands.
                if near >= radius * radius || m.rect_sum(&m.sat, rect) <= 0.0 {
                    return Area::Part(0.0);
                }
                let open = x0 >= -m.hw && x1 <= m.hw && y0 >= -m.hh && y1 <= m.hh && m.rect_sum(&m.holes, rect) == 0.0;
                Area::Part(if open {
                    polygon_circle_area(&[[x0, y0], [x1, y0], [x1, y1], [x0, y1]], v, radius)
                } else {
                    m.circle_sum(&m.sat, rect, v, radius).max(0.0)
                })
            }
        }
    }

    /// The unit-frame flux of the shape inside `cut` (the lattice sum of
    /// [`Geometry::coverage_cut`]'s weights over `r²`): a cat's-eye source's flux, in units
    /// of the whole shape's over its area ([`Geometry::flux_in_circle`]).
    pub fn cut_area(&self, cut: CutCircle) -> f64 {
        self.flux_in_circle([cut.centre[0] as f64, cut.centre[1] as f64], cut.radius as f64)
    }

    /// The unit-frame flux of the shape inside the circle of radius `radius` centred `v` (an
    /// exact circle, as [`Geometry::coverage_cut`]'s): its area, weighted by a bubble's
    /// profile; the whole shape's is its area (the profile's mean over the outline is 1).
    ///
    /// A polygon's area inside a circle is exact, O(vertices); with a bubble, the profile's
    /// integral by the shape's scaling as in [`Geometry::bubble_integral`] (`P(s)` the circle's
    /// area inside the shape scaled by `s`), with Gauss–Legendre nodes over
    /// [`FLUX_PANELS`] panels of the band of `s` where `P` changes. An image's by
    /// [`Mask::circle_sum`].
    pub fn flux_in_circle(&self, v: [f64; 2], radius: f64) -> f64 {
        let (pts, outer) = match &self.kind {
            Kind::Mask(m) => {
                let frame = [-m.hw, m.hw, -m.hh, m.hh];
                return m.circle_sum(if self.bubble == 0.0 { &m.sat } else { &m.profiled }, frame, v, radius).max(0.0);
            }
            Kind::Polygon { pts, radii: [_, outer], .. } => (pts, *outer),
        };
        let p1 = polygon_circle_area(pts, v, radius);
        if self.bubble == 0.0 || p1 <= 0.0 {
            return p1;
        }
        // `P(s) = s²·area(shape ∩ circle / s)`: 0 below the circle's least gauge, the whole
        // circle above its greatest.
        let at = |s: f64| s * s * polygon_circle_area(pts, [v[0] / s, v[1] / s], radius / s);
        let (a, far) = self.circle_gauges(v, radius, outer);
        let b = far.min(1.0);
        let band = gauss_legendre(a, b, FLUX_PANELS, |s| s * at(s));
        let moment = band + if far < 1.0 { std::f64::consts::PI * radius * radius * 0.5 * (1.0 - far * far) } else { 0.0 };
        (p1 + self.bubble as f64 * (p1 - 4.0 * moment)).max(0.0)
    }

    /// What a cat's eye's target pixel whose circle is centred `v` ([`CatEye::offset`])
    /// multiplies the light reaching it by: the shape's flux over its flux inside that unit
    /// circle ([`Geometry::flux_in_circle`]), the share of the lens the pixel sees (the
    /// tracer's per-pixel norm, its samples weighted by the profile). With each source spread
    /// at the whole shape's flux norm ([`Geometry::norm`]) through its cut ([`CatEye::cut`]),
    /// a uniform surface then stays uniform at any CoC. At least 1.
    pub fn cat_gain(&self, v: [f32; 2]) -> f32 {
        (self.area / self.flux_in_circle([v[0] as f64, v[1] as f64], 1.0).max(1e-12)) as f32
    }

    /// An area-preserving map from the unit square to a polygon's inside (unit frame, y up),
    /// continuous (so stratified samples stay stratified): the thin-lens tracer samples the
    /// shape with it. None for an image aperture (sample a disc and weight by
    /// [`Geometry::transmission`]).
    pub fn sample(&self, u: f32, v: f32) -> Option<(f32, f32)> {
        let Kind::Polygon { pts, .. } = &self.kind else { return None };
        let n = pts.len();
        let total = self.area;
        // `v` walks the outline by swept area (the fan's triangle from the centre to a point
        // of an edge grows linearly along it), `u` the radius as √u: uniform, and continuous
        // in `v` from one edge to the next.
        let mut target = v as f64 * total;
        let t = (u as f64).sqrt();
        for k in 0..n {
            let (a, b) = (pts[k], pts[(k + 1) % n]);
            let tri = 0.5 * (a[0] * b[1] - a[1] * b[0]);
            if target < tri || k + 1 == n {
                let s = (target / tri).clamp(0.0, 1.0);
                return Some(((t * ((1.0 - s) * a[0] + s * b[0])) as f32, (t * ((1.0 - s) * a[1] + s * b[1])) as f32));
            }
            target -= tri;
        }
        None
    }

    /// The aperture's transmission at the unit-frame point `(x, y)` (circumradius 1, y up,
    /// the shape as a source behind the focal plane shows it): 0 or 1 for a polygon, the
    /// cell's grey value for an image. What the thin-lens tracer weights its lens samples by.
    pub fn transmission(&self, x: f32, y: f32) -> f32 {
        let (x, y) = (x as f64, y as f64);
        match &self.kind {
            Kind::Polygon { planes, .. } => {
                if planes.iter().all(|&[nx, ny, c]| nx * x + ny * y <= c) {
                    self.intensity(x as f32, y as f32)
                } else {
                    0.0
                }
            }
            Kind::Mask(m) => {
                let (u, v) = ((x + m.hw) / (2.0 * m.hw) * m.w as f64, (m.hh - y) / (2.0 * m.hh) * m.h as f64);
                if u < 0.0 || v < 0.0 || u >= m.w as f64 || v >= m.h as f64 {
                    return 0.0;
                }
                m.values[v as usize * m.w + u as usize] * self.intensity(x as f32, y as f32)
            }
        }
    }

    /// The radius the fast kernel draws a larger CoC with, in a window of half-size `p`:
    /// where a polygon's inscribed circle holds the window (beyond, the window shows the
    /// inside of the shape whatever the CoC), but at most twice the window's radius, so that
    /// the coarse grid drawing it keeps cells well inside the window (a CoC beyond the window
    /// happens only with a `--lens` narrower than the blur; there a thin or image shape is
    /// drawn as it looks at that radius, its flux from its true CoC).
    pub fn drawn_cap(&self, p: usize) -> f32 {
        let p = p as f64 + 1.0;
        let cap = match &self.kind {
            Kind::Polygon { .. } => p / self.inradius.max(1e-3) + 1.0,
            Kind::Mask(_) => f64::INFINITY,
        };
        cap.min(2.0 * p) as f32
    }
}

/// A circle that cuts a shape (unit frame: the shape's circumradius is 1; y up, before the
/// point reflection): a cat's eye's second circle as one source's light meets it
/// ([`CatEye::cut`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CutCircle {
    /// Centre, unit frame.
    pub centre: [f32; 2],
    /// Radius, unit frame.
    pub radius: f32,
}

/// Optical vignetting over one frame (`Aperture::with_cat_eye`): where each pixel's second
/// circle sits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatEye {
    strength: f32,
    /// The frame's centre, pixels (column, row of pixel centres).
    cx: f32,
    cy: f32,
    /// 1 / the half-diagonal, per pixel.
    inv_reach: f32,
    /// The frame, pixels.
    width: usize,
    height: usize,
}

/// How far (unit frame) a target's circle moves between the pixel lattice points
/// [`CatEye::gains`] looks the gain up at: every pixel on frames up to ~380 px across at
/// strength 1. The gain is smooth in the circle's centre `v` but for a cone at 0 (the frame's
/// middle; the disc's gain is `1 + 2|v|/π` there), which bilinear interpolation at this step
/// misses by at most ~0.2%.
const GAIN_STEP: f32 = 1.0 / 192.0;

/// The polar table of [`Geometry::cat_gain`] that [`CatEye::gains`] reads: nodes in `|v|`
/// over `[0, strength]` and, unless the shape is round, in the angle. Polar, so the cone at
/// `v = 0` is linear along the radius; a table, because the gain is an O(vertices) area (the
/// disc is a 256-gon) and a 480 × 320 frame asked it at every pixel: 38% of its cat's-eye
/// render, 2026-11-29.
struct GainTable {
    /// `[radial][angular]`, row-major by radius.
    values: Vec<f32>,
    radial: usize,
    angular: usize,
    /// Radial nodes per unit of `|v|`.
    per_unit: f32,
}

impl GainTable {
    const RADIAL: usize = 96;
    const ANGULAR: usize = 96;

    fn new(g: &Geometry, strength: f32) -> GainTable {
        let radial = Self::RADIAL;
        let per_unit = (radial - 1) as f32 / strength.max(1e-6);
        let at = |r: usize, t: usize, angular: usize| {
            let (rho, theta) = (r as f32 / per_unit, t as f32 * std::f32::consts::TAU / angular as f32);
            g.cat_gain([rho * theta.cos(), rho * theta.sin()])
        };
        // Round (the disc, its anamorphic squeeze aside): the gain along one ray is the gain.
        let probe: Vec<f32> = (0..8).map(|t| at(radial / 2, t, 8)).chain((0..8).map(|t| at(radial - 1, t, 8))).collect();
        let round =
            probe[..8].iter().all(|&p| (p / probe[0] - 1.0).abs() < 1e-5) && probe[8..].iter().all(|&p| (p / probe[8] - 1.0).abs() < 1e-5);
        let angular = if round { 1 } else { Self::ANGULAR };
        let values = (0..radial * angular).into_par_iter().map(|k| at(k / angular, k % angular, angular)).collect();
        GainTable { values, radial, angular, per_unit }
    }

    /// The table of `g` at `strength`, built once per process: every layer of a render, every
    /// preview of the viewer and every frame of a batch asks for the same one (an image's
    /// takes ~0.1 s of CPU: 9,216 fluxes of a whole circle through its mask).
    fn cached(g: &'static Geometry, strength: f32) -> std::sync::Arc<GainTable> {
        type Entry = (usize, u32, std::sync::Arc<GainTable>);
        static TABLES: Mutex<Vec<Entry>> = Mutex::new(Vec::new());
        let key = (g as *const Geometry as usize, strength.to_bits());
        if let Some((_, _, t)) = TABLES.lock().unwrap_or_else(|e| e.into_inner()).iter().find(|(p, s, _)| (*p, *s) == key) {
            return std::sync::Arc::clone(t);
        }
        // Built outside the lock (in parallel); two threads asking at once both build it.
        let t = std::sync::Arc::new(GainTable::new(g, strength));
        let mut all = TABLES.lock().unwrap_or_else(|e| e.into_inner());
        // A handful per process (one per shape and strength asked for); the oldest go first.
        if all.len() >= 16 {
            all.remove(0);
        }
        all.push((key.0, key.1, std::sync::Arc::clone(&t)));
        t
    }

    /// The gain of circle centre `v` (|v| at most the strength).
    fn at(&self, v: [f32; 2]) -> f32 {
        let fr = ((v[0] * v[0] + v[1] * v[1]).sqrt() * self.per_unit).clamp(0.0, (self.radial - 1) as f32);
        let r0 = (fr as usize).min(self.radial - 2);
        let wr = fr - r0 as f32;
        let n = self.angular;
        let along = |r: usize| {
            if n == 1 {
                return self.values[r];
            }
            let ft = v[1].atan2(v[0]).rem_euclid(std::f32::consts::TAU) * n as f32 / std::f32::consts::TAU;
            let t0 = (ft as usize).min(n - 1);
            let wt = ft - t0 as f32;
            let (a, b) = (self.values[r * n + t0], self.values[r * n + (t0 + 1) % n]);
            a + (b - a) * wt
        };
        let (a, b) = (along(r0), along(r0 + 1));
        a + (b - a) * wr
    }
}

/// Every pixel's cat's-eye gain over one frame ([`CatEye::gains`]): on a pixel lattice from a
/// polar table of the gain ([`GainTable`]), bilinear between lattice points.
#[derive(Clone, Debug)]
pub struct CatGains {
    lattice: Vec<f32>,
    /// Lattice points per row.
    gw: usize,
    /// Pixels between lattice points.
    step: usize,
}

impl CatGains {
    /// The gain of pixel `(x, y)` (column, row).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> f32 {
        let (s, gw) = (self.step, self.gw);
        let (cx, cy) = (x / s, y / s);
        let k = cy * gw + cx;
        if s == 1 {
            return self.lattice[k];
        }
        let (fx, fy) = ((x % s) as f32 / s as f32, (y % s) as f32 / s as f32);
        let l = &self.lattice;
        let top = l[k] + (l[k + 1] - l[k]) * fx;
        let bottom = l[k + gw] + (l[k + gw + 1] - l[k + gw]) * fx;
        top + (bottom - top) * fy
    }
}

impl CatEye {
    /// The cat's eye of strength `strength` over a `width × height` frame.
    pub fn new(strength: f32, width: usize, height: usize) -> CatEye {
        let (w, h) = (width as f32, height as f32);
        let reach = 0.5 * (w * w + h * h).sqrt();
        CatEye {
            strength,
            cx: (w - 1.0) / 2.0,
            cy: (h - 1.0) / 2.0,
            inv_reach: 1.0 / reach.max(0.5),
            width: width.max(1),
            height: height.max(1),
        }
    }

    /// The part of the lens that source pixel `v`'s light (its [`CatEye::offset`]) crosses on
    /// its way to the pixels it reaches, for a CoC of `r` px, in front of the focal plane when
    /// `front`: a circle in the shape's frame (before the point reflection), which
    /// [`Geometry::coverage_cut`] intersects the shape with.
    ///
    /// A lens's barrel clips a ray by the pixel it lands on (the tracer's rule): lens point
    /// `a` (unit frame) of a source lands `∓r·a` from it (reflected in front) at a pixel whose
    /// own circle is centred `v ± k·a`, `k = strength · r / half-diagonal` (the offsets are
    /// linear across the frame). The ray passes where `|a − v ∓ k·a| ≤ 1`: a circle of
    /// radius `1 / |1 ∓ k|` centred `v / (1 ∓ k)` (− in front). Exact for every source
    /// inside the frame; the light that passes is then normalized at each target by
    /// [`Geometry::cat_gain`], as the tracer normalizes a pixel by the lens it sees.
    pub fn cut(&self, v: [f32; 2], r: f32, front: bool) -> CutCircle {
        let k = self.strength * r * self.inv_reach;
        // At |1 ∓ k| → 0 (a CoC as wide as the half-diagonal in front) every ray passes: the
        // circle grows without bound; 1e-3 keeps it finite and holds the shape whole.
        let s = if front { 1.0 - k } else { 1.0 + k };
        let s = if s.abs() < 1e-3 { 1e-3f32.copysign(s) } else { s };
        CutCircle { centre: [v[0] / s, v[1] / s], radius: 1.0 / s.abs() }
    }

    /// Every target pixel's gain ([`Geometry::cat_gain`]) over the frame, for shape `g`.
    pub fn gains(&self, g: &'static Geometry) -> CatGains {
        // The pixel lattice whose step moves the circle's centre by at most `GAIN_STEP`.
        let step = (GAIN_STEP / (self.strength * self.inv_reach)).floor().clamp(1.0, 1e6) as usize;
        let (gw, gh) = ((self.width - 1) / step + 2, (self.height - 1) / step + 2);
        let table = GainTable::cached(g, self.strength);
        let lattice =
            (0..gw * gh).into_par_iter().map(|k| table.at(self.offset(((k % gw) * step) as f32, ((k / gw) * step) as f32))).collect();
        CatGains { lattice, gw, step }
    }

    /// The frame's width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// The frame's height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The strength: how far (unit frame) the second circle moves at the corners.
    pub fn strength(&self) -> f32 {
        self.strength
    }

    /// The centre of the second circle (unit frame: circumradius 1, y up) of pixel `(x, y)`
    /// (column, row; may lie outside the frame; a target's, or a source's for its cut):
    /// toward the frame's centre, the strength times the pixel's distance from the centre
    /// over the half-diagonal (1 at most, so the cut shape always holds the pixel's own point).
    #[inline]
    pub fn offset(&self, x: f32, y: f32) -> [f32; 2] {
        let (ux, uy) = ((x - self.cx) * self.inv_reach, (self.cy - y) * self.inv_reach);
        let n = (ux * ux + uy * uy).sqrt();
        let k = if n > 1.0 { self.strength / n } else { self.strength };
        [-ux * k, -uy * k]
    }
}

/// `(sx, sy)`: the anamorphic squeeze of the unit frame.
fn squeeze(anamorphic: f32) -> (f64, f64) {
    let a = anamorphic as f64;
    if a >= 1.0 { (1.0 / a, 1.0) } else { (1.0, a) }
}

/// `value` if finite and in `range`; else a usage error naming `key` and saying what the
/// values mean.
fn in_range(key: &str, value: f32, range: &std::ops::RangeInclusive<f32>, meaning: &str) -> Result<f32> {
    if value.is_finite() && range.contains(&value) {
        Ok(value)
    } else {
        Err(Error::usage(format!("{key} {value} is outside [{}, {}] ({meaning})", range.start(), range.end())))
    }
}

/// Bands per unit-frame length in [`Mask::circle_sum`] (the mask's whole frame is 2 high).
const CIRCLE_BANDS_PER_UNIT: f64 = 256.0;

/// A grey aperture mask with its summed-area tables.
#[derive(Debug, PartialEq)]
struct Mask {
    w: usize,
    h: usize,
    /// Half-extents of the mask's rectangle in the unit frame (the longer one 1 before the
    /// anamorphic squeeze).
    hw: f64,
    hh: f64,
    /// Summed-area tables, `(w + 1) × (h + 1)`, of the values and of `1 - value` (the
    /// latter tells a rectangle wholly open: its sum is exactly 0).
    sat: Vec<f64>,
    holes: Vec<f64>,
    /// The summed-area table of the values times a bubble's profile at each cell's centre
    /// (empty without a bubble; set by [`Geometry::new`], after the squeeze).
    profiled: Vec<f64>,
    values: Vec<f32>,
}

impl Mask {
    fn read(path: &Path) -> Result<Mask> {
        let decoded = crate::io::image_file::read_decoded(path, &crate::io::ReadLimits::default())?;
        let img = decoded.image;
        let colour = if decoded.has_alpha { img.channels - 1 } else { img.channels };
        if img.width > MAX_IMAGE_SIDE || img.height > MAX_IMAGE_SIDE {
            return Err(Error::input(
                path,
                format!("aperture image is {}x{}; at most {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} is accepted", img.width, img.height),
            ));
        }
        let grey: Vec<f32> = img.data.chunks_exact(img.channels).map(|px| px[..colour].iter().sum::<f32>() / colour as f32).collect();
        Mask::new(img.width, img.height, &grey).map_err(|msg| Error::input(path, format!("aperture image: {msg}")))
    }

    fn new(w: usize, h: usize, values: &[f32]) -> std::result::Result<Mask, String> {
        if w == 0 || h == 0 || values.len() != w * h {
            return Err(format!("empty ({w}x{h}, {} values)", values.len()));
        }
        if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE {
            return Err(format!("{w}x{h}; at most {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} is accepted"));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(format!("the value at ({}, {}) is not finite", i % w, i / w));
        }
        let values: Vec<f32> = values.iter().map(|v| v.clamp(0.0, 1.0)).collect();
        if values.iter().all(|&v| v == 0.0) {
            return Err("all black: no light passes (bright = open)".into());
        }
        let side = w.max(h) as f64;
        let mut m =
            Mask { w, h, hw: w as f64 / side, hh: h as f64 / side, sat: Vec::new(), holes: Vec::new(), profiled: Vec::new(), values };
        m.sat = m.table(|v, _, _| v);
        m.holes = m.table(|v, _, _| 1.0 - v);
        Ok(m)
    }

    /// The summed-area table, `(w + 1) × (h + 1)`, of `f(value, x, y)` at each cell's centre
    /// `(x, y)` (unit frame, y up).
    fn table(&self, f: impl Fn(f64, f64, f64) -> f64) -> Vec<f64> {
        let (w, h) = (self.w, self.h);
        let mut sat = vec![0f64; (w + 1) * (h + 1)];
        for row in 0..h {
            let y = self.hh - (row as f64 + 0.5) * 2.0 * self.hh / h as f64;
            let mut sum = 0f64;
            for col in 0..w {
                let x = -self.hw + (col as f64 + 0.5) * 2.0 * self.hw / w as f64;
                sum += f(self.values[row * w + col] as f64, x, y);
                sat[(row + 1) * (w + 1) + col + 1] = sat[row * (w + 1) + col + 1] + sum;
            }
        }
        sat
    }

    fn symmetric(&self) -> bool {
        let n = self.values.len();
        (0..n).all(|i| self.values[i] == self.values[n - 1 - i])
    }

    /// `∫` of the summed-area table `t` from the mask's top-left corner to cell coordinates
    /// `(u, v)` (columns right, rows down), bilinear inside a cell (exact for cells of
    /// constant value).
    fn sat_at(&self, t: &[f64], u: f64, v: f64) -> f64 {
        let (u, v) = (u.clamp(0.0, self.w as f64), v.clamp(0.0, self.h as f64));
        // Truncation is the floor of these non-negative numbers, without libm's `floor` (8%
        // of a cut image aperture's render on baseline x86-64).
        let (i, j) = ((u as usize).min(self.w - 1), (v as usize).min(self.h - 1));
        let (fu, fv) = (u - i as f64, v - j as f64);
        let at = |a: usize, b: usize| t[b * (self.w + 1) + a];
        let top = at(i, j) * (1.0 - fu) + at(i + 1, j) * fu;
        let bottom = at(i, j + 1) * (1.0 - fu) + at(i + 1, j + 1) * fu;
        top * (1.0 - fv) + bottom * fv
    }

    /// The sum of table `t` over the whole mask.
    fn total(&self, t: &[f64]) -> f64 {
        t[t.len() - 1]
    }

    /// The integral of the profile-weighted mask over the unit-frame rectangle `rect`, in
    /// unit-frame area (its bubble's weights: exact for cells of constant value and profile,
    /// so their lattice sum is the flux norm whatever the CoC).
    fn profiled_integral(&self, rect: [f64; 4]) -> f64 {
        self.rect_sum(&self.profiled, rect).max(0.0)
    }

    /// The sum of table `t` over the unit-frame rectangle `rect`, in unit-frame area (0
    /// outside the mask's frame).
    fn rect_sum(&self, t: &[f64], [x0, x1, y0, y1]: [f64; 4]) -> f64 {
        if x1 <= -self.hw || x0 >= self.hw || y1 <= -self.hh || y0 >= self.hh {
            return 0.0;
        }
        // Cells per unit along each axis; rows run down.
        let (ku, kv) = (self.w as f64 / (2.0 * self.hw), self.h as f64 / (2.0 * self.hh));
        let (u0, u1) = ((x0 + self.hw) * ku, (x1 + self.hw) * ku);
        let (v0, v1) = ((self.hh - y1) * kv, (self.hh - y0) * kv);
        (self.sat_at(t, u1, v1) - self.sat_at(t, u0, v1) - self.sat_at(t, u1, v0) + self.sat_at(t, u0, v0)) / (ku * kv)
    }

    /// The sum of table `t` over the part of the unit-frame rectangle `rect` inside the circle
    /// of radius `radius` centred `c`, in unit-frame area: [`Mask::rect_sum`] where the
    /// rectangle lies inside the circle, 0 outside; across the outline, horizontal bands
    /// within the mask's rows (at most 1/[`CIRCLE_BANDS_PER_UNIT`] high, at least 8 over the
    /// height the circle meets), each summed over the circle's chord at its middle: for an
    /// open mask the midpoint rule of the circle's area (~1e-4 of a unit circle's). A square
    /// that holds the whole mask gets the whole circle's bands. O(bands).
    fn circle_sum(&self, t: &[f64], rect: [f64; 4], c: [f64; 2], radius: f64) -> f64 {
        let [x0, x1, y0, y1] = rect;
        let (near, far) = rect_reach([x0 - c[0], x1 - c[0], y0 - c[1], y1 - c[1]]);
        let r2 = radius * radius;
        if near >= r2 {
            return 0.0;
        }
        if far <= r2 {
            return self.rect_sum(t, rect);
        }
        // The rows (y, up) the circle, the rectangle and the mask share.
        let (ya, yb) = (y0.max(c[1] - radius).max(-self.hh), y1.min(c[1] + radius).min(self.hh));
        if yb <= ya {
            return 0.0;
        }
        let per_unit = CIRCLE_BANDS_PER_UNIT.max(8.0 / (yb - ya));
        // Cells per unit; rows run down from `hh`.
        let (ku, kv) = (self.w as f64 / (2.0 * self.hw), self.h as f64 / (2.0 * self.hh));
        // `yb ≤ hh`: truncation is the floor.
        let (first, last) = (((self.hh - yb) * kv) as usize, (((self.hh - ya) * kv).ceil() as usize).min(self.h));
        let mut sum = 0.0;
        for row in first..last {
            // The row's part of [ya, yb], in bands.
            let (top, bottom) = ((self.hh - row as f64 / kv).min(yb), (self.hh - (row + 1) as f64 / kv).max(ya));
            if top <= bottom {
                continue;
            }
            let bands = ((top - bottom) * per_unit).ceil().max(1.0) as usize;
            let h = (top - bottom) / bands as f64;
            for k in 0..bands {
                let y = bottom + (k as f64 + 0.5) * h;
                let w = (r2 - (y - c[1]) * (y - c[1])).max(0.0).sqrt();
                let (xa, xb) = (x0.max(c[0] - w).max(-self.hw), x1.min(c[0] + w).min(self.hw));
                if xb > xa {
                    sum += self.row_sum(t, row, (xa + self.hw) * ku, (xb + self.hw) * ku) * h / ku;
                }
            }
        }
        sum
    }

    /// The sum of table `t`'s cells in row `row` from column `u0` to `u1` (cell units,
    /// fractional: exact for cells of constant value).
    fn row_sum(&self, t: &[f64], row: usize, u0: f64, u1: f64) -> f64 {
        let stride = self.w + 1;
        let at = |u: f64| {
            // `u ≥ 0` (the callers clip to the mask's left edge): truncation is its floor.
            let i = (u as usize).min(self.w - 1);
            let f = u - i as f64;
            let col = |k: usize| t[(row + 1) * stride + k] - t[row * stride + k];
            col(i) + (col(i + 1) - col(i)) * f
        };
        at(u1) - at(u0)
    }

    /// The mask's integral over the unit-frame rectangle `rect`, in unit-frame area.
    fn integral(&self, rect: [f64; 4]) -> Area {
        let [x0, x1, y0, y1] = rect;
        let inside_frame = x0 >= -self.hw && x1 <= self.hw && y0 >= -self.hh && y1 <= self.hh;
        if inside_frame && self.rect_sum(&self.holes, rect) == 0.0 {
            return Area::Inside;
        }
        Area::Part(self.rect_sum(&self.sat, rect).max(0.0))
    }
}

#[cfg(test)]
mod tests;
