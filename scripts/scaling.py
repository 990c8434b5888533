#!/usr/bin/env python3
"""Thread scaling of each stage (issue 39), measured in one window on this machine.

    python3 scripts/scaling.py [--threads 1,2,4] [--runs 3] [--size 4032x3024] [--no-build]
                               [--bin DIR] [--label TEXT] [--out FILE] [--readme ANCHOR]
                               [--work DIR] [--no-gaussian]

For every thread count N it times, one after the other and `--runs` times each (medians):
- the end-to-end command of `scripts/e2e_timing.sh` (PNG photo, EXR depth, PNG matte, focus on
  the subject, K = 64, classical stages, 8-bit PNG out) with `--threads N`: wall time, peak RSS
  of the process (from wait4), and each stage's time from `--json`;
- the render from the same scene's saved layers (`render --layer fg --layer bg`), wall time;
- where OpenCV imports, cv2.GaussianBlur sigma 21 of the same photo as float32 RGB, with
  `cv2.setNumThreads(N)`: the reference the issue compares the tool with.

Then prints, per stage, the time at each N, the speed-up T1/TN, the parallel efficiency
T1/(N TN), and the serial fraction that Amdahl's law gives from the 1- and 2-thread times,
s = 2 T2/T1 - 1 (so a 2-core machine still tells where the serial time is). It also checks
that the output PNG is byte-identical at every thread count.

With `--out FILE` the table is written there; `--readme ANCHOR` also copies it into docs/performance.md
between `<!-- ANCHOR -->` anchors (`--paste FILE --readme ANCHOR` copies a table measured
elsewhere, e.g. on a lent many-core machine, without measuring). `--bin DIR` takes `drbokeh` and `make_scene` from DIR (a
machine without cargo: build here, carry the two binaries). Figures are medians of this run's
window only; the machine's name and core count head the table.
"""
import argparse
import hashlib
import json
import os
import pathlib
import platform
import statistics
import subprocess
import sys
import time

root = pathlib.Path(__file__).resolve().parent.parent
os.chdir(root)
COC, FOCUS, SIGMA = 64, 1, 21


