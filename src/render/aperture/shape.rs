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

use crate::error::{Error, Result};
use smallvec::SmallVec;
use std::f64::consts::PI;
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
/// Vertices of a polygonized curve per full turn (an anamorphic disc, rounded blades): the
/// area of a 256-gon is 1e-4 below its circle's.
const CURVE_VERTICES: usize = 256;

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
    /// a source's bokeh is the shape intersected with a second circle of the same
    /// circumradius, displaced toward the frame's centre by `s` times the source's distance
    /// from the centre over the half-diagonal (see [`CatEye`]): round in the middle of the
    /// frame, cut on the side away from the centre toward the corners, as a real lens's
    /// barrel clips its pupil off axis (each source normalized so that a surface stays
    /// uniform: [`CatEye::norm_disc`]). The disc and blade shapes only (an image aperture or a
    /// bubble profile is refused); 0 = off.
    pub fn with_cat_eye(self, s: f32) -> Result<Aperture> {
        Aperture::check_values(1.0, 0.0, 0.0, s)?;
        if s == 0.0 {
            return Ok(self);
        }
        let shape = match self.shape {
            // The disc as a polygon (the kernels' radial ramp has no cut).
            None => Aperture::from_kind(ShapeSpec::Disc, 1.0, 0.0, Kind::polygon(circle(CURVE_VERTICES))).shape,
            Some(g) if matches!(g.kind, Kind::Mask(_)) => {
                return Err(Error::usage(format!("aperture.cat_eye {s}: an image aperture has no cat's eye; use the disc or blades")));
            }
            Some(g) if g.bubble != 0.0 => {
                return Err(Error::usage(format!("aperture.cat_eye {s}: not with a bubble profile (aperture.bubble {})", g.bubble)));
            }
            shape => shape,
        };
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
        let n = pts.len();
        let planes: Vec<[f64; 3]> = (0..n)
            .map(|i| {
                let (a, b) = (pts[i], pts[(i + 1) % n]);
                let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
                let len = (ex * ex + ey * ey).sqrt();
                let (nx, ny) = (ey / len, -ex / len);
                [nx, ny, nx * a[0] + ny * a[1]]
            })
            .collect();
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
                Kind::Mask(m)
            }
        };
        let (area, inradius, symmetric) = match &kind {
            Kind::Polygon { pts, planes, .. } => {
                let area = shoelace(pts);
                let inradius = planes.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min).max(0.0);
                let symmetric = pts.iter().all(|p| pts.iter().any(|q| (p[0] + q[0]).abs() < 1e-9 && (p[1] + q[1]).abs() < 1e-9));
                (area, inradius, symmetric)
            }
            // A mask's radial profile is by distance from the centre (the circumscribed circle's
            // radius is 1): its flux is the profile-weighted sum of its cells.
            Kind::Mask(m) => (
                m.weighted_total(|x, y| profile(bubble, (x * x + y * y).sqrt())) * (4.0 * m.hw * m.hh) / (m.w * m.h) as f64,
                0.0,
                m.symmetric(),
            ),
        };
        Geometry { spec, anamorphic, bubble, kind, area, inradius, symmetric }
    }

    /// Whether foreground and background bokeh are the same shape.
    pub fn symmetric(&self) -> bool {
        self.symmetric
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

    /// [`Geometry::coverage`] of the shape intersected with the unit circle centred `cut`
    /// (unit frame, y up, before the point reflection: a cat's eye's second circle,
    /// [`CatEye::offset`]); None is the whole shape.
    pub fn coverage_cut(&self, r: f32, x: f32, y: f32, flip: bool, cut: Option<[f32; 2]>) -> f32 {
        if r < POINT_COC_PX {
            return if x == 0.0 && y == 0.0 { 1.0 } else { 0.0 };
        }
        let (x, y) = if flip { (-x, -y) } else { (x, y) };
        if let Some([vx, vy]) = cut
            && self.bubble == 0.0
        {
            // Well inside both outlines (the cut circle is 1 − |v| from the centre at its
            // nearest): no clipping, most of a large bokeh's pixels.
            let inner = self.inradius.min(1.0 - ((vx * vx + vy * vy) as f64).sqrt()) * r as f64;
            let (x, y, r) = (x as f64, y as f64, r as f64);
            if (x * x + y * y).sqrt() + std::f64::consts::SQRT_2 < inner {
                return 1.0;
            }
            // Wholly outside the cut circle: most of the window off axis.
            let (dx, dy) = (x - vx as f64 * r, y - vy as f64 * r);
            if (dx * dx + dy * dy).sqrt() - std::f64::consts::SQRT_2 > r {
                return 0.0;
            }
        }
        let cut = cut.map(|v| [v[0] as f64, v[1] as f64]);
        match self.square_area(r, x, y, 1.0, cut) {
            Area::Inside if self.bubble == 0.0 => return 1.0,
            Area::Part(0.0) => return 0.0,
            _ => {}
        }
        // A cat's eye's cut shape is clipped by two polygons per offset and built into a
        // template per source class: 2 × 2 offsets (the tiling, hence the flux, stays exact;
        // the outline's half-maximum stays on it: tests/aperture.rs).
        let n = if cut.is_some() { 2 } else { 4 };
        let mut acc = 0f64;
        for i in 0..n {
            for j in 0..n {
                let (ox, oy) = ((i as f32 + 0.5) / n as f32 - 0.5, (j as f32 + 0.5) / n as f32 - 0.5);
                let area = match self.square_area(r, x + ox, y + oy, 0.5, cut) {
                    Area::Inside => 1.0,
                    Area::Part(a) => a * r as f64 * r as f64,
                };
                // A bubble's intensity at the small square's centre (midpoint rule).
                acc += if self.bubble == 0.0 || area == 0.0 { area } else { area * self.intensity((x + ox) / r, (y + oy) / r) as f64 };
            }
        }
        // A bubble's rim (or centre) is brighter than 1.
        ((acc / (n * n) as f64) as f32).clamp(0.0, 1.0 + self.bubble.abs())
    }

    /// The bubble profile's intensity at the unit-frame point `(x, y)` (y up, not reflected):
    /// `1 + B·(2t² − 1)` where `t` is the point's relative radius, the scale of the outline
    /// through it (the polygon's gauge, `max n·p / c` over its edges; for an image, the
    /// distance from the centre). 1 without a bubble.
    pub fn intensity(&self, x: f32, y: f32) -> f32 {
        if self.bubble == 0.0 {
            return 1.0;
        }
        let (x, y) = (x as f64, y as f64);
        let t = match &self.kind {
            Kind::Polygon { planes, sectors, .. } => {
                sectors.planes(planes, [x, x, y, y]).map(|&[nx, ny, c]| (nx * x + ny * y) / c).fold(0.0, f64::max)
            }
            Kind::Mask(_) => (x * x + y * y).sqrt(),
        };
        profile(self.bubble, t) as f32
    }

    /// The unit-frame area of the shape (circumradius `r` px), cut by the unit circle centred
    /// `cut` if any, inside the square of half-side `half` px centred `(x, y)` px from the
    /// source (y up, not reflected). O(1) inside and outside the shape, O(vertices) on its
    /// outline.
    fn square_area(&self, r: f32, x: f32, y: f32, half: f32, cut: Option<[f64; 2]>) -> Area {
        let s = 1.0 / r as f64;
        let (x, y, h) = (x as f64, y as f64, half as f64);
        let rect = [(x - h) * s, (x + h) * s, (y - h) * s, (y + h) * s];
        match (&self.kind, cut) {
            (Kind::Polygon { planes, bbox, radii, sectors, .. }, None) => polygon_rect_area(planes, bbox, *radii, sectors, rect),
            (Kind::Polygon { planes, bbox, radii, sectors, .. }, Some(v)) => {
                let [x0, x1, y0, y1] = rect;
                let mut poly: Poly = smallvec::smallvec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
                let mut next = Poly::new();
                let a = clip_convex(planes, bbox, *radii, sectors, [0.0; 2], rect, &mut poly, &mut next);
                if a == Clip::Empty {
                    return Area::Part(0.0);
                }
                let Kind::Polygon { planes, bbox, radii, sectors, .. } = unit_circle() else { unreachable!("a polygon") };
                match (a, clip_convex(planes, bbox, *radii, sectors, v, rect, &mut poly, &mut next)) {
                    (_, Clip::Empty) => Area::Part(0.0),
                    (Clip::Untouched, Clip::Untouched) => Area::Inside,
                    _ => Area::Part(shoelace(&poly).max(0.0)),
                }
            }
            // A cat's eye is refused for images (`Aperture::with_cat_eye`).
            (Kind::Mask(m), _) => m.integral(rect),
        }
    }

    /// The norm of a cut shape: its area inside the circle of radius `radius` centred `centre`
    /// (unit frame, y up; [`CatEye::norm_disc`]) times `r²`; 1 below [`POINT_COC_PX`]. With
    /// the cut's own circle (radius 1) it is the lattice sum of [`Geometry::coverage_cut`]'s
    /// weights. O(vertices · 256).
    pub fn norm_cut(&self, r: f32, (centre, radius): ([f32; 2], f32)) -> f32 {
        if r < POINT_COC_PX {
            return 1.0;
        }
        (self.area_cut([centre[0] as f64, centre[1] as f64], radius as f64) * r as f64 * r as f64) as f32
    }

    /// The unit-frame area of the shape intersected with the circle of radius `radius` centred
    /// `v`.
    fn area_cut(&self, v: [f64; 2], radius: f64) -> f64 {
        let Kind::Polygon { pts, .. } = &self.kind else { return self.area };
        let Kind::Polygon { planes, .. } = unit_circle() else { unreachable!("a polygon") };
        let (mut poly, mut next) = (pts.clone(), Vec::with_capacity(pts.len() + 8));
        for &[nx, ny, c] in planes {
            let c = c * radius + nx * v[0] + ny * v[1];
            if poly.iter().all(|p| nx * p[0] + ny * p[1] <= c) {
                continue;
            }
            next.clear();
            clip_half_plane(&poly, [nx, ny, c], &mut next);
            std::mem::swap(&mut poly, &mut next);
            if poly.len() < 3 {
                return 0.0;
            }
        }
        shoelace(&poly).max(0.0)
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

/// The unit circle as a polygon (a cat's eye's second circle), built once.
fn unit_circle() -> &'static Kind {
    static CIRCLE: std::sync::OnceLock<Kind> = std::sync::OnceLock::new();
    CIRCLE.get_or_init(|| Kind::polygon(circle(CURVE_VERTICES)))
}

/// Optical vignetting over one frame (`Aperture::with_cat_eye`): where each source's second
/// circle sits.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CatEye {
    strength: f32,
    /// The frame's centre, pixels (column, row of pixel centres).
    cx: f32,
    cy: f32,
    /// 1 / the half-diagonal, per pixel.
    inv_reach: f32,
}

