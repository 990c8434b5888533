"""Reads and writes the files of `examples/io_timing` with OpenCV and (when installed) Pillow,
to compare with drbokeh's own readers and writers on the same bytes.

    cargo run --release --example io_timing -- 4032 3024 5      # makes out/io-timing-4032x3024
    .venv/bin/python scripts/io_timing_ref.py out/io-timing-4032x3024 5

Reads time `cv2.imread(..., IMREAD_UNCHANGED)` (EXR needs OPENCV_IO_ENABLE_OPENEXR=1, set
here) and `PIL.Image.open(..).load()`: decoding to the stored integers or floats only, no
conversion to linear float (drbokeh's figures include that). Writes time `cv2.imwrite` of
the decoded 8/16-bit array as PNG (OpenCV's default compression level 1) and of float RGB
as EXR (OpenCV's default ZIP). Prints `CASE  median ms  min ms`, medians of N.
"""
import os
import sys
import time

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")
import cv2  # noqa: E402
import numpy as np  # noqa: E402

try:
    from PIL import Image  # noqa: E402
except ImportError:
    Image = None


def timed(runs, f):
    t = []
    for _ in range(runs):
        s = time.perf_counter()
        f()
        t.append((time.perf_counter() - s) * 1e3)
    t.sort()
    return t[len(t) // 2], t[0]


def main():
    d = sys.argv[1]
    runs = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    print(f"OpenCV {cv2.__version__} ({cv2.getNumThreads()} threads), Pillow {Image.__version__ if Image else 'not installed'}, median of {runs}")
    files = ["png8.png", "png16.png", "jpeg.jpg", "tiff8.tif", "tiff16.tif", "exr32.exr", "exr16.exr"]
    for name in files:
        p = os.path.join(d, name)
        med, lo = timed(runs, lambda: cv2.imread(p, cv2.IMREAD_UNCHANGED))
        print(f"cv2 read {name.split('.')[0]:8} {med:9.1f} ms {lo:9.1f} ms")
        if Image is not None and not name.endswith(".exr"):
            med, lo = timed(runs, lambda: Image.open(p).load())
            print(f"PIL read {name.split('.')[0]:8} {med:9.1f} ms {lo:9.1f} ms")
    out = os.path.join(d, "written_ref")
    os.makedirs(out, exist_ok=True)
    for name in ["png8.png", "png16.png"]:
        a = cv2.imread(os.path.join(d, name), cv2.IMREAD_UNCHANGED)
        q = os.path.join(out, name)
        med, lo = timed(runs, lambda: cv2.imwrite(q, a))
        print(f"cv2 write {name.split('.')[0]:7} {med:9.1f} ms {lo:9.1f} ms {os.path.getsize(q) / 1e6:8.1f} MB")
        if Image is not None:
            im = Image.open(os.path.join(d, name))
            im.load()
            med, lo = timed(runs, lambda: im.save(q, compress_level=1))
            print(f"PIL write {name.split('.')[0]:7} {med:9.1f} ms {lo:9.1f} ms {os.path.getsize(q) / 1e6:8.1f} MB")
    f = cv2.imread(os.path.join(d, "exr32.exr"), cv2.IMREAD_UNCHANGED).astype(np.float32)
    q = os.path.join(out, "exr32.exr")
    med, lo = timed(runs, lambda: cv2.imwrite(q, f))
    print(f"cv2 write exr32   {med:9.1f} ms {lo:9.1f} ms {os.path.getsize(q) / 1e6:8.1f} MB")


if __name__ == "__main__":
    main()