def run_rss(cmd):
    """Runs cmd with os.wait4 so that the peak RSS is this child's, not the max of all children."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    # The JSON report is small; read it before waiting so the pipe never fills.
    out = p.stdout.read()
    err = p.stderr.read()
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed ({p.returncode}):\n{err.decode(errors='replace')}")
    return wall, usage.ru_maxrss * 1024, out.decode()


def med(xs):
    return statistics.median(xs)


def cpu_name():
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def gaussian_times(photo, threads, runs):
    """cv2.GaussianBlur sigma 21 of the photo as float32 RGB at each thread count, or None."""
    try:
        import cv2
        import numpy as np
    except ImportError:
        return None
    img = cv2.imread(str(photo), cv2.IMREAD_COLOR).astype(np.float32) / 255.0
    res = {}
    for n in threads:
        cv2.setNumThreads(n)
        ts = []
        for _ in range(runs):
            t = time.perf_counter()
            cv2.GaussianBlur(img, (0, 0), SIGMA)
            ts.append(time.perf_counter() - t)
        res[n] = med(ts)
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    cores = os.cpu_count() or 1
    default = sorted({1, 2, *[2 ** k for k in range(1, 8) if 2 ** k <= cores], cores})
    ap.add_argument("--threads", default=",".join(map(str, default)), help="thread counts (default: 1, 2, 4, ... cores)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--size", default="4032x3024")
    ap.add_argument("--bin", help="folder with drbokeh and make_scene (default: build target/release)")
    ap.add_argument("--no-build", action="store_true")
    ap.add_argument("--label", default=None, help="the machine's description in the table's heading")
    ap.add_argument("--out", help="write the table (markdown) to this file")
    ap.add_argument("--readme", help="copy the table into docs/performance.md between <!-- ANCHOR --> anchors")
    ap.add_argument("--work", default=None, help="scene folder (default out/e2e-WxH)")
    ap.add_argument("--no-gaussian", action="store_true", help="skip the OpenCV reference")
    ap.add_argument("--paste", help="with --readme: copy this table file into README.md, measure nothing")
    a = ap.parse_args()
    if a.paste:
        if not a.readme:
            sys.exit("--paste needs --readme ANCHOR")
        to_readme(pathlib.Path(a.paste).read_text().rstrip("\n"), a.readme)
        return 0
    threads = [int(x) for x in a.threads.split(",")]
    if threads[0] != 1 or (len(threads) > 1 and threads[1] != 2):
        sys.exit("--threads must start with 1,2 (the serial fraction comes from them)")
    w, h = (int(x) for x in a.size.split("x"))

    if a.bin:
        drbokeh, make_scene = pathlib.Path(a.bin) / "drbokeh", pathlib.Path(a.bin) / "make_scene"
    else:
        if not a.no_build:
            subprocess.run(["cargo", "build", "--release", "--quiet", "--bin", "drbokeh", "--example", "make_scene"], check=True)
        drbokeh, make_scene = pathlib.Path("target/release/drbokeh"), pathlib.Path("target/release/examples/make_scene")
    work = pathlib.Path(a.work or f"out/e2e-{w}x{h}")
    if not (work / "image.png").exists():
        subprocess.run([str(make_scene), str(work), str(w), str(h)], check=True, capture_output=True)
    scene = ["render", str(work / "image.png"), "--depth", str(work / "depth.exr"), "--matte", str(work / "matte.png"),
             "--focus", str(FOCUS), "--blur", str(COC)]
    layers = work / "scaling-layers"
    subprocess.run([str(drbokeh), *scene, "-o", str(work / "scaling-bokeh.png"), "--save-layers", str(layers)],
                   check=True, capture_output=True)
    layer_cmd = ["render", "--layer", str(layers / "0_fg.exr"), "--layer", str(layers / "1_bg.exr"),
                 "--focus", str(FOCUS), "--blur", str(COC)]

    e2e, rss, stages, digests, from_layers = {}, {}, {}, {}, {}
    for n in threads:
        walls, peaks, per_stage = [], [], {}
        for i in range(a.runs):
            out = work / f"scaling-{n}.png"
            wall, peak, report = run_rss([str(drbokeh), *scene, "-o", str(out), "--json", "--threads", str(n)])
            walls.append(wall)
            peaks.append(peak)
            for s in json.loads(report).get("stages", []):
                if s.get("status") == "ran":
                    per_stage.setdefault(s["name"], []).append(s.get("ms", 0.0) / 1e3)
            digests.setdefault(n, hashlib.sha256(out.read_bytes()).hexdigest())
        e2e[n], rss[n] = med(walls), max(peaks)
        stages[n] = {k: med(v) for k, v in per_stage.items()}
        lw = [run_rss([str(drbokeh), *layer_cmd, "-o", str(work / f"scaling-layers-{n}.png"), "--threads", str(n)])[0]
              for _ in range(a.runs)]
        from_layers[n] = med(lw)
        print(f"{n:3} threads: end to end {e2e[n]:.3f} s, peak {rss[n] / 2**30:.2f} GiB, from layers {from_layers[n]:.3f} s",
              file=sys.stderr, flush=True)
    gauss = None if a.no_gaussian else gaussian_times(work / "image.png", threads, a.runs)

    names = list(stages[threads[0]])
    rows = [("end to end (wall)", e2e)] + [(k, {n: stages[n].get(k, 0.0) for n in threads}) for k in names]
    if {"fill_depth", "inpaint"} <= set(names):
        # The depth fill runs beside the background fill's preparation, so their reported
        # times overlap; their sum is the peel's wall time.
        rows.append(("fill_depth + inpaint (they overlap)", {n: stages[n].get("fill_depth", 0.0) + stages[n].get("inpaint", 0.0) for n in threads}))
    rows.append(("render from saved layers (wall)", from_layers))
    if gauss:
        rows.append(("cv2.GaussianBlur sigma 21 (float32 RGB)", gauss))

    label = a.label or f"{cpu_name()}, {cores} cores"
    lines = [f"Thread scaling, {w}x{h} ({w * h / 1e6:.1f} MP), focus {FOCUS}, K {COC}, classical stages; "
             f"{label}; medians of {a.runs} per cell, one window ({time.strftime('%Y-%m-%d')}).", ""]
    head = "| stage | " + " | ".join(f"{n} thr" for n in threads) + " | speed-up at " + str(threads[-1]) + \
           " | efficiency at " + str(threads[-1]) + " | serial fraction (1 vs 2) |"
    lines += [head, "|" + "---|" * (len(threads) + 4)]
    for name, t in rows:
        t1, tn, n_max = t[threads[0]], t[threads[-1]], threads[-1]
        speed = t1 / tn if tn > 0 else float("nan")
        serial = 2 * t[2] / t1 - 1 if 2 in t and t1 > 0 else float("nan")
        cells = " | ".join(f"{t[n] * 1e3:.0f} ms" for n in threads)
        lines.append(f"| {name} | {cells} | {speed:.2f}x | {speed / n_max:.0%} | {max(serial, 0.0):.0%} |")
    lines.append("")
    peak_cells = ", ".join(f"{n}: {rss[n] / 2**30:.2f}" for n in threads)
    lines.append(f"Peak RSS (GiB) by threads: {peak_cells} ({rss[threads[-1]] / rss[threads[0]]:.2f}x the 1-thread peak).")
    if gauss:
        n = threads[-1]
        lines.append(f"At {n} threads: end to end / Gaussian = {e2e[n] / gauss[n]:.1f}x, "
                     f"from layers / Gaussian = {from_layers[n] / gauss[n]:.1f}x.")
    same = len(set(digests.values())) == 1
    lines.append("Output PNG " + ("byte-identical at every thread count." if same else
                 "DIFFERS between thread counts: " + ", ".join(f"{n}: {d[:12]}" for n, d in digests.items())))
    table = "\n".join(lines)
    print(table)
    if a.out:
        pathlib.Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        pathlib.Path(a.out).write_text(table + "\n")
    if a.readme:
        to_readme(table, a.readme)
    return 0 if same else 1


def to_readme(table, anchor):
    """Puts `table` between docs/performance.md's two `<!-- anchor -->` lines."""
    readme = pathlib.Path("docs/performance.md").read_text()
    tag = f"<!-- {anchor} -->"
    parts = readme.split(tag)
    if len(parts) != 3:
        sys.exit(f"docs/performance.md needs two {tag} anchors")
    pathlib.Path("docs/performance.md").write_text(parts[0] + tag + "\n" + table + "\n" + tag + parts[2])


if __name__ == "__main__":
    sys.exit(main())
