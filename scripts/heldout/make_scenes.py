#!/usr/bin/env python3
"""Held-out thin-lens ground-truth scenes in the format of `shared/groundtruth` (see its README).

Six layered scenes of fronto-parallel, opaque, emissive billboards, rendered with Mitsuba 3.9.1
(`scalar_rgb`): the all-in-focus pinhole image, the exact depth (analytic, pixel centres), the
foreground matte and colour, the true background, and three thin-lens ground truths each
(focus_fg, focus_mid, focus_bg). Deterministic for a seed. Made to check `drbokeh bench
--groundtruth` on scenes nothing was tuned on (issue 12); they differ from the shared `portrait`
and `thin_bars` scenes in shapes, textures and crops.

    bash scripts/heldout/setup.sh                       # .venv-heldout with pinned mitsuba
    nice -n 10 .venv-heldout/bin/python scripts/heldout/make_scenes.py --out target/heldout

Conventions (as the shared README): pinhole at the origin looking down +z, +y up; a point
(x, y, z) lands at pixel u = W/2 - f x/z, v = H/2 - f y/z; box pixel filter; linear radiance;
depth is camera-space z of the frontmost layer at each pixel centre.
"""
import argparse
import json
import math
import os
import sys
import tempfile
import time

import numpy as np

W_DEFAULT, H_DEFAULT = 256, 192
FOV = 40.0
PAD = 48  # background and textures reach this far past every border (px)
SPP_PASS = 576  # a square: the multijitter sampler rounds other counts up


# ----------------------------------------------------------------------------- geometry

def rect_poly(cx, cy, w, h, angle_deg=0.0):
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    pts = [(-w / 2, -h / 2), (w / 2, -h / 2), (w / 2, h / 2), (-w / 2, h / 2)]
    return np.array([(cx + x * c - y * s, cy + x * s + y * c) for x, y in pts])


def bar_poly(p0, p1, width):
    """A bar of `width` px from p0 to p1 (a rotated rectangle)."""
    (x0, y0), (x1, y1) = p0, p1
    L = math.hypot(x1 - x0, y1 - y0)
    return rect_poly((x0 + x1) / 2, (y0 + y1) / 2, L, width, math.degrees(math.atan2(y1 - y0, x1 - x0)))


def disk_poly(cx, cy, r, n=96):
    t = np.arange(n) * 2 * np.pi / n + 0.0137
    return np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], 1)


def star_poly(cx, cy, r_out, r_in, points, rot=0.0):
    t = np.arange(2 * points) * np.pi / points + math.radians(rot)
    r = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    return np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], 1)


def blob_poly(cx, cy, r, rng, n=120, amp=0.18):
    t = np.arange(n) * 2 * np.pi / n
    rad = np.full(n, float(r))
    for k in (2, 3, 5):
        rad *= 1 + amp / k * math.sqrt(k) * np.sin(k * t + rng.uniform(0, 2 * np.pi))
    return np.stack([cx + rad * np.cos(t), cy + rad * np.sin(t)], 1)


def catmull_rom(ctrl, sub=8):
    """Closed Catmull-Rom spline through the control points."""
    P = np.asarray(ctrl, float)
    n = len(P)
    out = []
    for i in range(n):
        p0, p1, p2, p3 = P[(i - 1) % n], P[i], P[(i + 1) % n], P[(i + 2) % n]
        for k in range(sub):
            t = k / sub
            out.append(0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t * t
                              + (-p0 + 3 * p1 - 3 * p2 + p3) * t ** 3))
    return np.array(out)


def signed_area(P):
    x, y = P[:, 0], P[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def clean_poly(P):
    """Drops repeated and collinear vertices; returns the polygon counter-clockwise in (u, v)."""
    P = np.asarray(P, float)
    keep = [P[0]]
    for p in P[1:]:
        if np.hypot(*(p - keep[-1])) > 1e-6:
            keep.append(p)
    if np.hypot(*(keep[0] - keep[-1])) <= 1e-6:
        keep.pop()
    P = np.array(keep)
    if signed_area(P) < 0:
        P = P[::-1].copy()
    changed = True
    while changed and len(P) > 3:
        changed = False
        for i in range(len(P)):
            a, b, c = P[i - 1], P[i], P[(i + 1) % len(P)]
            if abs((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])) < 1e-9:
                P = np.delete(P, i, 0)
                changed = True
                break
    return P


def triangulate(P):
    """Ear clipping of a simple polygon (counter-clockwise); triangles as index triples."""
    n = len(P)
    idx = list(range(n))
    tris = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    guard = 0
    while len(idx) > 3:
        guard += 1
        if guard > 10 * n * n:
            raise RuntimeError("ear clipping failed (polygon not simple?)")
        m = len(idx)
        for k in range(m):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % m]
            a, b, c = P[i0], P[i1], P[i2]
            if cross(a, b, c) <= 1e-12:
                continue  # reflex
            inside = False
            for j in idx:
                if j in (i0, i1, i2):
                    continue
                p = P[j]
                if cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0:
                    inside = True
                    break
            if not inside:
                tris.append((i0, i1, i2))
                idx.pop(k)
                break
        else:
            raise RuntimeError("ear clipping found no ear")
    tris.append(tuple(idx))
    area = sum(abs(cross(P[a], P[b], P[c])) / 2 for a, b, c in tris)
    assert abs(area - abs(signed_area(P))) < 1e-6 * max(1.0, area), "triangulation does not cover the polygon"
    return tris


def inside_polygon(P, us, vs):
    """Even-odd point-in-polygon test of the points (us, vs)."""
    inside = np.zeros(us.shape, bool)
    n = len(P)
    for i in range(n):
        (x0, y0), (x1, y1) = P[i], P[(i + 1) % n]
        cond = (y0 > vs) != (y1 > vs)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x0 + (vs - y0) * (x1 - x0) / (y1 - y0)
        inside ^= cond & (us < xc)
    return inside


