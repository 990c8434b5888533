//! Convex polygons in the aperture's unit frame: the outlines the shapes are made of (a circle,
//! straight or curved blades) and the area of a pixel rectangle inside one (clipped by the
//! polygon's half-planes, with the angular sectors that tell which edges can cut a rectangle).
//! Used by [`super::shape::Geometry`] and the cat's eye's cut.

use smallvec::SmallVec;
use std::f64::consts::PI;

/// Vertices of a polygonized circle, and of a curved-blade outline (spread over its sides).
pub(super) const CURVE_VERTICES: usize = 256;

/// What a pixel's rectangle covers of a shape (unit frame areas).
pub(super) enum Area {
    /// Wholly inside (coverage exactly 1).
    Inside,
    /// This much area.
    Part(f64),
}

/// A unit circle as a counterclockwise polygon of `n` vertices.
pub(super) fn circle(n: usize) -> Vec<[f64; 2]> {
    (0..n).map(|k| 2.0 * PI * k as f64 / n as f64).map(|t| [t.cos(), t.sin()]).collect()
}

/// `n` blades, a vertex at `rotation` degrees, curvature `c`: the outline's radius at angle
/// θ is `(1 - c)·polygon(θ) + c` (straight sides at 0, the circle at 1), polygonized with
/// [`CURVE_VERTICES`] vertices (the corners kept exactly) when curved.
pub(super) fn blades(n: u32, rotation: f64, c: f64) -> Vec<[f64; 2]> {
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

/// A convex polygon's edges (counterclockwise `pts`) as half-planes `n·p ≤ c`, `n` the unit
/// outward normal.
pub(super) fn half_planes(pts: &[[f64; 2]]) -> Vec<[f64; 3]> {
    let n = pts.len();
    (0..n)
        .map(|i| {
            let (a, b) = (pts[i], pts[(i + 1) % n]);
            let (ex, ey) = (b[0] - a[0], b[1] - a[1]);
            let len = (ex * ex + ey * ey).sqrt();
            let (nx, ny) = (ey / len, -ex / len);
            [nx, ny, nx * a[0] + ny * a[1]]
        })
        .collect()
}

/// Area of a polygon given counterclockwise.
pub(super) fn shoelace(pts: &[[f64; 2]]) -> f64 {
    let n = pts.len();
    0.5 * (0..n).map(|i| pts[i][0] * pts[(i + 1) % n][1] - pts[(i + 1) % n][0] * pts[i][1]).sum::<f64>()
}

/// Area of `rect = [x0, x1, y0, y1]` inside the convex polygon of half-planes `planes`: the
/// rectangle clipped by each plane that cuts it (most pixels meet none or one edge).
pub(super) fn polygon_rect_area(planes: &[[f64; 3]], bbox: &[f64; 4], radii: [f64; 2], sectors: &Sectors, rect: [f64; 4]) -> Area {
    let [x0, x1, y0, y1] = rect;
    let mut poly: Poly = smallvec::smallvec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
    let mut next = Poly::new();
    match clip_convex(planes, bbox, radii, sectors, [0.0; 2], rect, &mut poly, &mut next) {
        Clip::Empty => Area::Part(0.0),
        Clip::Untouched => Area::Inside,
        Clip::Cut => Area::Part(shoelace(&poly).max(0.0)),
    }
}

/// Area of the convex polygon `pts` (counterclockwise) inside the circle of radius `radius`
/// centred `centre`: exact, the circle not polygonized (a cat's eye's second circle). O(vertices):
/// the sum over edges of the signed area of the triangle (centre, edge) inside the circle, a
/// triangle where the edge is inside and a circular sector where it is outside.
///
/// Consecutive sectors merge into one (one `atan2` per run instead of per edge: a 256-gon's
/// norm took 5% of a 12 MP cat's-eye render); a run is cut where its next point leaves the
/// half-plane facing its first, so that its angle stays within ±π/2 and `atan2` of its two
/// ends is the angle it sweeps.
pub(super) fn polygon_circle_area(pts: &[[f64; 2]], centre: [f64; 2], radius: f64) -> f64 {
    let n = pts.len();
    let cross = |u: [f64; 2], v: [f64; 2]| u[0] * v[1] - u[1] * v[0];
    let dot = |u: [f64; 2], v: [f64; 2]| u[0] * v[0] + u[1] * v[1];
    let sector = |u: [f64; 2], v: [f64; 2]| 0.5 * radius * radius * cross(u, v).atan2(dot(u, v));
    let rel = |p: [f64; 2]| [p[0] - centre[0], p[1] - centre[1]];
    let mut total = 0.0;
    // The pending run of sectors, from its first point to its last.
    let mut run: Option<([f64; 2], [f64; 2])> = None;
    let arc = |total: &mut f64, run: &mut Option<([f64; 2], [f64; 2])>, from: [f64; 2], to: [f64; 2]| {
        match *run {
            Some((first, _)) if dot(first, to) > 0.0 => {
                *run = Some((first, to));
                return;
            }
            Some((first, last)) => *total += sector(first, last),
            None => {}
        }
        // A new run from `from`, kept open only while its points face `from`; else this
        // sector alone (one edge sweeps less than π).
        if dot(from, to) > 0.0 {
            *run = Some((from, to));
        } else {
            *total += sector(from, to);
            *run = None;
        }
    };
    let flush = |total: &mut f64, run: &mut Option<([f64; 2], [f64; 2])>| {
        if let Some((first, last)) = run.take() {
            *total += sector(first, last);
        }
    };
    for i in 0..n {
        let (a, b) = (rel(pts[i]), rel(pts[(i + 1) % n]));
        let d = [b[0] - a[0], b[1] - a[1]];
        let dd = dot(d, d);
        if dd == 0.0 {
            continue;
        }
        // |a + t·d|² = radius²: t = (-a·d ± √disc) / dd.
        let ad = dot(a, d);
        let disc = ad * ad - dd * (dot(a, a) - radius * radius);
        let root = disc.max(0.0).sqrt();
        let (t0, t1) = ((-ad - root) / dd, (-ad + root) / dd);
        if disc <= 0.0 || t1 <= 0.0 || t0 >= 1.0 {
            arc(&mut total, &mut run, a, b);
            continue;
        }
        let at = |t: f64| [a[0] + t * d[0], a[1] + t * d[1]];
        let (p, q) = (at(t0.max(0.0)), at(t1.min(1.0)));
        if t0 > 0.0 {
            arc(&mut total, &mut run, a, p);
        }
        flush(&mut total, &mut run);
        total += 0.5 * cross(p, q);
        if t1 < 1.0 {
            arc(&mut total, &mut run, q, b);
        }
    }
    flush(&mut total, &mut run);
    total.max(0.0)
}

/// Appends to `out` the convex polygon `poly` clipped to the half-plane `n·p ≤ c`
/// (Sutherland–Hodgman, one plane).
pub(super) fn clip_half_plane(poly: &[[f64; 2]], [nx, ny, c]: [f64; 3], out: &mut impl PushPoint) {
    let m = poly.len();
    for i in 0..m {
        let (a, b) = (poly[i], poly[(i + 1) % m]);
        let (da, db) = (nx * a[0] + ny * a[1] - c, nx * b[0] + ny * b[1] - c);
        if da <= 0.0 {
            out.push_point(a);
        }
        if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
            let t = da / (da - db);
            out.push_point([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])]);
        }
    }
}

