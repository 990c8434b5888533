#!/usr/bin/env python3
"""Checks the scene folders written by make_scenes.py, from the files alone.

For every folder: the files and EXR channels the format asks for (ZIP, float32; R, G, B or Y);
depth only takes the layers' z values, and z_min / z_max in params.json are its extremes;
depth <= bg_depth everywhere (a foreground is in front of the background);
fg_alpha.png equals fg_alpha.exr to 16 bits; alpha is 1 where the depth is a foreground
layer's, away from edges, and 0 two pixels away from any (up to a few pixels); aif = fg + (1 - alpha) bg, over all
pixels and away from the foreground's edge pixels (0 < alpha < 1, where a highlight cut by the
edge breaks the alpha model); each setting's K_norm, focus and CoC agree with the thin-lens
formulas; gt in focus matches aif (focus_plane_check). Prints one line per scene, exits 1 on
a failure.

    .venv-heldout/bin/python scripts/heldout/check_scenes.py target/heldout [--sheet=docs/heldout/scenes.png]

With --sheet, also writes the scenes' previews stacked at half size (8-bit sRGB, clipped).
"""
import json
import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from make_scenes import read_exr  # noqa: E402


def check(d):
    p = json.loads((d / "params.json").read_text())
    fails = []

    def req(cond, what):
        if not cond:
            fails.append(what)

    W, H = p["width"], p["height"]
    img = {}
    for n in ["aif", "fg", "bg"] + ["gt_" + s["name"] for s in p["settings"]]:
        a, comp, ch = read_exr(str(d / (n + ".exr")))
        req(a.shape == (H, W, 3) and "ZIP" in str(comp) and ch == ["B", "G", "R"], "%s: format" % n)
        req(np.isfinite(a).all() and (a >= 0).all(), "%s: finite, non-negative" % n)
        img[n] = a
    for n in ["depth", "bg_depth", "fg_alpha"]:
        a, comp, ch = read_exr(str(d / (n + ".exr")))
        req(a.shape == (H, W) and "ZIP" in str(comp) and ch == ["Y"], "%s: format" % n)
        img[n] = a
    import imageio.v3 as iio
    png = iio.imread(d / "fg_alpha.png")
    req(png.dtype == np.uint16 and np.abs(png / 65535.0 - img["fg_alpha"]).max() <= 0.5 / 65535 + 1e-7, "fg_alpha.png vs exr")
    depth, bgd, alpha = img["depth"], img["bg_depth"], img["fg_alpha"]
    zs = sorted({l["z"] for l in p["layers"]})
    req(all(np.isclose(depth, z).any() for z in np.unique(depth)) and set(np.round(np.unique(depth), 6)) <= set(np.round(zs, 6)),
        "depth takes only layer depths")
    req(math.isclose(depth.min(), p["z_min"], rel_tol=1e-6) and math.isclose(depth.max(), p["z_max"], rel_tol=1e-6), "z_min / z_max")
    req((depth <= bgd + 1e-6).all(), "depth <= bg_depth")
    fg = depth < bgd - 1e-6
    from scipy.ndimage import binary_dilation, binary_erosion
    inner = binary_erosion(fg, iterations=2, border_value=1)
    far = ~binary_dilation(fg, iterations=2)
    # A few pixels may disagree where a gap between two foreground shapes runs between pixel
    # centres (shared thin_bars has one).
    bad_alpha = int((alpha[inner] <= 1 - 2e-3).sum() + (alpha[far] >= 2e-3).sum())
    req(bad_alpha <= max(3, W * H // 2000), "alpha vs depth labels (%d pixels)" % bad_alpha)
    comp = img["fg"] + (1 - alpha[..., None]) * img["bg"]
    err = comp - img["aif"]
    edge = (alpha > 1e-3) & (alpha < 1 - 1e-3)
    rm_all = float(np.sqrt(np.mean(err ** 2)))
    rm_in = float(np.sqrt(np.mean(err[~edge] ** 2)))
    req(rm_in < 5e-3, "composite away from edges")
    f = W / (2 * math.tan(math.radians(p["fov_x_deg"] / 2)))
    req(math.isclose(f, p["focal_px"], rel_tol=1e-9), "focal_px")
    span = 1 / p["z_min"] - 1 / p["z_max"]
    for s in p["settings"]:
        K = s["aperture_radius"] * f
        req(math.isclose(K, s["K_px_per_inv_depth"], rel_tol=1e-9) and math.isclose(K * span, s["K_norm"], rel_tol=1e-9), s["name"] + ": K")
        req(math.isclose((1 / s["focus_distance"] - 1 / p["z_max"]) / span, s["focus_norm_disparity"], rel_tol=1e-9, abs_tol=1e-12),
            s["name"] + ": focus")
        vis = [K * abs(1 / z - 1 / s["focus_distance"]) for z in np.unique(depth)]
        req(math.isclose(max(vis), s["coc_px_visible_max"], rel_tol=1e-6), s["name"] + ": coc_px_visible_max")
        fpc = s["focus_plane_check"]
        if fpc["pixels"]:
            req(fpc["rmse_gt_vs_aif"] < 5 * max(s["noise_rmse"], 1e-3), s["name"] + ": gt in focus vs aif")
    print("%-16s %s  composite rmse all %.2e, away from the %d edge pixels %.2e; noise %s; %s" % (
        p["scene"], "ok  " if not fails else "FAIL", rm_all, int(edge.sum()), rm_in,
        " ".join("%s %.4f" % (s["name"], s["noise_rmse"]) for s in p["settings"]),
        "; ".join(fails) if fails else "focus-plane rmse " + " ".join(
            "%.1e" % s["focus_plane_check"]["rmse_gt_vs_aif"] for s in p["settings"] if s["focus_plane_check"]["pixels"])))
    return not fails


def contact_sheet(dirs, path):
    """The scenes' preview.png (aif, disparity, alpha, bg, gt per setting) stacked, at half size."""
    import imageio.v3 as iio
    rows = []
    for d in dirs:
        im = iio.imread(d / "preview.png").astype(np.float32)
        h, w = im.shape[0] // 2 * 2, im.shape[1] // 2 * 2
        rows.append(im[:h:2, :w:2] * 0.25 + im[1:h:2, :w:2] * 0.25 + im[:h:2, 1:w:2] * 0.25 + im[1:h:2, 1:w:2] * 0.25)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 3), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    iio.imwrite(path, np.concatenate(rows, 0).round().astype(np.uint8))


def main():
    args = [a for a in sys.argv[1:] if not a.startswith("--sheet=")]
    sheet = [a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("--sheet=")]
    root = pathlib.Path(args[0] if args else "target/heldout")
    dirs = sorted(x.parent for x in root.glob("*/params.json"))
    ok = all([check(d) for d in dirs])
    if sheet and dirs:
        contact_sheet(dirs, sheet[0])
    print("%d scene(s) checked: %s" % (len(dirs), "all ok" if ok else "FAILURES"))
    sys.exit(0 if ok and dirs else 1)


if __name__ == "__main__":
    main()