impl CatEye {
    /// The cat's eye of strength `strength` over a `width × height` frame.
    pub fn new(strength: f32, width: usize, height: usize) -> CatEye {
        let (w, h) = (width as f32, height as f32);
        let reach = 0.5 * (w * w + h * h).sqrt();
        CatEye { strength, cx: (w - 1.0) / 2.0, cy: (h - 1.0) / 2.0, inv_reach: 1.0 / reach.max(0.5) }
    }

    /// The circle (centre, radius; unit frame) whose area of the shape normalizes a source
    /// whose cut is centred `v`, of CoC `r` px, in front of the focal plane when `front`.
    ///
    /// The cut moves with the source, so the sources that reach one pixel of a surface at one
    /// CoC are those whose offsets lie in the shape and in the cut circle scaled by
    /// `1 / (1 − k)` (behind; `1 / (1 + k)` in front, reflected) about the pixel's own cut,
    /// `k = strength · r / half-diagonal`: normalizing each source by the shape's area inside
    /// that circle rather than inside its own cut keeps an opaque surface opaque and a uniform
    /// one uniform (to second order), as a lens's pupil does, where unit flux per source would
    /// make them `1 ± k`-ish (k reaches 0.2 on the bench's 128 px frames). Each source's light
    /// is then its cut's area over that circle's.
    ///
    /// The pixels a source reaches see cuts moved by `k` times their offset from it, about
    /// `v·r/2` on average (the cut shape's centroid, reflected in front): the circle is taken
    /// about `v·(1 ∓ k/2)`, which cancels that first-order term as well.
    pub fn norm_disc(&self, v: [f32; 2], r: f32, front: bool) -> ([f32; 2], f32) {
        let k = (self.strength * r * self.inv_reach).min(0.9);
        let (scale, shift) = if front { (1.0 / (1.0 + k), 1.0 + 0.5 * k) } else { (1.0 / (1.0 - k), 1.0 - 0.5 * k) };
        ([v[0] * shift * scale, v[1] * shift * scale], scale)
    }