# ----------------------------------------------------------------------------- textures

def srgb_to_linear(x):
    return np.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def source_image(name):
    import skimage.data as data
    img = getattr(data, name)()
    if isinstance(img, tuple):
        img = img[0]
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.float32)
    else:
        img = img.astype(np.float32) / (255.0 if img.dtype == np.uint8 else 1.0)
    if img.ndim == 3 and img.shape[2] == 4:
        img = img[:, :, :3]
    return srgb_to_linear(img)


def texture(name, crop, size, tint=(1.0, 1.0, 1.0), gain=1.0):
    """A linear RGB texture of `size` = (rows, cols) texels from the crop (fractions y0, x0,
    y1, x1 of the source) of a scikit-image sample photo; grey photos are tinted."""
    from skimage.transform import resize
    img = source_image(name)
    h, w = img.shape[:2]
    y0, x0, y1, x1 = crop
    img = img[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]
    img = resize(img, size, order=1, anti_aliasing=True, mode="edge").astype(np.float32)
    if img.ndim == 2:
        img = img[:, :, None] * np.asarray(tint, np.float32)[None, None, :]
    else:
        img = img * np.asarray(tint, np.float32)
    return np.ascontiguousarray(np.clip(img * gain, 0, None).astype(np.float32))


def add_highlights(tex, spots, origin=(-PAD, -PAD)):
    """Draws antialiased discs (u, v, radius px, radiance, colour) into a screen-space texture
    (2 texels per pixel, texel (0, 0) at screen `origin`)."""
    th, tw = tex.shape[:2]
    ss = 4
    for (u, v, r, L, col) in spots:
        cu, cv, rr = 2 * (u - origin[0]), 2 * (v - origin[1]), 2 * r
        c0, c1 = max(int(cu - rr) - 1, 0), min(int(cu + rr) + 2, tw)
        r0, r1 = max(int(cv - rr) - 1, 0), min(int(cv + rr) + 2, th)
        if c0 >= c1 or r0 >= r1:
            continue
        yy, xx = np.mgrid[r0:r1, c0:c1].astype(np.float64)
        cov = np.zeros(yy.shape)
        for a in range(ss):
            for b in range(ss):
                cov += ((xx + (b + 0.5) / ss - cu) ** 2 + (yy + (a + 0.5) / ss - cv) ** 2) <= rr * rr
        cov /= ss * ss
        val = L * np.asarray(col, np.float64)
        tex[r0:r1, c0:c1] = (tex[r0:r1, c0:c1] * (1 - cov[..., None]) + cov[..., None] * val).astype(np.float32)


def random_spots(rng, n, W, H, near=None, near_frac=0.5):
    """n highlight discs: radius 1.5-3 px, radiance 5-50 (log-uniform), warm or cool white;
    a share of them next to the given outline points (to end up half behind an edge)."""
    spots = []
    for k in range(n):
        if near is not None and len(near) and k < int(n * near_frac):
            p = near[rng.integers(len(near))]
            u, v = p[0] + rng.uniform(-7, 7), p[1] + rng.uniform(-7, 7)
        else:
            u, v = rng.uniform(8, W - 8), rng.uniform(8, H - 8)
        r = rng.uniform(1.5, 3.0)
        L = float(np.exp(rng.uniform(np.log(5), np.log(50))))
        col = [(1.0, 0.85, 0.6), (0.75, 0.85, 1.0), (1.0, 1.0, 0.95)][rng.integers(3)]
        spots.append((float(u), float(v), float(r), L, col))
    return spots


# ----------------------------------------------------------------------------- scenes

class Layer:
    def __init__(self, name, z, poly, role, shape, tex_key, texture_desc, uv=None):
        self.name, self.z, self.role, self.shape = name, float(z), role, shape
        self.poly = clean_poly(poly)
        self.tex_key, self.texture_desc = tex_key, texture_desc
        # None: the texture is mapped in screen space; else (origin, e1, e2) of the shape's own
        # frame, the texture spanning origin + [0, 1] e1 + [0, 1] e2.
        self.uv = uv


def outline_points(layers, W, H, step=4.0):
    """Points every `step` px along the foreground outlines, inside the frame."""
    pts = []
    for l in layers:
        if l.role != "fg":
            continue
        P = l.poly
        for a, b in zip(P, np.roll(P, -1, 0)):
            n = max(int(np.hypot(*(b - a)) / step), 1)
            pts += [a + (b - a) * t for t in np.arange(n) / n]
    pts = np.array(pts)
    ok = (pts[:, 0] > 6) & (pts[:, 0] < W - 6) & (pts[:, 1] > 6) & (pts[:, 1] < H - 6)
    return pts[ok]


def bg_rect(W, H):
    return rect_poly(W / 2 + 0.0137, H / 2 + 0.0213, W + 2 * PAD + 0.7, H + 2 * PAD + 0.7)


