"""Oracle for tests/telea_opencv.rs: runs cv2.inpaint(..., INPAINT_TELEA) on a batch of cases.

Usage: telea.py MANIFEST.json
The manifest is a JSON list of cases, each {"image": path, "mask": path, "radius": float,
"dtype": "uint8" | "uint16" | "float32", "out": path}. Images are float32 .npy files holding the
values in the target dtype's units (codes for integer dtypes); masks are .npy, nonzero = fill.
Each result is written as a float32 .npy of the same shape.
"""
import json
import sys

import cv2
import numpy as np


def run(case):
    img = np.load(case["image"])
    mask = (np.load(case["mask"]) != 0).astype(np.uint8) * 255
    dtype = case["dtype"]
    if dtype == "uint8":
        src = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    elif dtype == "uint16":
        src = np.clip(np.rint(img), 0, 65535).astype(np.uint16)
    elif dtype == "float32":
        src = img.astype(np.float32)
    else:
        raise ValueError(f"unknown dtype {dtype}")
    out = cv2.inpaint(np.ascontiguousarray(src), mask, float(case["radius"]), cv2.INPAINT_TELEA)
    np.save(case["out"], out.astype(np.float32))


def main():
    with open(sys.argv[1]) as f:
        cases = json.load(f)
    for case in cases:
        run(case)


if __name__ == "__main__":
    main()
