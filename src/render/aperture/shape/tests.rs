use super::*;
use std::f64::consts::PI;

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
        let got = g.cut_area(CutCircle { centre: [0.0, -d as f32], radius: 1.0 });
        assert!((got - want).abs() < 2e-3 * want, "d {d}: {got} vs {want}");
        // Coverages tile: their lattice sum is the area (the source's unit flux).
        let r = 7.5f32;
        let sum: f64 = (-10..=10)
            .flat_map(|y| (-10..=10).map(move |x| (x, y)))
            .map(|(x, y)| g.coverage_cut(r, x as f32, y as f32, false, Some(CutCircle { centre: [0.0, -d as f32], radius: 1.0 })) as f64)
            .sum();
        let want = got * (r * r) as f64;
        assert!((sum - want).abs() < 1e-3 * sum, "d {d}: lattice {sum} (want {want})");
    }
    // Refused: out of range. An image aperture and a bubble take one.
    assert!(Aperture::DISC.with_cat_eye(1.5).is_err() && Aperture::DISC.with_cat_eye(f32::NAN).is_err());
    let image = Aperture::from_mask(2, 2, &[1.0; 4], 1.0, "m").unwrap();
    assert_eq!(image.with_cat_eye(0.5).unwrap().geometry().map(|g| g as *const _), image.geometry().map(|g| g as *const _));
    let bubble = Aperture::with_bubble(&ShapeSpec::Disc, 1.0, 0.5, "b").unwrap();
    assert!(bubble.with_cat_eye(0.5).unwrap().cat_eye(10, 10).is_some());
    assert_eq!(disc.label(), "disc,cat_eye=1");
    assert!(Aperture::DISC.with_cat_eye(0.0).unwrap().is_disc());
}

/// `CatEye::cut` is the lens's per-ray rule: for sources across a frame and lens points
/// over the unit square, a lens point lies in the source's cut exactly when it lies in the
/// unit circle of the pixel its ray lands on (`offset` there), that pixel `∓r·a` from the
/// source (y up; reflected in front), behind and in front, from small CoCs to one past the
/// half-diagonal in front (where the circle turns over).
#[test]
fn a_sources_cut_is_where_its_rays_pass_their_pixels_circles() {
    let c = CatEye::new(0.9, 160, 90);
    let reach = 0.5 * (160.0f32 * 160.0 + 90.0 * 90.0).sqrt();
    let (mut checked, mut passed) = (0usize, 0usize);
    for (sx, sy) in [(5.0f32, 7.0f32), (80.0, 45.0), (150.0, 20.0), (30.0, 80.0), (120.0, 60.0)] {
        for r in [1.5f32, 6.0, 20.0, 0.5 * reach, 1.3 * reach] {
            for front in [false, true] {
                let v = c.offset(sx, sy);
                let cut = c.cut(v, r, front);
                for i in 0..41 {
                    for j in 0..41 {
                        let a = [-1.0 + i as f32 * 0.05, -1.0 + j as f32 * 0.05];
                        // The landing pixel (image coordinates, rows down): `r·a` behind, `-r·a`
                        // in front, y flipped; beyond the frame its circle is not linear, skipped.
                        let sign = if front { -1.0 } else { 1.0 };
                        let (tx, ty) = (sx + sign * r * a[0], sy - sign * r * a[1]);
                        if !(0.0..160.0).contains(&tx) || !(0.0..90.0).contains(&ty) {
                            continue;
                        }
                        let w = c.offset(tx, ty);
                        let lens = (a[0] - w[0]).powi(2) + (a[1] - w[1]).powi(2);
                        let circle = (a[0] - cut.centre[0]).powi(2) + (a[1] - cut.centre[1]).powi(2) - cut.radius * cut.radius;
                        // Points within rounding of either boundary say nothing.
                        if (lens - 1.0).abs() < 1e-3 || circle.abs() < 1e-3 * cut.radius * cut.radius {
                            continue;
                        }
                        assert_eq!(lens < 1.0, circle < 0.0, "source ({sx}, {sy}) r {r} front {front} a {a:?}: {cut:?}");
                        checked += 1;
                        passed += usize::from(lens < 1.0);
                    }
                }
            }
        }
    }
    // Both outcomes were met, many times.
    assert!(passed > 1000 && checked - passed > 1000, "{passed} of {checked}");
}

