"""The memory-bound references for a render of WIDTH x HEIGHT at CoC radius COC: OpenCV's
GaussianBlur (sigma = COC/3) and box blur (cv2.blur, side 2*COC+1) of a float32 RGB image of
that size, medians of RUNS, in one process with OpenCV's default threads. Compare with
`cargo run --release --example timing -- WIDTH HEIGHT COC fast2 --profile physical` run right
before or after (issue 14: the render should cost no more than the Gaussian blur).
Usage: .venv/bin/python scripts/blur_reference_timing.py [WIDTH HEIGHT COC RUNS]"""
import sys, time
import numpy as np, cv2

w, h, coc, runs = (int(a) for a in (sys.argv[1:5] + ["4032", "3024", "64", "5"][len(sys.argv[1:5]):]))
img = np.random.default_rng(1).random((h, w, 3), dtype=np.float32)


def median_time(f):
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        f()
        times.append(time.perf_counter() - t)
    return sorted(times)[len(times) // 2]


g = median_time(lambda: cv2.GaussianBlur(img, (0, 0), coc / 3.0))
b = median_time(lambda: cv2.blur(img, (2 * coc + 1, 2 * coc + 1)))
print(f"{w}x{h} float32 RGB, CoC {coc}: cv2.GaussianBlur(sigma={coc / 3.0:.2f}) {g:.3f} s, "
      f"cv2.blur({2 * coc + 1}) {b:.3f} s (medians of {runs}, cv2 threads {cv2.getNumThreads()})")