def scene_defs(W, H, seed):
    """The six scenes: layers, screen-space textures (by key), and settings' focus depths."""
    TW, TH = 2 * (W + 2 * PAD), 2 * (H + 2 * PAD)
    full = (TH, TW)
    s = []

    # (a) portrait-like: a three-quarter head-and-shoulders silhouette, off centre, tilted.
    rng = np.random.default_rng(seed * 1000 + 1)
    ctrl = [(62, 270), (70, 178), (92, 152), (124, 141), (139, 129), (142, 112), (134, 101), (127, 92),
            (120, 80), (127, 71), (124, 57), (130, 41), (147, 25), (170, 20), (191, 31), (201, 52), (199, 78),
            (190, 102), (186, 122), (206, 136), (242, 147), (290, 165), (310, 270)]
    person = catmull_rom([(x * W / 256 + 0.013, y * H / 192 + 0.021) for x, y in ctrl], 8)
    layers = [Layer("person", 1.8, person, "fg", "three-quarter head-and-shoulders silhouette (polygon)", "fg",
                    "skimage chelsea (cat) photo, screen-mapped"),
              Layer("background", 9.0, bg_rect(W, H), "bg", "rectangle", "bg", "skimage coffee photo + 6 highlight spots")]
    tex = {"fg": texture("chelsea", (0.05, 0.15, 0.95, 0.85), full),
           "bg": texture("coffee", (0.0, 0.05, 1.0, 0.95), full)}
    add_highlights(tex["bg"], random_spots(rng, 6, W, H, outline_points(layers, W, H)))
    s.append(dict(scene="ho_profile", K_norm=19.0, layers=layers, tex=tex, mid=None,
                  description="(a) portrait-like: a three-quarter head-and-shoulders silhouette, off centre and running off "
                              "the bottom and right edges, with a photo texture, in front of a far photo background with highlights"))

    # (b) thin structures: a branching twig (trunk + branches) and thinner twigs at a second depth.
    rng = np.random.default_rng(seed * 1000 + 2)
    layers = [
        Layer("trunk", 2.0, bar_poly((70.3, 240.2), (104.1, -50.3), 5.0), "fg", "bar 5 px wide (rotated rectangle)", "near",
              "skimage brick texture, tinted brown"),
        Layer("branch1", 2.0, bar_poly((88.2, 90.1), (300.4, 20.7), 3.0), "fg", "bar 3 px wide (rotated rectangle)", "near",
              "skimage brick texture, tinted brown"),
        Layer("branch2", 2.0, bar_poly((80.6, 150.3), (-60.2, 60.4), 2.0), "fg", "bar 2 px wide (rotated rectangle)", "near",
              "skimage brick texture, tinted brown"),
        Layer("branch3", 2.0, bar_poly((95.1, 40.2), (170.3, -60.1), 1.5), "fg", "bar 1.5 px wide (rotated rectangle)", "near",
              "skimage brick texture, tinted brown"),
        Layer("twig1", 2.9, bar_poly((150.2, 250.4), (230.3, -40.6), 2.5), "fg", "bar 2.5 px wide (rotated rectangle)", "far",
              "skimage grass texture, tinted green"),
        Layer("twig2", 2.9, bar_poly((120.7, 230.1), (330.2, 110.3), 2.0), "fg", "bar 2 px wide (rotated rectangle)", "far",
              "skimage grass texture, tinted green"),
        Layer("twig3", 2.9, bar_poly((196.4, 140.6), (250.2, 230.8), 3.5), "fg", "bar 3.5 px wide (rotated rectangle)", "far",
              "skimage grass texture, tinted green"),
        Layer("background", 11.0, bg_rect(W, H), "bg", "rectangle", "bg", "skimage immunohistochemistry photo + 6 highlight spots"),
    ]
    tex = {"near": texture("brick", (0.1, 0.1, 0.9, 0.9), full, tint=(0.9, 0.6, 0.35), gain=1.2),
           "far": texture("grass", (0.0, 0.0, 1.0, 1.0), full, tint=(0.45, 0.9, 0.3), gain=1.1),
           "bg": texture("immunohistochemistry", (0.1, 0.0, 0.9, 1.0), full)}
    add_highlights(tex["bg"], random_spots(rng, 6, W, H, outline_points(layers, W, H)))
    s.append(dict(scene="ho_branches", K_norm=18.0, layers=layers, tex=tex, mid=None,
                  description="(b) thin structures: a branching twig (bars 1.5-5 px wide) and three thinner twigs at a second "
                              "depth, in front of a photo background with highlights"))

    # (c) a foreground blob over a background of two planes with a depth step.
    rng = np.random.default_rng(seed * 1000 + 3)
    step_u = 0.62 * W + 0.0171
    near_bg = np.array([(-PAD - 0.35, -PAD - 0.35), (step_u, -PAD - 0.35), (step_u, H + PAD + 0.35), (-PAD - 0.35, H + PAD + 0.35)])
    layers = [Layer("blob", 2.2, blob_poly(0.45 * W + 0.013, 0.55 * H + 0.017, 0.26 * H, rng), "fg", "irregular blob (polygon)",
                    "fg", "skimage stereo_motorcycle (left) photo, screen-mapped"),
              Layer("wall", 5.0, near_bg, "bg", "rectangle (left part of the background, step at u = %.1f)" % step_u, "wall",
                    "skimage camera photo, tinted warm"),
              Layer("far", 13.0, bg_rect(W, H), "bg", "rectangle", "far", "skimage retina photo")]
    tex = {"fg": texture("stereo_motorcycle", (0.15, 0.2, 0.85, 0.8), full),
           "wall": texture("camera", (0.0, 0.0, 1.0, 1.0), full, tint=(1.0, 0.8, 0.6)),
           "far": texture("retina", (0.2, 0.2, 0.8, 0.8), full, gain=1.6)}
    spots = random_spots(rng, 5, W, H, outline_points(layers, W, H))
    spots += [(step_u + 2.5, 60.3, 2.2, 30.0, (1.0, 1.0, 0.95)), (step_u - 2.7, 140.6, 2.0, 20.0, (1.0, 0.85, 0.6))]
    add_highlights(tex["wall"], [sp for sp in spots if sp[0] < step_u])
    add_highlights(tex["far"], [sp for sp in spots if sp[0] >= step_u])
    s.append(dict(scene="ho_step", K_norm=20.0, layers=layers, tex=tex, mid=5.0,
                  description="(c) a foreground blob over a background of two planes with a depth step (a near wall on the "
                              "left, a far plane on the right), photo textures with highlights; focus_mid is on the wall"))

    # (d) a rotated text card running off the left edge, and a rotated rectangle off the bottom.
    rng = np.random.default_rng(seed * 1000 + 4)
    card = rect_poly(0.14 * W + 0.011, 0.36 * H + 0.023, 160.0, 96.0, -18.0)
    card_uv = (card[0], card[1] - card[0], card[3] - card[0])
    layers = [Layer("card", 1.6, card, "fg", "rotated rectangle 160x96 px, -18 deg", "card",
                    "skimage text image mapped onto the card (dark text on light paper)", uv=card_uv),
              Layer("panel", 2.4, rect_poly(0.74 * W + 0.017, 0.93 * H + 0.019, 110.0, 70.0, 24.0), "fg",
                    "rotated rectangle 110x70 px, 24 deg", "panel", "skimage coins photo, tinted gold, screen-mapped"),
              Layer("background", 10.0, bg_rect(W, H), "bg", "rectangle", "bg", "skimage astronaut photo (lower right crop) + 6 highlight spots")]
    tex = {"card": texture("text", (0.0, 0.0, 1.0, 1.0), (192, 320), tint=(0.95, 0.92, 0.85)),
           "panel": texture("coins", (0.0, 0.0, 1.0, 1.0), full, tint=(1.0, 0.8, 0.4)),
           "bg": texture("astronaut", (0.45, 0.4, 1.0, 1.0), full)}
    add_highlights(tex["bg"], random_spots(rng, 6, W, H, outline_points(layers, W, H)))
    s.append(dict(scene="ho_card", K_norm=17.0, layers=layers, tex=tex, mid=None,
                  description="(d) a rotated text card partly off the left edge and a rotated panel off the bottom edge, at two "
                              "depths, in front of a photo background with highlights"))

    # (e) small disks and stars over a highlight-rich background.
    rng = np.random.default_rng(seed * 1000 + 5)
    layers = [Layer("disk1", 1.6, disk_poly(0.22 * W, 0.3 * H, 14.0), "fg", "disk r = 14 px (polygon)", "shapes",
                    "skimage colorwheel, screen-mapped"),
              Layer("star1", 1.6, star_poly(0.55 * W, 0.62 * H, 18.0, 8.0, 5, 11.0), "fg", "5-point star r = 18 px (polygon)", "shapes",
                    "skimage colorwheel, screen-mapped"),
              Layer("disk2", 1.6, disk_poly(0.83 * W, 0.02 * H, 12.0), "fg", "disk r = 12 px, off the top edge (polygon)", "shapes",
                    "skimage colorwheel, screen-mapped"),
              Layer("disk3", 2.3, disk_poly(0.38 * W, 0.78 * H, 7.0), "fg", "disk r = 7 px (polygon)", "shapes2",
                    "skimage chelsea photo, screen-mapped"),
              Layer("star2", 2.3, star_poly(0.8 * W, 0.5 * H, 12.0, 5.0, 6, 3.0), "fg", "6-point star r = 12 px (polygon)", "shapes2",
                    "skimage chelsea photo, screen-mapped"),
              Layer("background", 12.0, bg_rect(W, H), "bg", "rectangle", "bg", "skimage hubble_deep_field photo + 12 highlight spots")]
    tex = {"shapes": texture("colorwheel", (0.0, 0.0, 1.0, 1.0), full),
           "shapes2": texture("chelsea", (0.0, 0.3, 1.0, 1.0), full),
           "bg": texture("hubble_deep_field", (0.3, 0.1, 0.8, 0.75), full, gain=1.5)}
    add_highlights(tex["bg"], random_spots(rng, 12, W, H, outline_points(layers, W, H), near_frac=0.4))
    s.append(dict(scene="ho_shapes", K_norm=21.0, layers=layers, tex=tex, mid=None,
                  description="(e) small foreground disks and stars (r = 7-18 px) at two depths over a highlight-rich "
                              "background (hubble deep field photo with 12 added highlights)"))

    # (f) three layers: a horse silhouette in front, a rotated panel in the middle, a far background.
    rng = np.random.default_rng(seed * 1000 + 6)
    from skimage import data, measure
    horse = ~data.horse()
    cont = max(measure.find_contours(np.pad(horse.astype(float), 2), 0.5), key=len)
    cont = measure.approximate_polygon(cont, 0.8)[:-1]  # (row, col), closed -> open
    scale = 0.55 * W / 400.0
    horse_poly = np.stack([0.02 * W + cont[:, 1] * scale + 0.013, 0.45 * H + cont[:, 0] * scale + 0.019], 1)
    layers = [Layer("horse", 1.5, horse_poly, "fg", "horse silhouette (polygon, from the skimage horse image)", "horse",
                    "skimage gravel texture, tinted dark brown, screen-mapped"),
              Layer("panel", 3.5, rect_poly(0.66 * W + 0.011, 0.42 * H + 0.017, 96.0, 72.0, -9.0), "fg",
                    "rotated rectangle 96x72 px, -9 deg (the middle layer)", "mid", "skimage clock photo, tinted blue"),
              Layer("background", 14.0, bg_rect(W, H), "bg", "rectangle", "bg", "skimage rocket photo (left crop) + 6 highlight spots")]
    tex = {"horse": texture("gravel", (0.0, 0.0, 1.0, 1.0), full, tint=(0.55, 0.35, 0.2)),
           "mid": texture("clock", (0.0, 0.0, 1.0, 1.0), full, tint=(0.6, 0.75, 1.0)),
           "bg": texture("rocket", (0.0, 0.0, 1.0, 0.6), full)}
    add_highlights(tex["bg"], random_spots(rng, 6, W, H, outline_points(layers, W, H)))
    s.append(dict(scene="ho_three_layers", K_norm=20.0, layers=layers, tex=tex, mid=3.5,
                  description="(f) three layers: a horse silhouette in front, a rotated panel in the middle (focus_mid is on "
                              "it), a far photo background with highlights"))
    return s


