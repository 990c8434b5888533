"""Times cv2.inpaint(INPAINT_TELEA) on the files written by examples/telea_timing.rs.
Usage: .venv/bin/python scripts/telea_cv_timing.py RADIUS [DIR]"""
import sys, time
import numpy as np, cv2

r = float(sys.argv[1])
d = sys.argv[2] if len(sys.argv) > 2 else "/tmp"
img = np.load(f"{d}/telea_img.npy").astype(np.uint8)
mask = (np.load(f"{d}/telea_mask.npy") > 0).astype(np.uint8)
times = []
for _ in range(3):
    t = time.perf_counter()
    cv2.inpaint(img, mask, r, cv2.INPAINT_TELEA)
    times.append(time.perf_counter() - t)
print(f"cv2.inpaint Telea r={r}: {sorted(times)[1]:.3f} s (median of 3, cv2 threads {cv2.getNumThreads()})")