    /// The strength: how far (unit frame) the second circle moves at the corners.
    pub fn strength(&self) -> f32 {
        self.strength
    }

    /// The centre of the second circle (unit frame: circumradius 1, y up) for a source at
    /// pixel `(x, y)` (column, row; may lie outside the frame): toward the frame's centre,
    /// the strength times the source's distance from the centre over the half-diagonal (1 at
    /// most, so the cut shape always holds the source's own point).
    #[inline]
    pub fn offset(&self, x: f32, y: f32) -> [f32; 2] {
        let (ux, uy) = ((x - self.cx) * self.inv_reach, (self.cy - y) * self.inv_reach);
        let n = (ux * ux + uy * uy).sqrt();
        let k = if n > 1.0 { self.strength / n } else { self.strength };
        [-ux * k, -uy * k]
    }
}

/// What a pixel's rectangle covers of a shape (unit frame areas).
enum Area {
    /// Wholly inside (coverage exactly 1).
    Inside,
    /// This much area.
    Part(f64),
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

/// A unit circle as a counterclockwise polygon of `n` vertices.
fn circle(n: usize) -> Vec<[f64; 2]> {
    (0..n).map(|k| 2.0 * PI * k as f64 / n as f64).map(|t| [t.cos(), t.sin()]).collect()
}

/// `n` blades, a vertex at `rotation` degrees, curvature `c`: the outline's radius at angle
/// θ is `(1 - c)·polygon(θ) + c` (straight sides at 0, the circle at 1), polygonized with
/// [`CURVE_VERTICES`] vertices (the corners kept exactly) when curved.
fn blades(n: u32, rotation: f64, c: f64) -> Vec<[f64; 2]> {
    let rot = rotation.to_radians();
    let step = 2.0 * PI / n as f64;
    if c == 0.0 {
        return (0..n).map(|k| rot + step * k as f64).map(|t| [t.cos(), t.sin()]).collect();
    }
    let per_side = CURVE_VERTICES.div_ceil(n as usize).max(4);
    let apothem = (PI / n as f64).cos();
    let mut pts = Vec::with_capacity(n as usize * per_side);
    for k in 0..n {
        for i in 0..per_side {
            let u = i as f64 / per_side as f64;
            let t = step * u;
            let polygon = apothem / (t - step / 2.0).cos();
            let radius = (1.0 - c) * polygon + c;
            let a = rot + step * k as f64 + t;
            pts.push([radius * a.cos(), radius * a.sin()]);
        }
    }
    pts
}

/// Area of a polygon given counterclockwise.
fn shoelace(pts: &[[f64; 2]]) -> f64 {
    let n = pts.len();
    0.5 * (0..n).map(|i| pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1]).sum::<f64>()
}

/// Area of `rect = [x0, x1, y0, y1]` inside the convex polygon of half-planes `planes`: the
/// rectangle clipped by each plane that cuts it (most pixels meet none or one edge).
fn polygon_rect_area(planes: &[[f64; 3]], bbox: &[f64; 4], radii: [f64; 2], sectors: &Sectors, rect: [f64; 4]) -> Area {
    let [x0, x1, y0, y1] = rect;
    let mut poly: Poly = smallvec::smallvec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
    let mut next = Poly::new();
    match clip_convex(planes, bbox, radii, sectors, [0.0; 2], rect, &mut poly, &mut next) {
        Clip::Empty => Area::Part(0.0),
        Clip::Untouched => Area::Inside,
        Clip::Cut => Area::Part(shoelace(&poly).max(0.0)),
    }
}

