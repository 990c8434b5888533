"""Oracle for tests/matting_pymatting.rs: PyMatting's closed-form matting (Levin et al. 2008).

Usage: closed_form.py MANIFEST.json
The manifest is a JSON list of cases, each {"image": path, "trimap": path, "out": path}: the
image an H x W x 3 float32 .npy in [0, 1], the trimap an H x W float32 .npy (1 foreground,
0 background, 0.5 unknown). Each alpha is written as an H x W float32 .npy.
"""
import json
import sys

import numpy as np
from pymatting import estimate_alpha_cf


def main():
    for case in json.load(open(sys.argv[1])):
        image = np.load(case["image"]).astype(np.float64)
        trimap = np.load(case["trimap"]).astype(np.float64)
        alpha = estimate_alpha_cf(image, trimap)
        np.save(case["out"], np.clip(alpha, 0.0, 1.0).astype(np.float32))


if __name__ == "__main__":
    main()