# ----------------------------------------------------------------------------- rendering

def to_world(u, v, z, W, H, f):
    return np.stack([(W / 2 - u) * z / f, (H / 2 - v) * z / f, np.full_like(u, z)], 1)


def write_ply(path, V, UV, F):
    with open(path, "wb") as fh:
        hdr = ("ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty float y\nproperty float z\n"
               "property float u\nproperty float v\nelement face %d\nproperty list uchar int vertex_indices\nend_header\n"
               % (len(V), len(F)))
        fh.write(hdr.encode())
        fh.write(np.hstack([V, UV]).astype("<f4").tobytes())
        for tri in F:
            fh.write(np.uint8(3).tobytes() + np.asarray(tri, "<i4").tobytes())


def build_meshes(sc, W, H, f, tmp):
    """PLY files of every layer: triangles wound so their normals face the camera."""
    paths = []
    for k, l in enumerate(sc["layers"]):
        P = l.poly
        tris = triangulate(P)
        F = []
        for a, b, c in tris:
            # Mitsuba emits on the side the normal faces: clockwise in (u, v) (v down) faces the camera.
            cr = (P[b][0] - P[a][0]) * (P[c][1] - P[a][1]) - (P[b][1] - P[a][1]) * (P[c][0] - P[a][0])
            F.append((a, c, b) if cr > 0 else (a, b, c))
        if l.uv is not None:
            o, e1, e2 = (np.asarray(x, float) for x in l.uv)
            UV = np.stack([(P - o) @ e1 / (e1 @ e1), (P - o) @ e2 / (e2 @ e2)], 1)
        else:
            UV = np.stack([(P[:, 0] + PAD) / (W + 2 * PAD), (P[:, 1] + PAD) / (H + 2 * PAD)], 1)
        path = os.path.join(tmp, "%s_%d.ply" % (sc["scene"], k))
        write_ply(path, to_world(P[:, 0], P[:, 1], l.z, W, H, f), UV, F)
        paths.append(path)
    return paths