/// A growable list of points: what [`clip_half_plane`] writes to, one point at a time
/// (`Extend` with a one-element array went through a reserve per point).
pub(super) trait PushPoint {
    fn push_point(&mut self, p: [f64; 2]);
}

impl PushPoint for Vec<[f64; 2]> {
    #[inline]
    fn push_point(&mut self, p: [f64; 2]) {
        self.push(p);
    }
}

impl PushPoint for Poly {
    #[inline]
    fn push_point(&mut self, p: [f64; 2]) {
        self.push(p);
    }
}

/// A small polygon on the stack: a rectangle clipped by a few planes, or by the run of a
/// curved outline's edges (256 vertices) that crosses it (with room for 12 these spilled to
/// the heap: the bundled example at `--blur 4 --bubble 0.5 --cat-eye 1` took ~8% longer).
pub(super) type Poly = SmallVec<[[f64; 2]; 40]>;

/// What [`clip_convex`] did.
#[derive(Clone, Copy, PartialEq, Debug)]
pub(super) enum Clip {
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
pub(super) fn clip_convex(
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
    let (near, far) = rect_reach([x0, x1, y0, y1]);
    if far < inner * inner * (1.0 - 1e-12) {
        return Clip::Untouched;
    }
    if near >= outer * outer {
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

/// The squared distances from the origin to the nearest and the farthest point of
/// `rect = [x0, x1, y0, y1]` (0 nearest when it holds the origin).
pub(super) fn rect_reach([x0, x1, y0, y1]: [f64; 4]) -> (f64, f64) {
    let far = |a: f64, b: f64| a.abs().max(b.abs());
    let near = |a: f64, b: f64| if a <= 0.0 && b >= 0.0 { 0.0 } else { a.abs().min(b.abs()) };
    let (fx, fy, nx, ny) = (far(x0, x1), far(y0, y1), near(x0, x1), near(y0, y1));
    (nx * nx + ny * ny, fx * fx + fy * fy)
}

/// A many-sided polygon's edges by angle from the centre: which planes can bound it inside a
/// cone (see [`polygon_rect_area`]). Few-sided polygons keep every plane.
#[derive(Debug, PartialEq)]
pub(super) struct Sectors {
    /// Per sector of `2π / SECTORS`, the first and one-past-last edge (cyclic) whose angular
    /// span meets it; empty for polygons of at most `ALL_BELOW` edges.
    ranges: Vec<(usize, usize)>,
}

impl Sectors {
    const COUNT: usize = 64;
    const ALL_BELOW: usize = 16;

    pub(super) fn new(pts: &[[f64; 2]]) -> Sectors {
        let n = pts.len();
        if n <= Self::ALL_BELOW {
            return Sectors { ranges: Vec::new() };
        }
        let sector = |a: f64| (((a.rem_euclid(2.0 * PI)) / (2.0 * PI) * Self::COUNT as f64) as usize).min(Self::COUNT - 1);
        // Each edge's sectors, counterclockwise from its first point's to its last's.
        let spans: Vec<(usize, usize)> = (0..n)
            .map(|k| {
                let (a, b) = (pts[k], pts[(k + 1) % n]);
                (sector(a[1].atan2(a[0])), sector(b[1].atan2(b[0])))
            })
            .collect();
        let touches = |k: usize, s: usize| {
            let (a, b) = spans[k % n];
            (s + Self::COUNT - a) % Self::COUNT <= (b + Self::COUNT - a) % Self::COUNT
        };
        // A sector's edges are consecutive, cyclically: its range starts at the edge whose
        // predecessor misses it, and may run past n (read modulo n). Ranges built in edge
        // order broke where the run wraps: the first sector took every edge, `(0, n)`, and a
        // rectangle across angle 0 (from the last sector to the first) then got edges `n − 1`
        // on only, missing 0, 1, ...: a pixel on the +x axis of the disc's 256-gon was 0.09%
        // too bright (found by the cat's eye's mirrored templates, which did not match there).
        let ranges = (0..Self::COUNT)
            .map(|s| match (0..n).find(|&k| touches(k, s) && !touches(k + n - 1, s)) {
                Some(a) => (a, (a..a + n).find(|&k| !touches(k, s)).unwrap_or(a + n)),
                None if touches(0, s) => (0, n),
                None => (usize::MAX, 0),
            })
            .collect();
        Sectors { ranges }
    }

    /// The planes that can bound the polygon inside the cone holding `rect`: every plane when
    /// the rectangle holds the centre or spans more than a quarter turn.
    pub(super) fn planes<'a>(&self, planes: &'a [[f64; 3]], [x0, x1, y0, y1]: [f64; 4]) -> impl Iterator<Item = &'a [f64; 3]> + 'a {
        let all = || (0..planes.len(), 0..0);
        let (first, wrap) = if self.ranges.is_empty() || (x0 <= 0.0 && x1 >= 0.0 && y0 <= 0.0 && y1 >= 0.0) {
            all()
        } else {
            // The rectangle's corners' angles, unwrapped around its centre's.
            let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
            let mid = cy.atan2(cx);
            let rel = |x: f64, y: f64| {
                let d = y.atan2(x) - mid;
                // `d / 2π` lies in [−1, 1]: its `round()` (a libm call on baseline x86-64)
                // is one of −1, 0, 1, as here.
                let q = d / (2.0 * PI);
                d - (2.0 * PI) * ((q >= 0.5) as i8 - (q <= -0.5) as i8) as f64
            };
            // A point (a gauge's) is its own centre: every corner's angle is 0 (`0.5·(x + x)`
            // is `x` exactly), without four more `atan2`.
            let corners = if x0 == x1 && y0 == y1 { [0.0; 4] } else { [rel(x0, y0), rel(x1, y0), rel(x1, y1), rel(x0, y1)] };
            let (lo, hi) =
                (corners.iter().copied().fold(f64::INFINITY, f64::min), corners.iter().copied().fold(f64::NEG_INFINITY, f64::max));
            if hi - lo > 0.5 * PI {
                all()
            } else {
                let n = planes.len();
                let count = Self::COUNT as f64;
                let (s0, s1) = (((mid + lo) / (2.0 * PI) * count).floor() as i64, ((mid + hi) / (2.0 * PI) * count).floor() as i64);
                let at = |s: i64| self.ranges[s.rem_euclid(Self::COUNT as i64) as usize];
                // Edges from the first sector's first to the last sector's last, cyclically
                // (a range's end may pass n); none between them when they meet.
                let (a, b) = (at(s0).0, at(s1).1);
                let count = (b % n + n - a) % n;
                if count == 0 {
                    all()
                } else if a + count <= n {
                    (a..a + count, 0..0)
                } else {
                    (a..n, 0..a + count - n)
                }
            }
        };
        planes[first].iter().chain(planes[wrap].iter())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The exact circle's area inside a polygon against closed forms and a fine grid count
    /// (an independent quadrature), for polygons inside, around, across and outside the circle.
    #[test]
    fn polygon_circle_area_matches_closed_forms_and_a_grid() {
        let square = |x0: f64, x1: f64, y0: f64, y1: f64| vec![[x0, y0], [x1, y0], [x1, y1], [x0, y1]];
        let close = |a: f64, b: f64, tol: f64| (a - b).abs() <= tol;
        // Inside the circle: the polygon's own area. Around it: the circle's.
        assert!(close(polygon_circle_area(&square(-0.3, 0.4, -0.2, 0.1), [0.0, 0.0], 1.0), 0.21, 1e-12));
        assert!(close(polygon_circle_area(&square(-3.0, 3.0, -3.0, 3.0), [0.5, -0.2], 2.0), 4.0 * PI, 1e-12));
        // Half the circle, a quarter, nothing.
        assert!(close(polygon_circle_area(&square(0.0, 2.0, -2.0, 2.0), [0.0, 0.0], 1.0), PI / 2.0, 1e-12));
        assert!(close(polygon_circle_area(&square(1.0, 5.0, 2.0, 5.0), [1.0, 2.0], 1.5), PI * 2.25 / 4.0, 1e-12));
        assert!(close(polygon_circle_area(&square(2.0, 3.0, 0.0, 1.0), [0.0, 0.0], 1.0), 0.0, 1e-12));
        // A circular segment: the strip x ≥ 0.5 of the unit circle.
        let segment = 0.5f64.acos() - 0.5 * 0.75f64.sqrt();
        assert!(close(polygon_circle_area(&square(0.5, 2.0, -2.0, 2.0), [0.0, 0.0], 1.0), segment, 1e-12));
        // A 256-gon around a small circle (one turn of merged sectors, off centre), inside a
        // large one, and across one: against the closed forms and the 256-gon's own clip.
        let gon = circle(CURVE_VERTICES);
        assert!(close(polygon_circle_area(&gon, [0.3, -0.2], 0.25), PI * 0.0625, 1e-12));
        assert!(close(polygon_circle_area(&gon, [0.1, 0.0], 1.5), shoelace(&gon), 1e-12));
        let (v, r) = ([0.6, 0.5], 0.9);
        let mut clipped = gon.clone();
        for [nx, ny, c] in circle(4096).iter().enumerate().map(|(k, _)| {
            let t = 2.0 * PI * (k as f64 + 0.5) / 4096.0;
            [t.cos(), t.sin(), r * (PI / 4096.0).cos() + t.cos() * v[0] + t.sin() * v[1]]
        }) {
            let mut next = Vec::new();
            clip_half_plane(&clipped, [nx, ny, c], &mut next);
            clipped = next;
        }
        // The 4096-gon inscribed in the circle falls short of it by ~4e-7 of its area.
        assert!(
            close(polygon_circle_area(&gon, v, r), shoelace(&clipped), 2e-6),
            "{} vs {}",
            polygon_circle_area(&gon, v, r),
            shoelace(&clipped)
        );
        // A small circle in a triangle whose first edge sweeps 175° and the next two 100° and
        // 85°: no run may hold the first two edges (275°, which `atan2` would read as -85°).
        let polar = |deg: f64| [10.0 * deg.to_radians().cos(), 10.0 * deg.to_radians().sin()];
        assert!(close(polygon_circle_area(&[polar(190.0), polar(5.0), polar(105.0)], [0.0, 0.0], 0.1), PI * 0.01, 1e-12));
        // A pentagon across the circle's edge, against a 2000 x 2000 grid of cell centres.
        let pentagon: Vec<[f64; 2]> =
            (0..5).map(|k| 0.3 + 2.0 * PI * k as f64 / 5.0).map(|t| [0.4 + 0.9 * t.cos(), -0.1 + 0.9 * t.sin()]).collect();
        let (c, r) = ([-0.2, 0.15], 0.8);
        let n = 2000;
        let inside_polygon = |p: [f64; 2]| {
            (0..5).all(|i| {
                let (a, b) = (pentagon[i], pentagon[(i + 1) % 5]);
                (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]) >= 0.0
            })
        };
        let cell = 4.0 / n as f64;
        let count = (0..n * n)
            .map(|k| [-2.0 + (k % n) as f64 * cell + 0.5 * cell, -2.0 + (k / n) as f64 * cell + 0.5 * cell])
            .filter(|&p| inside_polygon(p) && (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2) <= r * r)
            .count();
        let grid = count as f64 * cell * cell;
        let exact = polygon_circle_area(&pentagon, c, r);
        assert!(exact > 0.3 && close(exact, grid, 2e-3), "{exact} vs grid {grid}");
    }

    /// [`Sectors::planes`] never leaves out an edge that cuts a rectangle: the clipped area
    /// with the sectors' edges equals the area with every edge (to 1e-12) for 1-px squares at
    /// 720 angles around the outline of the disc's 256-gon, rounded 7-blade and 9-blade
    /// polygons rotated 10° and 180°, and a disc squeezed 2:1, at circumradius 6 and 40 px,
    /// straddling the outline and across angle 0 (where the first sector's range wraps).
    /// Before the wrap was kept, the 256-gon's squares across the +x axis missed edges 0-3.
    #[test]
    fn sectors_keep_every_edge_that_cuts_a_rectangle() {
        let squeezed: Vec<[f64; 2]> = circle(CURVE_VERTICES).iter().map(|p| [p[0], 0.5 * p[1]]).collect();
        for (name, pts) in [
            ("256-gon", circle(CURVE_VERTICES)),
            ("7 blades", blades(7, 10f64.to_radians(), 0.6)),
            ("9 blades", blades(9, PI, 1.0)),
            ("squeezed disc", squeezed),
        ] {
            let n = pts.len();
            assert!(n > Sectors::ALL_BELOW, "{name}: {n} vertices use no sectors");
            let planes = half_planes(&pts);
            let bbox = [-1.0, 1.0, -1.0, 1.0];
            let radii = [0.0, 1.0];
            let (sectors, every) = (Sectors::new(&pts), Sectors { ranges: Vec::new() });
            let mut worst = (0.0f64, 0.0f64, 0.0f64);
            for r in [6.0f64, 40.0] {
                for k in 0..720 {
                    let t = 2.0 * PI * k as f64 / 720.0;
                    // Where the outline crosses the ray at t, and a square there (1 px, in units of r).
                    let reach =
                        planes.iter().map(|p| p[2] / (p[0] * t.cos() + p[1] * t.sin())).filter(|d| *d > 0.0).fold(f64::INFINITY, f64::min);
                    for off in [-0.6, 0.0, 0.4] {
                        let (x, y) = ((reach + off / r) * t.cos(), (reach + off / r) * t.sin());
                        let h = 0.5 / r;
                        let rect = [x - h, x + h, y - h, y + h];
                        let area = |s: &Sectors| match polygon_rect_area(&planes, &bbox, radii, s, rect) {
                            Area::Inside => 4.0 * h * h,
                            Area::Part(a) => a,
                        };
                        let (a, b) = (area(&sectors), area(&every));
                        if (a - b).abs() > worst.0 {
                            worst = ((a - b).abs(), t.to_degrees(), r);
                        }
                    }
                }
            }
            assert!(worst.0 <= 1e-12, "{name}: area off by {} at {}° (r {})", worst.0, worst.1, worst.2);
        }
    }
}
