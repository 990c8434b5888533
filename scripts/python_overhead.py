#!/usr/bin/env python3
"""Issue 37's overhead goal: a 1 MP `render_layers` from Python against the library's own
render of the same layers.

The library's time is one `Refocuser::render` of layers already in memory
(`examples/refocus.rs`: `Pipeline::render_layers` on borrowed layers, the call the binding
makes); the Python time is the whole `drbokeh.render_layers` call (the arrays checked and
rendered where NumPy keeps them, the result handed back without a copy). Each side renders once to warm up,
then N times in the same process (the Python interpreter; one `refocus` process); three such
rounds, the sides alternated; medians. The render stage `drbokeh render --json` reports is
printed too (the kernels alone, in a fresh process).

    cargo build --release --example refocus
    .venv/bin/python scripts/python_overhead.py [N [ROUNDS]]

ROUNDS (default 3) rounds of N renders per side; also printed, the median over the rounds of
each round's ratio (the two sides of a round ran within seconds of each other, so a slow
minute of this shared machine moves both).

Also printed: the interpreter's resident memory after the Python side's renders (what the
extension's allocator keeps for the next render) and after `drbokeh.release_memory()`, and
its peak.
"""

import json
import pathlib
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

import drbokeh

ROOT = pathlib.Path(__file__).resolve().parents[1]
BIN = ROOT / "target" / "release" / "drbokeh"
REFOCUS = ROOT / "target" / "release" / "examples" / "refocus"


def resident_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 5
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    h, w = 1000, 1000
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:h, 0:w]
    front_a = ((((yy - 500) ** 2 + (xx - 400) ** 2) < 250**2) * 1.0)[..., None]
    front = np.concatenate([rng.uniform(0, 1, (h, w, 3)), front_a, np.full((h, w, 1), 0.9)], axis=2).astype(np.float32)
    back = np.concatenate([rng.uniform(0, 1, (h, w, 3)), np.ones((h, w, 1)), (xx / w * 0.5)[..., None]], axis=2).astype(np.float32)
    focus, blur = 0.9, 30.0
    with tempfile.TemporaryDirectory() as d:
        d = pathlib.Path(d)
        np.save(d / "f.npy", front)
        np.save(d / "b.npy", back)
        py, lib, stage, ratios = [], [], [], []
        foci = ",".join([str(focus)] * (n + 1))
        for _ in range(rounds):
            # Each side warm in its own process: one render first, then n timed ones.
            drbokeh.render_layers([front, back], focus, blur)
            for _ in range(n):
                t = time.perf_counter()
                drbokeh.render_layers([front, back], focus, blur)
                py.append((time.perf_counter() - t) * 1e3)
            out = subprocess.run([str(REFOCUS), str(blur), foci, "f.npy", "b.npy"], cwd=d, capture_output=True, text=True, check=True)
            lib += [float(l.split(": ")[1].split(" s")[0]) * 1e3 for l in out.stdout.splitlines() if l.startswith("focus")][1:]
            out = subprocess.run([str(BIN), "render", "--layer", "f.npy", "--layer", "b.npy", "--focus", str(focus), "--blur",
                                  str(blur), "-o", "o.npy", "--json"], cwd=d, capture_output=True, text=True, check=True)
            ratios.append(np.median(py[-n:]) / np.median(lib[-n:]))
            rep = json.loads(out.stdout)
            stage.append(next(s["ms"] for s in rep["stages"] if s["name"] == "render"))
    mp, ml, ms = (float(np.median(v)) for v in (py, lib, stage))
    runs = lambda v: ", ".join(f"{x:.0f}" for x in v)  # noqa: E731
    kept = resident_mb()
    drbokeh.release_memory()
    released = resident_mb()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"1 MP, 2 layers, K = {blur}, focus {focus}: {rounds} rounds of {n} warm renders per side, the sides alternated")
    print(f"drbokeh.render_layers (Python, whole call): median {mp:.1f} ms  ({runs(py)})")
    print(f"library call (Refocuser::render):            median {ml:.1f} ms  ({runs(lib)})")
    print(f"render stage alone (drbokeh render --json):  median {ms:.1f} ms  ({runs(stage)})")
    print(f"Python / library call: {mp / ml:.3f} ({(mp / ml - 1) * 100:+.1f}%)")
    rr = float(np.median(ratios))
    print(f"median of the rounds' ratios: {rr:.3f} ({(rr - 1) * 100:+.1f}%)  ({', '.join(f'{r:.3f}' for r in ratios)})")
    print(f"interpreter resident: {kept:.0f} MB after the renders, {released:.0f} MB after release_memory(); peak {peak:.0f} MB")


if __name__ == "__main__":
    main()