def mitsuba_scene(mi, sc, plys, W, H, mode, sensor="perspective", spp=256, focus=None, aperture=None, sampler="multijitter"):
    """mode: aif | fg | alpha | bg (which layers emit what), or depth (the depth AOV)."""
    black = {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}
    d = {"type": "scene",
         "integrator": {"type": "aov", "aovs": "dd.y:depth"} if mode == "depth" else {"type": "path", "max_depth": 1},
         "sensor": {"type": sensor, "fov": FOV, "fov_axis": "x",
                    "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
                    "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                             "pixel_format": "rgb", "component_format": "float32"},
                    "sampler": ({"type": "stratified", "sample_count": 1, "jitter": False} if sampler == "center"
                                else {"type": sampler, "sample_count": spp})}}
    if sensor == "thinlens":
        d["sensor"].update(focus_distance=float(focus), aperture_radius=float(aperture))
    for k, (l, path) in enumerate(zip(sc["layers"], plys)):
        if mode == "bg" and l.role == "fg":
            continue
        shape = {"type": "ply", "filename": path, "bsdf": black}
        if mode == "alpha":
            if l.role == "fg":
                shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}
        elif mode in ("aif", "bg") or (mode == "fg" and l.role == "fg"):
            shape["emitter"] = {"type": "area", "radiance": {
                "type": "bitmap", "bitmap": sc["bitmaps"][l.tex_key], "raw": True,
                "filter_type": "bilinear", "wrap_mode": "clamp"}}
        d["layer%d" % k] = shape
    return mi.load_dict(d)


def render_passes(mi, scene, passes, seed0, spp):
    imgs = []
    for p in range(passes):
        imgs.append(np.array(mi.render(scene, seed=seed0 + p, spp=spp), dtype=np.float64)[:, :, :3])
    return imgs


def noise_stats(imgs):
    A = np.stack(imgs)
    P = len(imgs)
    sem = A.std(0, ddof=1) / math.sqrt(P)
    h = P // 2
    halves = 0.5 * float(np.sqrt(np.mean((A[:h].mean(0) - A[h:2 * h].mean(0)) ** 2)))
    return float(np.sqrt(np.mean(sem ** 2))), halves, float(np.percentile(np.sqrt(np.mean(sem ** 2, axis=2)), 99))


# ----------------------------------------------------------------------------- output

def round_mantissa(a, bits=15):
    a = np.ascontiguousarray(a, np.float32)
    u = a.view(np.uint32)
    drop = 23 - bits
    u = ((u + np.uint32(1 << (drop - 1))) & ~np.uint32((1 << drop) - 1)).astype(np.uint32)
    return u.view(np.float32)


def write_exr(path, img, rounded=False):
    import OpenEXR
    img = np.asarray(img, np.float32)
    if rounded:
        img = round_mantissa(img)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if img.ndim == 2:
        ch = {"Y": np.ascontiguousarray(img)}
    else:
        ch = {c: np.ascontiguousarray(img[:, :, i]) for i, c in enumerate("RGB")}
    with OpenEXR.File(header, ch) as fh:
        fh.write(path)


def read_exr(path):
    import OpenEXR
    with OpenEXR.File(path, separate_channels=True) as fh:
        ch = fh.channels()
        comp = fh.header()["compression"]
        if "Y" in ch:
            return ch["Y"].pixels.astype(np.float64), comp, ["Y"]
        return np.stack([ch[c].pixels for c in "RGB"], 2).astype(np.float64), comp, sorted(ch)


def srgb8(x):
    x = np.clip(x, 0, 1)
    return (np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055) * 255 + 0.5).astype(np.uint8)


# ----------------------------------------------------------------------------- one scene