/// Appends to `out` the convex polygon `poly` clipped to the half-plane `n·p ≤ c`
/// (Sutherland–Hodgman, one plane).
fn clip_half_plane(poly: &[[f64; 2]], [nx, ny, c]: [f64; 3], out: &mut impl Extend<[f64; 2]>) {
    let m = poly.len();
    for i in 0..m {
        let (a, b) = (poly[i], poly[(i + 1) % m]);
        let (da, db) = (nx * a[0] + ny * a[1] - c, nx * b[0] + ny * b[1] - c);
        if da <= 0.0 {
            out.extend([a]);
        }
        if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
            let t = da / (da - db);
            out.extend([[a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]]);
        }
    }
}

/// A small polygon on the stack (a rectangle clipped by a few planes).
type Poly = SmallVec<[[f64; 2]; 12]>;

/// What [`clip_convex`] did.
#[derive(Clone, Copy, PartialEq, Debug)]
enum Clip {
    /// Nothing is left.
    Empty,
    /// The polygon lies inside: unchanged.
    Untouched,
    /// Clipped (possibly to nothing: check its area).
    Cut,
}

/// Clips `poly`, which lies inside `rect` (both in the frame whose origin is the shape's
/// centre), to the convex polygon of half-planes `planes` (with its bounding box, inscribed
/// and circumscribed radii and sectors, in its own frame) centred at `shift`. `next` is
/// scratch.
#[allow(clippy::too_many_arguments)]
fn clip_convex(
    planes: &[[f64; 3]],
    bbox: &[f64; 4],
    [inner, outer]: [f64; 2],
    sectors: &Sectors,
    shift: [f64; 2],
    rect: [f64; 4],
    poly: &mut Poly,
    next: &mut Poly,
) -> Clip {
    // The rectangle in the polygon's own frame.
    let [x0, x1, y0, y1] = [rect[0] - shift[0], rect[1] - shift[0], rect[2] - shift[1], rect[3] - shift[1]];
    if x1 <= bbox[0] || x0 >= bbox[1] || y1 <= bbox[2] || y0 >= bbox[3] {
        return Clip::Empty;
    }
    // The rectangle's farthest and nearest points from the centre.
    let far = |a: f64, b: f64| a.abs().max(b.abs());
    let near = |a: f64, b: f64| if a <= 0.0 && b >= 0.0 { 0.0 } else { a.abs().min(b.abs()) };
    let (fx, fy, nx, ny) = (far(x0, x1), far(y0, y1), near(x0, x1), near(y0, y1));
    if fx * fx + fy * fy < inner * inner * (1.0 - 1e-12) {
        return Clip::Untouched;
    }
    if nx * nx + ny * ny >= outer * outer {
        return Clip::Empty;
    }
    let mut cut = false;
    // Within the cone from the centre that holds the rectangle, the polygon is bounded by the
    // edges of that cone's angles alone (it is convex around the centre).
    for &[nx, ny, c] in sectors.planes(planes, [x0, x1, y0, y1]) {
        // The rectangle's corner farthest along n, and the nearest.
        let far = nx * if nx > 0.0 { x1 } else { x0 } + ny * if ny > 0.0 { y1 } else { y0 };
        if far <= c {
            continue;
        }
        let near = nx * if nx > 0.0 { x0 } else { x1 } + ny * if ny > 0.0 { y0 } else { y1 };
        if near >= c {
            return Clip::Empty;
        }
        // In the shape's frame: n·p ≤ c + n·shift.
        cut = true;
        next.clear();
        clip_half_plane(poly, [nx, ny, c + nx * shift[0] + ny * shift[1]], next);
        std::mem::swap(poly, next);
        if poly.len() < 3 {
            return Clip::Empty;
        }
    }
    if cut { Clip::Cut } else { Clip::Untouched }
}

/// A many-sided polygon's edges by angle from the centre: which planes can bound it inside a
/// cone (see [`polygon_rect_area`]). Few-sided polygons keep every plane.
#[derive(Debug, PartialEq)]
struct Sectors {
    /// Per sector of `2π / SECTORS`, the first and one-past-last edge (cyclic) whose angular
    /// span meets it; empty for polygons of at most `ALL_BELOW` edges.
    ranges: Vec<(usize, usize)>,
}

impl Sectors {
    const COUNT: usize = 64;
    const ALL_BELOW: usize = 16;

    fn new(pts: &[[f64; 2]]) -> Sectors {
        let n = pts.len();
        if n <= Self::ALL_BELOW {
            return Sectors { ranges: Vec::new() };
        }
        let sector = |a: f64| (((a.rem_euclid(2.0 * PI)) / (2.0 * PI) * Self::COUNT as f64) as usize).min(Self::COUNT - 1);
        let mut ranges = vec![(usize::MAX, 0usize); Self::COUNT];
        for k in 0..n {
            let (a, b) = (pts[k], pts[(k + 1) % n]);
            let (sa, sb) = (sector(a[1].atan2(a[0])), sector(b[1].atan2(b[0])));
            // The edge's sectors, counterclockwise from a's to b's.
            let mut s = sa;
            loop {
                let r = &mut ranges[s];
                // Edges arrive in order: a sector's edges are consecutive (cyclically).
                if r.0 == usize::MAX {
                    *r = (k, k + 1);
                } else {
                    r.1 = k + 1;
                }
                if s == sb {
                    break;
                }
                s = (s + 1) % Self::COUNT;
            }
        }
        Sectors { ranges }
    }