/// `CatGains` interpolates the gain (from a polar table, between pixel lattice points): within
/// 0.3% of the exact gain at every pixel of a frame large enough to need the lattice, within
/// 0.1% on a small frame (the table alone; measured 0.06% for the pentagon), for the disc (one radial table), a pentagon and an anamorphic disc
/// (radius and angle), and [`cut_shapes`] (bubbles and images); the gain is the shape's flux over its flux in the pixel's circle (the
/// disc's `π / lens(|v|)` at a corner).
#[test]
fn cat_gains_follow_the_pixels_circles() {
    let pentagon = Aperture::new(&ShapeSpec::Blades { n: 5, rotation: 90.0, curvature: 0.0 }, 1.0, "p").unwrap();
    let oval = Aperture::new(&ShapeSpec::Disc, 1.4, "o").unwrap();
    let shapes = [("disc", Aperture::DISC), ("pentagon", pentagon), ("anamorphic", oval)]
        .map(|(name, a)| (name, a.with_cat_eye(0.9).unwrap().geometry().unwrap()))
        .into_iter()
        .chain(cut_shapes());
    for (name, g) in shapes {
        for (w, h) in [(1200usize, 800usize), (64, 48)] {
            let c = CatEye::new(0.9, w, h);
            let gains = c.gains(g);
            let mut worst = 0f32;
            for y in (0..h).step_by(7).chain([h - 1]) {
                for x in (0..w).step_by(5).chain([w - 1]) {
                    let exact = g.cat_gain(c.offset(x as f32, y as f32));
                    worst = worst.max((gains.at(x, y) / exact - 1.0).abs());
                }
            }
            let bound = if w < 100 { 1e-3 } else { 3e-3 };
            assert!(worst < bound, "{name} {w}x{h}: {worst}");
            if name == "disc" {
                // The corner pixel's centre is half a pixel inside the half-diagonal.
                let [vx, vy] = c.offset(0.0, 0.0);
                let d = (vx as f64).hypot(vy as f64);
                assert!(d > 0.87, "{d}");
                let lens = 2.0 * (d / 2.0).acos() - d / 2.0 * (4.0 - d * d).sqrt();
                let corner = gains.at(0, 0) as f64;
                assert!((corner / (PI / lens) - 1.0).abs() < 2e-3, "{w}x{h}: corner {corner}");
            }
        }
    }
}

/// A bubble disc, a bubble hexagon, a grey image and the same image with a bubble: the
/// apertures a cat's eye meets beyond the plain polygons.
fn cut_shapes() -> Vec<(&'static str, &'static Geometry)> {
    let (w, h) = (40usize, 30usize);
    // A grey blob with a hole and a soft rim, not symmetric.
    let values: Vec<f32> = (0..w * h)
        .map(|i| {
            let (x, y) = ((i % w) as f32 / w as f32 - 0.45, (i / w) as f32 / h as f32 - 0.5);
            let d = (x * x + 1.3 * y * y).sqrt();
            let hole = ((x - 0.1).powi(2) + (y + 0.15).powi(2)).sqrt() < 0.08;
            if hole { 0.0 } else { (1.6 - 3.5 * d).clamp(0.0, 1.0) * (0.7 + 0.3 * (7.0 * x).sin().abs()) }
        })
        .collect();
    let mask = |bubble: f32| {
        let m = Mask::new(w, h, &values).unwrap();
        Aperture::from_kind(ShapeSpec::Image { path: format!("blob{bubble}") }, 1.0, bubble, Kind::Mask(m)).geometry().unwrap()
    };
    let bubble =
        |spec: &str, b: f32| Aperture::with_bubble(&ShapeSpec::parse(spec, "a").unwrap(), 1.0, b, "a").unwrap().geometry().unwrap();
    vec![
        ("bubble disc 0.5", bubble("disc", 0.5)),
        ("bubble hexagon -0.7", bubble("blades:6,rotation=15", -0.7)),
        ("image", mask(0.0)),
        ("image bubble 0.6", mask(0.6)),
    ]
}

/// The circles [`cut_shapes`]' tests cut with (unit frame): the centre, off axis, beyond the
/// outline, and two smaller than the shape (one wholly inside it).
const CUTS: [([f64; 2], f64); 5] = [([0.0, 0.0], 1.0), ([0.3, -0.5], 1.0), ([0.9, 0.2], 1.2), ([0.0, -0.8], 0.7), ([0.1, 0.05], 0.35)];

/// A cut shape's flux (`Geometry::flux_in_circle`, what the cat's eye's gains and the fast
/// kernel's sources are normalized by) is the shape's transmission, weighted by its bubble's
/// profile, integrated over the circle: against a 900 × 900 midpoint grid, within 2e-3 of
/// the whole shape's; with no cut, the whole shape's flux (its area).
#[test]
fn a_cut_shapes_flux_is_its_weighted_area_inside_the_circle() {
    let n = 900usize;
    for (name, g) in cut_shapes() {
        let far = g.flux_in_circle([0.0, 0.0], 10.0);
        assert!((far / g.area - 1.0).abs() < 1e-4, "{name}: uncut {far} vs {}", g.area);
        for (v, radius) in CUTS {
            let mut acc = 0f64;
            for i in 0..n {
                for j in 0..n {
                    let (x, y) = (-1.0 + 2.0 * (i as f64 + 0.5) / n as f64, -1.0 + 2.0 * (j as f64 + 0.5) / n as f64);
                    if (x - v[0]).hypot(y - v[1]) <= radius {
                        acc += g.transmission(x as f32, y as f32) as f64;
                    }
                }
            }
            let want = acc * 4.0 / (n * n) as f64;
            let got = g.flux_in_circle(v, radius);
            assert!((got - want).abs() < 2e-3 * g.area, "{name} cut {v:?} {radius}: {got} vs {want} (area {})", g.area);
        }
    }
}