def make_scene(mi, sc, args, W, H, f, tmp, log):
    t_scene = time.time()
    out = os.path.join(args.out, sc["scene"])
    os.makedirs(out, exist_ok=True)
    sidx = int(sc["index"])
    sc["bitmaps"] = {k: mi.Bitmap(v) for k, v in sc["tex"].items()}
    plys = build_meshes(sc, W, H, f, tmp)
    layers = sc["layers"]

    # Analytic depth: frontmost layer covering each pixel centre.
    vs, us = np.mgrid[0:H, 0:W].astype(np.float64) + 0.5
    depth = np.full((H, W), np.inf)
    bg_depth = np.full((H, W), np.inf)
    label = np.full((H, W), -1)
    for k, l in enumerate(layers):
        m = inside_polygon(l.poly, us, vs)
        closer = m & (l.z < depth)
        depth[closer] = l.z
        label[closer] = k
        if l.role == "bg":
            bg_depth = np.where(m & (l.z < bg_depth), l.z, bg_depth)
    assert np.isfinite(depth).all() and np.isfinite(bg_depth).all(), "a pixel sees no layer"
    zmin, zmax = float(depth.min()), float(depth.max())
    inv = lambda z: 1.0 / z
    span = inv(zmin) - inv(zmax)
    aperture = sc["K_norm"] / (f * span)
    K = aperture * f
    K_norm = K * span

    # Pinhole images.
    pin = {}
    pin_noise = {}
    t0 = time.time()
    for k, mode in enumerate(["aif", "fg", "alpha", "bg"]):
        scene = mitsuba_scene(mi, sc, plys, W, H, mode, spp=args.pinhole_spp)
        # The same sample seeds for the four images: the same sample positions in every pixel,
        # so aif = fg + (1 - alpha) bg holds to rounding wherever no edge crosses the pixel.
        imgs = render_passes(mi, scene, 2, 7919 * (sidx + 1), args.pinhole_spp)
        pin[mode] = np.mean(imgs, 0)
        pin_noise[mode] = float(np.sqrt(np.mean(((imgs[0] - imgs[1]) / 2) ** 2)))
    pinhole_time = time.time() - t0
    log("%s: pinhole images (4 x 2 x %d spp) in %.1f s" % (sc["scene"], args.pinhole_spp, pinhole_time))
    alpha = pin["alpha"][:, :, 0]

    # Depth against Mitsuba's depth AOV, one ray through each pixel centre.
    scene = mitsuba_scene(mi, sc, plys, W, H, "depth", sampler="center")
    t_aov = np.array(mi.render(scene, seed=0, spp=1), dtype=np.float64)
    t_aov = t_aov[:, :, -1] if t_aov.ndim == 3 else t_aov
    dx, dy = (W / 2 - us) / f, (H / 2 - vs) / f
    dz = 1.0 / np.sqrt(dx * dx + dy * dy + 1.0)
    near_clip = 0.01  # Mitsuba's default: rays start on the near-clip plane
    z_aov = near_clip + t_aov * dz
    rel = np.abs(z_aov - depth) / depth
    mismatch = rel > 1e-3
    depth_check = {"pixels_label_mismatch": int(mismatch.sum()),
                   "max_rel_err_elsewhere": float(rel[~mismatch].max()) if (~mismatch).any() else None}

    # Thin-lens ground truth.
    focus = {"focus_fg": zmin, "focus_mid": sc["mid"] if sc["mid"] else 2.0 / (inv(zmin) + inv(zmax)), "focus_bg": zmax}
    settings = []
    gts = {}
    for si, (name, zf) in enumerate(focus.items()):
        scene = mitsuba_scene(mi, sc, plys, W, H, "aif", sensor="thinlens", spp=args.spp_pass, focus=zf, aperture=aperture)
        t0 = time.time()
        imgs = []
        while True:
            imgs += render_passes(mi, scene, 1, 1_000_003 * (sidx + 1) + 1009 * si + len(imgs), args.spp_pass)
            if len(imgs) >= args.max_passes:
                break
            if len(imgs) >= args.min_passes and noise_stats(imgs)[0] <= args.target_noise:
                break
        rt = time.time() - t0
        gt = np.mean(imgs, 0)
        gts[name] = gt
        nr, nh, p99 = noise_stats(imgs)
        coc = {l.name: K * abs(inv(l.z) - inv(zf)) for l in layers}
        vis = np.unique(depth)
        coc_vis = [K * abs(inv(z) - inv(zf)) for z in vis]
        # Focus-plane check: pixels whose whole blur neighbourhood lies on the focus plane.
        r = int(math.ceil(max(coc_vis))) + 2
        on = np.isclose(depth, zf)
        from scipy.ndimage import minimum_filter
        ok = minimum_filter(on.astype(np.uint8), size=2 * r + 1, mode="constant", cval=0).astype(bool)
        fpc = {"pixels": int(ok.sum()),
               "rmse_gt_vs_aif": float(np.sqrt(np.mean((gt[ok] - pin["aif"][ok]) ** 2))) if ok.any() else None}
        settings.append({"name": name, "focus_distance": zf, "aperture_radius": aperture, "K_px_per_inv_depth": K,
                         "K_norm": K_norm, "focus_norm_disparity": (inv(zf) - inv(zmax)) / span,
                         "spp": args.spp_pass * len(imgs), "passes": len(imgs), "sampler": "multijitter",
                         "noise_rmse": nr, "noise_rmse_two_halves": nh, "noise_p99_pixel": p99,
                         "coc_px_visible_min": min(coc_vis), "coc_px_visible_max": max(coc_vis), "coc_px_per_layer": coc,
                         "render_time_s": round(rt, 1), "focus_plane_check": fpc})
        log("%s %s: z_f = %.3f, %d x %d spp, noise %.4f (two halves %.4f), max CoC %.1f px, %.1f s"
            % (sc["scene"], name, zf, len(imgs), args.spp_pass, nr, nh, max(coc_vis), rt))

    # Checks on the pinhole images.
    comp = pin["fg"] + (1 - alpha[..., None]) * pin["bg"]
    d = np.abs(comp - pin["aif"])
    # The background texture seen by a box-filtered pinhole: mean over the pixel of the bilinear
    # interpolant = separable [1 7 7 1]/16 of the texels, every second texel.
    bg_expect = np.zeros((H, W, 3))
    covered = np.zeros((H, W), bool)
    for k, l in enumerate(layers):
        if l.role != "bg":
            continue
        t = np.pad(sc["tex"][l.tex_key].astype(np.float64), ((1, 2), (1, 2), (0, 0)), mode="edge")
        wts = np.array([1, 7, 7, 1]) / 16
        rows = sum(wts[i] * t[i:i + t.shape[0] - 3] for i in range(4))
        both = sum(wts[i] * rows[:, i:i + rows.shape[1] - 3] for i in range(4))
        px = both[2 * PAD:2 * PAD + 2 * H:2, 2 * PAD:2 * PAD + 2 * W:2]
        m = inside_polygon(l.poly, us, vs) & (bg_depth == l.z)
        # Pixels whose whole square is on this plane (not cut by the step edge).
        from scipy.ndimage import binary_erosion
        m = binary_erosion(m, iterations=1, border_value=1)
        bg_expect[m] = px[m]
        covered |= m
    bg_err = pin["bg"][covered] - bg_expect[covered]
    checks = {"depth_vs_mitsuba_depth_aov": depth_check,
              "composite": {"desc": "aif vs fg + (1-alpha)*bg", "rmse": float(np.sqrt(np.mean(d ** 2))),
                            "max_abs": float(d.max()), "max_abs_where_aif_le_1": float(d[pin["aif"] <= 1].max())},
              "bg_vs_texture": {"desc": "bg pinhole vs the box-filtered bilinear texture (texture mapping and orientation)",
                                "pixels": int(covered.sum()), "rmse": float(np.sqrt(np.mean(bg_err ** 2))),
                                "max_abs_where_le_1": float(np.abs(bg_err)[bg_expect[covered] <= 1].max())},
              "alpha_range": [float(alpha.min()), float(alpha.max())]}

    # Write.
    write_exr(os.path.join(out, "aif.exr"), pin["aif"], rounded=True)
    write_exr(os.path.join(out, "fg.exr"), pin["fg"], rounded=True)
    write_exr(os.path.join(out, "bg.exr"), pin["bg"], rounded=True)
    write_exr(os.path.join(out, "fg_alpha.exr"), alpha)
    write_exr(os.path.join(out, "depth.exr"), depth)
    write_exr(os.path.join(out, "bg_depth.exr"), bg_depth)
    import imageio.v3 as iio
    iio.imwrite(os.path.join(out, "fg_alpha.png"), np.round(np.clip(alpha, 0, 1) * 65535).astype(np.uint16))
    for name, gt in gts.items():
        write_exr(os.path.join(out, "gt_%s.exr" % name), gt, rounded=True)
    disp = (1 / depth - 1 / zmax) / span
    sheet = [pin["aif"], np.repeat(disp[..., None], 3, 2), np.repeat(alpha[..., None], 3, 2), pin["bg"]] + list(gts.values())
    iio.imwrite(os.path.join(out, "preview.png"), np.concatenate([srgb8(np.pad(x, ((0, 0), (0, 4), (0, 0)), constant_values=1)) for x in sheet], 1))

    layer_meta = []
    for l in layers:
        P = l.poly
        layer_meta.append({"name": l.name, "z": l.z, "shape": l.shape, "role": l.role, "vertices": len(P),
                           "screen_bbox_px": [float(P[:, 0].min()), float(P[:, 1].min()), float(P[:, 0].max()), float(P[:, 1].max())],
                           "texture": l.texture_desc})
    params = {"scene": sc["scene"], "description": sc["description"], "width": W, "height": H, "fov_x_deg": FOV,
              "focal_px": f, "z_min": zmin, "z_max": zmax, "layers": layer_meta, "settings": settings,
              "pinhole": {"spp": 2 * args.pinhole_spp, "passes": 2, "sampler": "multijitter", "pixel_filter": "box",
                          "noise_rmse": {"aif": pin_noise["aif"], "fg": pin_noise["fg"], "fg_alpha": pin_noise["alpha"], "bg": pin_noise["bg"]},
                          "render_time_s": round(pinhole_time, 1)},
              "checks": checks, "renderer": "Mitsuba %s (%s)" % (getattr(mi, "__version__", getattr(mi, "MI_VERSION", "?")), mi.variant()),
              "generator": "drbokeh scripts/heldout/make_scenes.py --seed %d" % args.seed,
              "total_time_s": round(time.time() - t_scene, 1)}
    with open(os.path.join(out, "params.json"), "w") as fh:
        json.dump(params, fh, indent=1)

    # Read back: the format the bench loader expects.
    for n in ["aif", "fg", "bg"] + ["gt_" + k for k in gts]:
        img, comp_, chans = read_exr(os.path.join(out, n + ".exr"))
        assert img.shape == (H, W, 3) and "ZIP" in str(comp_) and chans == ["B", "G", "R"], n
    for n, ref in [("depth", depth), ("bg_depth", bg_depth), ("fg_alpha", alpha)]:
        img, comp_, chans = read_exr(os.path.join(out, n + ".exr"))
        assert chans == ["Y"] and np.allclose(img, ref.astype(np.float32)), n
    log("%s: wrote %s in %.1f s; depth AOV mismatches %d, composite rmse %.2e, bg vs texture rmse %.2e"
        % (sc["scene"], out, time.time() - t_scene, depth_check["pixels_label_mismatch"], checks["composite"]["rmse"],
           checks["bg_vs_texture"]["rmse"]))
    return params