    /// The planes that can bound the polygon inside the cone holding `rect`: every plane when
    /// the rectangle holds the centre or spans more than a quarter turn.
    fn planes<'a>(&self, planes: &'a [[f64; 3]], [x0, x1, y0, y1]: [f64; 4]) -> impl Iterator<Item = &'a [f64; 3]> + 'a {
        let all = || (0..planes.len(), 0..0);
        let (first, wrap) = if self.ranges.is_empty() || (x0 <= 0.0 && x1 >= 0.0 && y0 <= 0.0 && y1 >= 0.0) {
            all()
        } else {
            // The rectangle's corners' angles, unwrapped around its centre's.
            let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
            let mid = cy.atan2(cx);
            let rel = |x: f64, y: f64| {
                let d = y.atan2(x) - mid;
                d - (2.0 * PI) * (d / (2.0 * PI)).round()
            };
            let corners = [rel(x0, y0), rel(x1, y0), rel(x1, y1), rel(x0, y1)];
            let (lo, hi) =
                (corners.iter().copied().fold(f64::INFINITY, f64::min), corners.iter().copied().fold(f64::NEG_INFINITY, f64::max));
            if hi - lo > 0.5 * PI {
                all()
            } else {
                let n = planes.len();
                let count = Self::COUNT as f64;
                let (s0, s1) = (((mid + lo) / (2.0 * PI) * count).floor() as i64, ((mid + hi) / (2.0 * PI) * count).floor() as i64);
                let at = |s: i64| self.ranges[s.rem_euclid(Self::COUNT as i64) as usize];
                // Edges from the first sector's first to the last sector's last, cyclically.
                let (a, b) = (at(s0).0, at(s1).1);
                let b = if b <= a { b + n } else { b };
                if b - a >= n {
                    all()
                } else if b <= n {
                    (a..b, 0..0)
                } else {
                    (a..n, 0..b - n)
                }
            }
        };
        planes[first].iter().chain(planes[wrap].iter())
    }
}

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
        let table = |f: &dyn Fn(f32) -> f64| {
            let mut sat = vec![0f64; (w + 1) * (h + 1)];
            for y in 0..h {
                let mut row = 0f64;
                for x in 0..w {
                    row += f(values[y * w + x]);
                    sat[(y + 1) * (w + 1) + x + 1] = sat[y * (w + 1) + x + 1] + row;
                }
            }
            sat
        };
        let side = w.max(h) as f64;
        Ok(Mask { w, h, hw: w as f64 / side, hh: h as f64 / side, sat: table(&|v| v as f64), holes: table(&|v| 1.0 - v as f64), values })
    }

    /// The sum of the values times `f` at each cell's centre (unit frame).
    fn weighted_total(&self, f: impl Fn(f64, f64) -> f64) -> f64 {
        let mut sum = 0.0;
        for row in 0..self.h {
            for col in 0..self.w {
                let x = -self.hw + (col as f64 + 0.5) * 2.0 * self.hw / self.w as f64;
                let y = self.hh - (row as f64 + 0.5) * 2.0 * self.hh / self.h as f64;
                sum += self.values[row * self.w + col] as f64 * f(x, y);
            }
        }
        sum
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
        let (i, j) = ((u.floor() as usize).min(self.w - 1), (v.floor() as usize).min(self.h - 1));
        let (fu, fv) = (u - i as f64, v - j as f64);
        let at = |a: usize, b: usize| t[b * (self.w + 1) + a];
        let top = at(i, j) * (1.0 - fu) + at(i + 1, j) * fu;
        let bottom = at(i, j + 1) * (1.0 - fu) + at(i + 1, j + 1) * fu;
        top * (1.0 - fv) + bottom * fv
    }

    /// The mask's integral over the unit-frame rectangle `rect`, in unit-frame area.
    fn integral(&self, [x0, x1, y0, y1]: [f64; 4]) -> Area {
        if x1 <= -self.hw || x0 >= self.hw || y1 <= -self.hh || y0 >= self.hh {
            return Area::Part(0.0);
        }
        // Cells per unit along each axis; rows run down.
        let (ku, kv) = (self.w as f64 / (2.0 * self.hw), self.h as f64 / (2.0 * self.hh));
        let (u0, u1) = ((x0 + self.hw) * ku, (x1 + self.hw) * ku);
        let (v0, v1) = ((self.hh - y1) * kv, (self.hh - y0) * kv);
        let sum = |t: &[f64]| self.sat_at(t, u1, v1) - self.sat_at(t, u0, v1) - self.sat_at(t, u1, v0) + self.sat_at(t, u0, v0);
        let inside_frame = x0 >= -self.hw && x1 <= self.hw && y0 >= -self.hh && y1 <= self.hh;
        if inside_frame && sum(&self.holes) == 0.0 {
            return Area::Inside;
        }
        Area::Part(sum(&self.sat).max(0.0) / (ku * kv))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn aperture(spec: &str, anamorphic: f32) -> &'static Geometry {
        Aperture::new(&ShapeSpec::parse(spec, "--aperture").unwrap(), anamorphic, "--aperture").unwrap().geometry().unwrap()
    }

    /// The weight of a pixel by supersampling the outline under the tent of the two pixel
    /// squares (an independent truth): `n × n` points over the 2 × 2 px around the centre.
    fn supersampled(inside: impl Fn(f64, f64) -> bool, r: f64, x: f64, y: f64, n: usize) -> f64 {
        supersampled_grey(|u, v| inside(u, v) as u8 as f64, r, x, y, n)
    }

    /// [`supersampled`] of a transmission in [0, 1].
    fn supersampled_grey(t: impl Fn(f64, f64) -> f64, r: f64, x: f64, y: f64, n: usize) -> f64 {
        let mut acc = 0.0;
        for i in 0..n {
            for j in 0..n {
                let (u, v) = (-1.0 + 2.0 * (i as f64 + 0.5) / n as f64, -1.0 + 2.0 * (j as f64 + 0.5) / n as f64);
                acc += t((x + u) / r, (y + v) / r) * (1.0 - u.abs()) * (1.0 - v.abs());
            }
        }
        acc * 4.0 / (n * n) as f64
    }

    fn in_hexagon(x: f64, y: f64, rot: f64) -> bool {
        (0..6).all(|k| {
            let t = (rot + 60.0 * k as f64 + 30.0).to_radians();
            x * t.cos() + y * t.sin() <= (PI / 6.0).cos()
        })
    }

    #[test]
    fn parse_and_reject() {
        assert_eq!(ShapeSpec::parse("disc", "a").unwrap(), ShapeSpec::Disc);
        assert_eq!(
            ShapeSpec::parse("blades:6,rotation=30,curvature=0.5", "a").unwrap(),
            ShapeSpec::Blades { n: 6, rotation: 30.0, curvature: 0.5 }
        );
        for bad in [
            "blades:2",
            "blades:65",
            "blades:6,curvature=1.5",
            "blades:6,curvature=-0.1",
            "blades:x",
            "blades:6,rotation=nan",
            "hexagon",
            "image:",
            "blades:6,size=2",
        ] {
            let e = ShapeSpec::parse(bad, "--aperture").unwrap_err().to_string();
            assert!(e.contains("--aperture"), "{bad}: {e}");
        }
        assert!(Aperture::new(&ShapeSpec::Disc, 0.0, "a").is_err());
        assert!(Aperture::new(&ShapeSpec::Disc, f32::NAN, "a").is_err());
        assert!(Aperture::new(&ShapeSpec::Disc, 1.0, "a").unwrap().is_disc());
    }

    #[test]
    fn masks_that_pass_no_light_or_are_too_large_are_refused() {
        assert!(Aperture::from_mask(0, 0, &[], 1.0, "m").is_err());
        assert!(Aperture::from_mask(2, 2, &[0.0; 4], 1.0, "m").unwrap_err().to_string().contains("all black"));
        assert!(Aperture::from_mask(2, 1, &[1.0, f32::NAN], 1.0, "m").unwrap_err().to_string().contains("not finite"));
        assert!(Aperture::from_mask(1025, 1, &[1.0; 1025], 1.0, "m").is_err());
    }

    #[test]
    fn cat_eye_cuts_toward_the_frame_centre() {
        // The offset points at the centre (y up), in proportion to the distance, at most the
        // strength; the centre itself is uncut.
        let c = CatEye::new(0.8, 101, 51);
        assert_eq!(c.offset(50.0, 25.0), [0.0, 0.0]);
        let reach = 0.5 * (101.0f32 * 101.0 + 51.0 * 51.0).sqrt();
        let [vx, vy] = c.offset(0.0, 0.0);
        assert!((vx - 0.8 * 50.0 / reach).abs() < 1e-6 && (vy + 0.8 * 25.0 / reach).abs() < 1e-6, "{vx} {vy}");
        let far = c.offset(1e6, 25.0);
        assert!((far[0] + 0.8).abs() < 1e-6 && far[1] == 0.0);
        // The cut's area is the two discs' lens: 2·acos(d/2) − (d/2)·sqrt(4 − d²).
        let disc = Aperture::DISC.with_cat_eye(1.0).unwrap();
        let g = disc.geometry().unwrap();
        for d in [0.0f64, 0.3, 0.7, 1.0] {
            let want = 2.0 * (d / 2.0).acos() - d / 2.0 * (4.0 - d * d).sqrt();
            let got = g.norm_cut(1.0, ([0.0, -d as f32], 1.0)) as f64;
            assert!((got - want).abs() < 2e-3 * want, "d {d}: {got} vs {want}");
            // Coverages tile: their lattice sum is the area (the source's unit flux).
            let r = 7.5f32;
            let sum: f64 = (-10..=10)
                .flat_map(|y| (-10..=10).map(move |x| (x, y)))
                .map(|(x, y)| g.coverage_cut(r, x as f32, y as f32, false, Some([0.0, -d as f32])) as f64)
                .sum();
            assert!((sum - g.norm_cut(r, ([0.0, -d as f32], 1.0)) as f64).abs() < 1e-3 * sum, "d {d}: lattice {sum}");
        }
        // Refused: out of range, an image aperture, a bubble.
        assert!(Aperture::DISC.with_cat_eye(1.5).is_err() && Aperture::DISC.with_cat_eye(f32::NAN).is_err());
        assert!(Aperture::from_mask(2, 2, &[1.0; 4], 1.0, "m").unwrap().with_cat_eye(0.5).is_err());
        assert!(Aperture::with_bubble(&ShapeSpec::Disc, 1.0, 0.5, "b").unwrap().with_cat_eye(0.5).is_err());
        assert_eq!(disc.label(), "disc,cat_eye=1");
        assert!(Aperture::DISC.with_cat_eye(0.0).unwrap().is_disc());
    }

    #[test]
    fn geometries_are_interned() {
        let a = Aperture::new(&ShapeSpec::parse("blades:7,rotation=10", "a").unwrap(), 1.0, "a").unwrap();
        let b = Aperture::new(&ShapeSpec::parse("blades:7,rotation=10", "a").unwrap(), 1.0, "a").unwrap();
        let c = Aperture::new(&ShapeSpec::parse("blades:7,rotation=11", "a").unwrap(), 1.0, "a").unwrap();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, Aperture::DISC);
    }

    /// An image file is read once per version: asking again gives the same handle; another
    /// squeeze or another version of the file gives another shape; a removed file is an error
    /// naming it (the cache is keyed by the live file's metadata).
    #[test]
    fn image_files_are_read_once_per_version() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("mask.png");
        let disc = |n: usize, r: f32| {
            let c = (n as f32 - 1.0) / 2.0;
            let v = (0..n * n).map(|i| if ((i % n) as f32 - c).hypot((i / n) as f32 - c) <= r { 1.0 } else { 0.0 }).collect();
            crate::image::Image::from_vec(n, n, 1, v).unwrap()
        };
        crate::io::write_png(&path, &disc(16, 7.0), 8, crate::color::Transfer::Linear).unwrap();
        let spec = ShapeSpec::parse(&format!("image:{}", path.display()), "a").unwrap();
        let a = Aperture::new(&spec, 1.0, "a").unwrap();
        assert_eq!(Aperture::new(&spec, 1.0, "a").unwrap(), a);
        assert_ne!(Aperture::new(&spec, 1.5, "a").unwrap(), a);
        crate::io::write_png(&path, &disc(20, 5.0), 8, crate::color::Transfer::Linear).unwrap();
        let b = Aperture::new(&spec, 1.0, "a").unwrap();
        assert_ne!(a, b, "a rewritten mask must be read again");
        std::fs::remove_file(&path).unwrap();
        let e = Aperture::new(&spec, 1.0, "a").unwrap_err().to_string();
        assert!(e.contains("mask.png"), "{e}");
    }

    #[test]
    fn hexagon_coverage_is_the_pixel_area_inside_it() {
        for rot in [0.0, 30.0, 17.0] {
            let g = aperture(&format!("blades:6,rotation={rot}"), 1.0);
            let r = 6.3f32;
            let mut worst = 0f64;
            let mut sum = 0f64;
            for y in -8..=8 {
                for x in -8..=8 {
                    let c = g.coverage(r, x as f32, y as f32, false) as f64;
                    sum += c;
                    let truth = supersampled(|u, v| in_hexagon(u, v, rot), r as f64, x as f64, y as f64, 64);
                    worst = worst.max((c - truth).abs());
                }
            }
            // Supersampling's own error on an edge pixel is about 1/64.
            assert!(worst < 0.02, "rotation {rot}: worst {worst}");
            assert!((sum / g.norm(r) as f64 - 1.0).abs() < 1e-5, "rotation {rot}: flux {sum}");
        }
    }

    #[test]
    fn rounded_blades_coverage_is_the_supersampled_outline() {
        // 256 edges: the planes are picked by sector.
        let g = aperture("blades:7,rotation=10,curvature=0.6", 1.0);
        let inside = |x: f64, y: f64| {
            let (r, a) = ((x * x + y * y).sqrt(), (y.atan2(x) - 10f64.to_radians()).rem_euclid(2.0 * PI / 7.0));
            r <= 0.4 * (PI / 7.0).cos() / (a - PI / 7.0).cos() + 0.6
        };
        for r in [2.3f32, 9.7] {
            let mut worst = 0f64;
            for y in -12..=12 {
                for x in -12..=12 {
                    let c = g.coverage(r, x as f32, y as f32, false) as f64;
                    worst = worst.max((c - supersampled(inside, r as f64, x as f64, y as f64, 64)).abs());
                }
            }
            assert!(worst < 0.03, "r {r}: worst {worst}");
        }
    }

    #[test]
    fn a_vertex_points_at_the_rotation() {
        let g = aperture("blades:5,rotation=90", 1.0);
        let r = 20.0;
        // Straight up (y up) the vertex reaches r; straight down an edge stops at the apothem.
        assert!(g.coverage(r, 0.0, 19.0, false) > 0.0);
        assert_eq!(g.coverage(r, 0.0, -18.0, false), 0.0);
        // In front of the focal plane the pentagon is point-reflected.
        assert_eq!(g.coverage(r, 0.0, 18.0, true), 0.0);
        assert!(g.coverage(r, 0.0, -19.0, true) > 0.0);
        assert!(!g.symmetric());
        assert!(aperture("blades:6", 1.0).symmetric());
    }

    #[test]
    fn curvature_runs_from_the_polygon_to_the_circle() {
        let area = |c: f32| aperture(&format!("blades:5,curvature={c}"), 1.0).area;
        let pentagon = 2.5 * (2.0 * PI / 5.0).sin();
        assert!((area(0.0) - pentagon).abs() < 1e-9);
        assert!((area(1.0) - PI).abs() < 1e-3);
        assert!(area(0.0) < area(0.5) && area(0.5) < area(1.0));
        // The rounded outline stays convex: every vertex inside every edge's half-plane.
        let g = aperture("blades:5,curvature=0.5", 1.0);
        let Kind::Polygon { pts, planes, .. } = &g.kind else { panic!() };
        assert!(planes.iter().all(|&[nx, ny, c]| pts.iter().all(|p| nx * p[0] + ny * p[1] <= c + 1e-9)));
    }

    #[test]
    fn anamorphic_disc_is_an_ellipse_inside_the_coc() {
        let g = aperture("disc", 1.5);
        assert!((g.area - PI / 1.5).abs() < 1e-3);
        let r = 10.0;
        assert!(g.coverage(r, 0.0, 9.0, false) > 0.99);
        assert_eq!(g.coverage(r, 9.0, 0.0, false), 0.0);
        assert_eq!(g.coverage(r, 5.0, 0.0, false), 1.0);
    }

    #[test]
    fn mask_coverage_integrates_the_image() {
        // A 4x4 mask, open in its left half and its top-right cell half.
        let mut v = vec![0f32; 16];
        for y in 0..4 {
            v[y * 4] = 1.0;
            v[y * 4 + 1] = 1.0;
        }
        v[3] = 0.5;
        let a = Aperture::from_mask(4, 4, &v, 1.0, "m").unwrap().geometry().unwrap();
        assert!((a.area - (8.5 * 0.25)).abs() < 1e-12);
        // The grey value of the cell under a unit-frame point (rows down).
        let cell = |x: f64, y: f64, flip: bool| {
            let (x, y) = if flip { (-x, -y) } else { (x, y) };
            let (cx, cy) = ((x + 1.0) * 2.0, (1.0 - y) * 2.0);
            if !(0.0..4.0).contains(&cx) || !(0.0..4.0).contains(&cy) {
                return 0.0;
            }
            v[cy as usize * 4 + cx as usize] as f64
        };
        let r = 8.0;
        let mut worst = 0f64;
        for flip in [false, true] {
            for y in -9..=9 {
                for x in -9..=9 {
                    let c = a.coverage(r, x as f32, y as f32, flip) as f64;
                    let truth = supersampled_grey(|u, w| cell(u, w, flip), r as f64, x as f64, y as f64, 96);
                    worst = worst.max((c - truth).abs());
                }
            }
        }
        assert!(worst < 0.03, "worst {worst}");
        // Wholly open 2 x 2 neighbourhoods are exactly 1, wholly closed ones 0.
        assert_eq!(a.coverage(r, -4.0, 4.0, false), 1.0);
        assert_eq!(a.coverage(r, 4.0, -4.0, false), 0.0);
        let sum: f64 =
            (-5..=5).flat_map(|y| (-5..=5).map(move |x| (x, y))).map(|(x, y)| a.coverage(2.7, x as f32, y as f32, false) as f64).sum();
        assert!((sum / a.norm(2.7) as f64 - 1.0).abs() < 1e-5, "{sum}");
    }

    #[test]
    fn the_sample_map_covers_the_polygon_uniformly() {
        let g = aperture("blades:5,rotation=90,curvature=0.3", 1.3);
        let n = 200;
        let mut upper = 0usize;
        for i in 0..n {
            for j in 0..n {
                let (x, y) = g.sample((i as f32 + 0.5) / n as f32, (j as f32 + 0.5) / n as f32).unwrap();
                assert_eq!(g.transmission(x * 0.999, y * 0.999), 1.0, "({x}, {y}) outside");
                upper += (y > 0.2) as usize;
            }
        }
        // The share above y = 0.2 is that of the area (by supersampled coverage).
        let mut above = 0f64;
        for y in 0..400 {
            for x in 0..400 {
                let (px, py) = (-1.0 + (x as f32 + 0.5) / 200.0, -1.0 + (y as f32 + 0.5) / 200.0);
                if py > 0.2 {
                    above += g.transmission(px, py) as f64;
                }
            }
        }
        let want = above / 40000.0 / g.area;
        let got = upper as f64 / (n * n) as f64;
        assert!((got - want).abs() < 0.01, "{got} vs {want}");
        assert!(aperture("blades:6", 1.0).sample(0.3, 0.3).is_some());
    }

    #[test]
    fn small_cocs_tend_continuously_to_the_source_pixel() {
        let g = aperture("blades:6", 2.0);
        assert_eq!(g.norm(0.0005), 1.0);
        assert_eq!(g.coverage(0.0005, 0.0, 0.0, false), 1.0);
        assert_eq!(g.coverage(0.0005, 1.0, 0.0, false), 0.0);
        let weights = |r: f32| -> Vec<f32> {
            (-2..=2)
                .flat_map(|y| (-2..=2).map(move |x| (x, y)))
                .map(|(x, y)| g.coverage(r, x as f32, y as f32, false) / g.norm(r))
                .collect()
        };
        // Unit flux at every radius; the centre's weight falls as the CoC grows.
        let mut last = 1.0f32;
        for r in [0.01f32, 0.1, 0.2, 0.3, 0.5, 0.8] {
            let w = weights(r);
            assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-4, "r {r}: {}", w.iter().sum::<f32>());
            assert!(w[12] <= last + 1e-6, "r {r}: centre {} after {last}", w[12]);
            last = w[12];
        }
        assert!((weights(0.01)[12] - 1.0).abs() < 1e-4 && last < 0.9);
    }
}