/// A cut shape's coverages tile: their lattice sum is its cut flux times r², at CoCs where a
/// bubble's weights are its exact integral (2.5 px), blended (5 px) and the midpoint rule
/// (9 px), behind and in front of the focal plane.
#[test]
fn a_cut_shapes_coverages_sum_to_its_cut_flux() {
    for (name, g) in cut_shapes() {
        for (v, radius) in CUTS {
            let cut = CutCircle { centre: [v[0] as f32, v[1] as f32], radius: radius as f32 };
            let flux = g.cut_area(cut);
            for r in [2.5f32, 5.0, 9.0] {
                for flip in [false, true] {
                    let m = r.ceil() as i32 + 2;
                    let sum: f64 = (-m..=m)
                        .flat_map(|y| (-m..=m).map(move |x| (x, y)))
                        .map(|(x, y)| g.coverage_cut(r, x as f32, y as f32, flip, Some(cut)) as f64)
                        .sum();
                    let want = flux * (r * r) as f64;
                    let tol = if name.contains("bubble") && r > 4.0 { 3e-3 } else { 1e-3 };
                    assert!(
                        (sum - want).abs() < tol * (g.area * (r * r) as f64),
                        "{name} cut {v:?} {radius} r {r} flip {flip}: {sum} vs {want}"
                    );
                }
            }
        }
    }
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
        (-2..=2).flat_map(|y| (-2..=2).map(move |x| (x, y))).map(|(x, y)| g.coverage(r, x as f32, y as f32, false) / g.norm(r)).collect()
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

/// A bubble's profile at CoCs of a few pixels and below, where one intensity per pixel square
/// is far from the profile's integral: the weights carry unit flux (the norm is the shape's
/// area, the profile's mean over it being 1) and match the supersampled profile under the tent,
/// for a bright rim and a bright centre, through the blend to the midpoint rule (4 to 6 px) and
/// past it. Before, a 0.3 px disc's light came out ~1.4 (rim) or ~0.6 (centre) times its flux.
#[test]
fn a_small_bubble_keeps_its_flux_and_its_profile() {
    for b in [0.5f32, -0.5] {
        let a = Aperture::with_bubble(&ShapeSpec::Disc, 1.0, b, "b").unwrap();
        let g = a.geometry().unwrap();
        for r in [0.3f32, 0.7, 1.3, 2.5, 3.9, 5.0, 7.0] {
            let (mut sum, mut worst) = (0f64, 0f64);
            let reach = r.ceil() as i32 + 2;
            for y in -reach..=reach {
                for x in -reach..=reach {
                    let c = g.coverage(r, x as f32 + 0.2, y as f32 - 0.1, false) as f64;
                    sum += c;
                    let profile = |u: f64, v: f64| {
                        let t = (u * u + v * v).sqrt();
                        if t <= 1.0 { 1.0 + b as f64 * (2.0 * t * t - 1.0) } else { 0.0 }
                    };
                    let truth = supersampled_grey(profile, r as f64, x as f64 + 0.2, y as f64 - 0.1, 200);
                    worst = worst.max((c - truth).abs());
                }
            }
            let flux = sum / g.norm(r) as f64;
            // The exact profile below 4 px (its Gauss rule in the scale), the midpoint rule's
            // ~0.2% above; the tent is a 4 x 4 staircase of squares, the disc a 256-gon.
            let (flux_tol, tol) = if r < 4.0 { (2e-4, 0.012) } else { (2.5e-3, 0.025) };
            assert!((flux - 1.0).abs() < flux_tol, "bubble {b}, r {r}: flux {flux}");
            assert!(worst < tol, "bubble {b}, r {r}: worst weight error {worst}");
        }
    }
}

/// A bubble inside its own pixel (a CoC well below a pixel, near the focal plane) leaves the
/// source's light where it is: the pixel's weight over the norm is 1 at every CoC, for
/// polygons and images, either sign, whole or cut by a cat's eye's circle (its cut flux). The midpoint rule gave 1 ± B there (and a first exact
/// quadrature, squares split to an eighth of the CoC, 1.00–1.02 varying with the CoC: a slope
/// of the weight in the depth that is no light moving, which put the backward's directional
/// check on a bubble 38% off).
#[test]
fn a_bubble_inside_its_pixel_keeps_its_light_at_every_coc() {
    let n = 24;
    let disc: Vec<f32> = (0..n * n)
        .map(|i| {
            let (x, y) = ((i % n) as f32 + 0.5 - n as f32 / 2.0, (i / n) as f32 + 0.5 - n as f32 / 2.0);
            ((n as f32 / 2.0 - (x * x + y * y).sqrt()).clamp(0.0, 1.0) * if x > 0.0 { 1.0 } else { 0.6 }).max(0.0)
        })
        .collect();
    for b in [1.0f32, -1.0, 0.5] {
        let shapes = [
            Aperture::with_bubble(&ShapeSpec::Disc, 1.0, b, "b").unwrap(),
            Aperture::with_bubble(&ShapeSpec::parse("blades:7,rotation=10,curvature=0.5", "t").unwrap(), 1.4, b, "b").unwrap(),
            Aperture::from_kind(ShapeSpec::Image { path: "disc".into() }, 0.7, b, Kind::Mask(Mask::new(n, n, &disc).unwrap())),
        ];
        for a in shapes {
            let g = a.geometry().unwrap();
            for r in [0.0011f32, 0.003, 0.01, 0.04, 0.1] {
                let own = g.coverage(r, 0.0, 0.0, false) as f64 / g.norm(r) as f64;
                assert!((own - 1.0).abs() < 2e-5, "{}, bubble {b}, r {r}: own weight {own}", a.label());
                assert_eq!(g.coverage(r, 1.0, 0.0, true), 0.0);
                // Under a cat's eye's cut: its cut flux, as the gains count it.
                for (v, radius) in CUTS {
                    let cut = CutCircle { centre: [v[0] as f32, v[1] as f32], radius: radius as f32 };
                    let own = g.coverage_cut_f64(r, 0.0, 0.0, true, Some(cut)) / (g.cut_area(cut) * (r * r) as f64);
                    assert!((own - 1.0).abs() < 2e-5, "{}, bubble {b}, r {r}, cut {v:?} {radius}: own weight {own}", a.label());
                }
            }
        }
    }
}

/// An image's bubble is its weighted table: the weights' lattice sum is the flux norm at any
/// CoC (the tiling), and a disc-shaped mask's weights follow its supersampled cells, each of
/// one value and one profile value (before, one intensity per pixel square, as polygons).
#[test]
fn an_image_bubble_is_exact_at_every_coc() {
    let n = 64;
    let inside = |x: f64, y: f64| x * x + y * y <= 1.0;
    let cell = |i: usize| (-1.0 + 2.0 * ((i % n) as f64 + 0.5) / n as f64, 1.0 - 2.0 * ((i / n) as f64 + 0.5) / n as f64);
    let disc: Vec<f32> = (0..n * n).map(|i| inside(cell(i).0, cell(i).1) as u8 as f32).collect();
    for b in [0.5f32, -0.8] {
        let a = Aperture::from_kind(ShapeSpec::Image { path: "disc".into() }, 1.0, b, Kind::Mask(Mask::new(n, n, &disc).unwrap()));
        let g = a.geometry().unwrap();
        for r in [0.4f32, 1.7, 3.3, 9.0] {
            let (mut sum, mut worst) = (0f64, 0f64);
            let reach = r.ceil() as i32 + 2;
            for y in -reach..=reach {
                for x in -reach..=reach {
                    let (px, py) = (x as f64 + 0.3, y as f64 + 0.1);
                    let c = g.coverage(r, px as f32, py as f32, false) as f64;
                    sum += c;
                    // The mask as it is: cells of one value and one profile value each.
                    let profile = |u: f64, v: f64| {
                        let (col, row) = (((u + 1.0) * n as f64 / 2.0).floor(), ((1.0 - v) * n as f64 / 2.0).floor());
                        if col < 0.0 || row < 0.0 || col >= n as f64 || row >= n as f64 {
                            return 0.0;
                        }
                        let (cu, cv) = cell(row as usize * n + col as usize);
                        if inside(cu, cv) { 1.0 + b as f64 * (2.0 * (cu * cu + cv * cv) - 1.0) } else { 0.0 }
                    };
                    worst = worst.max((c - supersampled_grey(profile, r as f64, px, py, 200)).abs());
                }
            }
            let flux = sum / g.norm(r) as f64;
            assert!((flux - 1.0).abs() < 1e-4, "bubble {b}, r {r}: flux {flux}");
            // The truth's 200 x 200 samples over 2 x 2 px against cells of 0.03 to 0.3 px.
            assert!(worst < 0.02, "bubble {b}, r {r}: worst weight error {worst}");
        }
    }
}