# ----------------------------------------------------------------------------- lens checks

def lens_checks(mi, args, log):
    """The circle of confusion of a tiny emissive disk against K|1/z - 1/z_f|, and a thin-lens
    render of a textured plane in focus against the pinhole render."""
    res = {"coc": [], "plane_in_focus": None}
    Wc = Hc = 160
    f = Wc / (2 * math.tan(math.radians(FOV / 2)))
    with tempfile.TemporaryDirectory() as tmp:
        for (z, zf, A, off) in [(10.0, 2.0, 0.05, 0.0), (1.2, 8.0, 0.05, 30.0)]:
            P = disk_poly(Wc / 2 + off + 0.013, Hc / 2 - off / 2 + 0.011, 0.5, 24)
            l = Layer("spot", z, P, "fg", "disk", "w", "white")
            sc = {"scene": "coc", "layers": [l], "tex": {}, "bitmaps": {}}
            plys = build_meshes(sc, Wc, Hc, f, tmp)
            scene = mitsuba_scene(mi, sc, plys, Wc, Hc, "alpha", sensor="thinlens", spp=args.spp_pass, focus=zf, aperture=A)
            img = np.mean(render_passes(mi, scene, 2, 77, args.spp_pass), 0)[:, :, 0]
            v, u = np.mgrid[0:Hc, 0:Wc] + 0.5
            m = img.sum()
            cu, cv = (img * u).sum() / m, (img * v).sum() / m
            rho2 = ((u - cu) ** 2 + (v - cv) ** 2)
            # uniform disk: E[rho^2] = r^2/2; minus the spot's own (r0^2/2) and the pixel box (1/6).
            r_mom = math.sqrt(max(2 * ((img * rho2).sum() / m - 0.25 / 2 - 1 / 6), 0))
            r_pred = A * f * abs(1 / z - 1 / zf)
            pu, pv = Wc / 2 + off, Hc / 2 - off / 2
            res["coc"].append({"film": "%dx%d" % (Wc, Hc), "spot_z": z, "focus_z": zf, "aperture": A,
                               "predicted_r": r_pred, "second_moment_r": r_mom,
                               "centroid_offset_px": math.hypot(cu - pu, cv - pv)})
            log("CoC check: z %.1f focus %.1f A %.2f: predicted %.2f px, measured %.2f px" % (z, zf, A, r_pred, r_mom))
        # A textured plane exactly on the focus plane: thin lens == pinhole (to the noise).
        z = 4.0
        l = Layer("plane", z, bg_rect(Wc, Hc), "bg", "rectangle", "t", "")
        tex = texture("coffee", (0, 0, 1, 1), (2 * (Hc + 2 * PAD), 2 * (Wc + 2 * PAD)))
        add_highlights(tex, [(60.3, 70.2, 2.0, 20.0, (1, 1, 1))])
        sc = {"scene": "plane", "layers": [l], "tex": {"t": tex}, "bitmaps": {"t": mi.Bitmap(tex)}}
        plys = build_meshes(sc, Wc, Hc, f, tmp)
        a = np.mean(render_passes(mi, mitsuba_scene(mi, sc, plys, Wc, Hc, "aif", spp=256), 2, 5, 256), 0)
        b = np.mean(render_passes(mi, mitsuba_scene(mi, sc, plys, Wc, Hc, "aif", sensor="thinlens", spp=256, focus=z, aperture=0.2), 2, 9, 256), 0)
        res["plane_in_focus"] = {"z": z, "aperture": 0.2, "rmse_thinlens_vs_pinhole": float(np.sqrt(np.mean((a - b) ** 2))),
                                 "max_abs": float(np.abs(a - b).max())}
        log("plane in focus: thin lens vs pinhole RMSE %.2e" % res["plane_in_focus"]["rmse_thinlens_vs_pinhole"])
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="target/heldout", help="output folder (one subfolder per scene)")
    ap.add_argument("--seed", type=int, default=12, help="seed of highlights, blobs and sample seeds")
    ap.add_argument("--size", default="%dx%d" % (W_DEFAULT, H_DEFAULT), help="frame WxH")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (default: all six)")
    ap.add_argument("--spp-pass", type=int, default=SPP_PASS, help="samples per pixel of one ground-truth pass")
    ap.add_argument("--min-passes", type=int, default=2)
    ap.add_argument("--max-passes", type=int, default=6)
    ap.add_argument("--target-noise", type=float, default=0.0035, help="stop adding passes at this noise RMSE")
    ap.add_argument("--pinhole-spp", type=int, default=144, help="spp of each of the 2 passes of every pinhole image")
    ap.add_argument("--variant", default="scalar_rgb")
    ap.add_argument("--lens-checks", action="store_true", help="also run the CoC and plane-in-focus checks")
    args = ap.parse_args()
    for n in (args.spp_pass, args.pinhole_spp):
        if math.isqrt(n) ** 2 != n:
            ap.error("sample counts must be squares (the multijitter sampler rounds others up), got %d" % n)
    import mitsuba as mi
    mi.set_variant(args.variant)
    W, H = (int(x) for x in args.size.lower().split("x"))
    f = W / (2 * math.tan(math.radians(FOV / 2)))
    os.makedirs(args.out, exist_ok=True)
    t_all = time.time()
    log = lambda m: print("[%7.1f s] %s" % (time.time() - t_all, m), flush=True)
    defs = scene_defs(W, H, args.seed)
    for i, sc in enumerate(defs):
        sc["index"] = i
    want = [s for s in args.scenes.split(",") if s]
    summary = {"generator": "scripts/heldout/make_scenes.py", "args": vars(args), "scenes": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for sc in defs:
            if want and sc["scene"] not in want:
                continue
            p = make_scene(mi, sc, args, W, H, f, tmp, log)
            summary["scenes"][sc["scene"]] = {
                "total_time_s": p["total_time_s"],
                "settings": {s["name"]: {"passes": s["passes"], "noise_rmse": s["noise_rmse"], "render_time_s": s["render_time_s"],
                                         "coc_px_visible_max": s["coc_px_visible_max"]} for s in p["settings"]},
                "checks": p["checks"]}
    if args.lens_checks:
        summary["lens_checks"] = lens_checks(mi, args, log)
    summary["total_time_s"] = round(time.time() - t_all, 1)
    with open(os.path.join(args.out, "summary.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    log("done: %s" % os.path.join(args.out, "summary.json"))


if __name__ == "__main__":
    sys.exit(main())
