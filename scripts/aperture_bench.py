#!/usr/bin/env python3
"""Scores every aperture shape against its own thin-lens truth and writes the table of
docs/guide.md (*Aperture shapes*, between the aperture-bench markers).

For each shape and seed: `drbokeh bench --methods sliced` on 12 generated scenes of 128 x 128
(1024 rays per pixel; one exact layer per depth plane, so the layered model is exact and what
is left is the lens model and the kernels), the tracer sampling the same aperture, on the
linear view and on its 8-bit sRGB encoding (clipped at white: what clipping costs each shape
with perfect layers; no highlights stage runs on exact layers). Reports go to
docs/aperture-bench/seedS/SHAPE/ (report.md, report.csv).

    scripts/aperture_bench.py            # run the benches, then write the table
    scripts/aperture_bench.py --table    # rewrite the table from the stored reports
    scripts/aperture_bench.py --only "--chromatic 0.05"   # run one shape's benches (repeatable), then the table
"""
import csv, os, subprocess, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "docs", "aperture-bench")
STAR = os.path.join(ROOT, "out", "aperture", "star.png")
SHAPES = [
    ("disc", []),
    ("blades:6", ["--aperture", "blades:6"]),
    ("blades:5,rotation=90", ["--aperture", "blades:5,rotation=90"]),
    ("blades:7,curvature=0.5", ["--aperture", "blades:7,curvature=0.5"]),
    ("--anamorphic 1.5", ["--anamorphic", "1.5"]),
    ("image:star.png", ["--aperture", "image:" + os.path.relpath(STAR, ROOT)]),
    ("--chromatic 0.05", ["--chromatic", "0.05"]),
    ("--cat-eye 1", ["--cat-eye", "1"]),
    ("--bubble 0.5", ["--bubble", "0.5"]),
    ("--bubble -0.5", ["--bubble", "-0.5"]),
    ("--cat-eye 1 --bubble 0.5", ["--cat-eye", "1", "--bubble", "0.5"]),
    ("image:star.png --cat-eye 1", ["--aperture", "image:" + os.path.relpath(STAR, ROOT), "--cat-eye", "1"]),
]
SEEDS = [1, 2]


def tag(name):
    return "".join(c if c.isalnum() else "_" for c in name).strip("_")


def star():
    """The five-pointed star of scripts/aperture_shapes.sh, 128 x 128 grey PNG."""
    import math, struct, zlib
    n, s = 128, 8
    rows = []
    v = []
    for k in range(10):
        r = 1.0 if k % 2 == 0 else 0.45
        t = math.pi / 2 + math.pi * k / 5
        v.append((r * math.cos(t), r * math.sin(t)))
    def inside(x, y):
        c = False
        for i in range(10):
            (x1, y1), (x2, y2) = v[i], v[(i + 1) % 10]
            if (y1 > y) != (y2 > y) and x < x1 + (y - y1) * (x2 - x1) / (y2 - y1):
                c = not c
        return c
    for row in range(n):
        line = bytearray([0])
        for col in range(n):
            hit = sum(inside(-1 + 2 * (col + (i + 0.5) / s) / n, 1 - 2 * (row + (j + 0.5) / s) / n) for i in range(s) for j in range(s))
            line.append(round(255 * hit / (s * s)))
        rows.append(bytes(line))
    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    os.makedirs(os.path.dirname(STAR), exist_ok=True)
    with open(STAR, "wb") as f:
        f.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", n, n, 8, 0, 0, 0, 0)) + chunk(b"IDAT", zlib.compress(b"".join(rows))) + chunk(b"IEND", b""))


def run(only=None):
    subprocess.run(["cargo", "build", "--release", "--locked", "-q", "--bin", "drbokeh"], cwd=ROOT, check=True)
    star()
    for seed in SEEDS:
        for name, flags in SHAPES:
            if only is not None and name not in only:
                continue
            out = os.path.join(OUT, f"seed{seed}", tag(name))
            cmd = [os.path.join(ROOT, "target", "release", "drbokeh"), "bench", "--methods", "sliced", "--scenes", "12", "--size", "128x128",
                   "--spp", "1024", "--repeats", "1", "--crops", "0", "--inputs", "linear,srgb8", "--seed", str(seed), "--out", os.path.relpath(out, ROOT)] + flags
            print(" ".join(cmd[1:]), flush=True)
            subprocess.run(cmd, cwd=ROOT, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            plot = os.path.join(out, "error_vs_time.png")
            if os.path.exists(plot):
                os.remove(plot)


def mean_psnr(seed, name, variant, input="linear"):
    with open(os.path.join(OUT, f"seed{seed}", tag(name), "report.csv")) as f:
        vals = [float(r["psnr_linear"]) for r in csv.DictReader(f)
                if r["method"] == "drbokeh-sliced" and r["variant"] == variant and r["input"] == input]
    return sum(vals) / len(vals)


def table():
    lines = ["| aperture | seed 1: exact / fast (linear dB) | seed 2: exact / fast | fast, against the disc (seed 1 / 2) | 8-bit input: fast (seed 1 / 2) |",
             "| --- | ---: | ---: | ---: | ---: |"]
    disc = {s: mean_psnr(s, "disc", "physical-fast-q2") for s in SEEDS}
    for name, _ in SHAPES:
        cells = []
        for s in SEEDS:
            cells.append(f"{mean_psnr(s, name, 'physical-exact'):.2f} / {mean_psnr(s, name, 'physical-fast-q2'):.2f}")
        delta = " / ".join(f"{mean_psnr(s, name, 'physical-fast-q2') - disc[s]:+.2f}" for s in SEEDS)
        clipped = " / ".join(f"{mean_psnr(s, name, 'physical-fast-q2', 'srgb8'):.2f}" for s in SEEDS)
        lines.append(f"| `{name}` | {cells[0]} | {cells[1]} | {delta if name != 'disc' else '—'} | {clipped} |")
    guide = os.path.join(ROOT, "docs", "guide.md")
    text = open(guide).read()
    a, b = "<!-- aperture-bench -->\n", "<!-- /aperture-bench -->"
    i, j = text.index(a) + len(a), text.index(b)
    open(guide, "w").write(text[:i] + "\n".join(lines) + "\n" + text[j:])
    print("\n".join(lines))


if __name__ == "__main__":
    if "--only" in sys.argv:
        # Repeatable: --only A --only B runs both.
        run([a for k, a in zip(sys.argv, sys.argv[1:]) if k == "--only"])
    elif "--table" not in sys.argv:
        run()
    table()
