#!/usr/bin/env python3
"""An estimator-like depth map from an exact one, for timing the pipeline on the input users
mostly have (docs/performance.md): the map reduced to 1/FACTOR by area averaging, blurred with a
Gaussian of SIGMA pixels at that size and resized back bilinearly, saved as float32 .npy.

    .venv/bin/python scripts/estimator_depth.py out/e2e-4032x3024/depth.exr out/e2e-4032x3024/depth_est.npy

Needs numpy and opencv (the test environment's, `scripts/setup-test-env.sh`).
"""
import argparse
import os

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("depth", help="the exact depth map (EXR, or .npy)")
    ap.add_argument("out", help="where to write the estimator-like map (.npy)")
    ap.add_argument("--factor", type=int, default=4, help="resolution reduction (default 4)")
    ap.add_argument("--sigma", type=float, default=2.0, help="blur at the reduced size, pixels (default 2)")
    a = ap.parse_args()
    d = np.load(a.depth) if a.depth.endswith(".npy") else cv2.imread(a.depth, cv2.IMREAD_UNCHANGED)
    if d is None:
        raise SystemExit(f"{a.depth}: cannot read a depth map")
    d = d.astype(np.float32)
    if d.ndim == 3:
        d = d[..., 0]
    h, w = d.shape
    small = cv2.resize(d, (max(1, w // a.factor), max(1, h // a.factor)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), a.sigma)
    np.save(a.out, cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR).astype(np.float32))


if __name__ == "__main__":
    main()
