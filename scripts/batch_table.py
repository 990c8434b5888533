#!/usr/bin/env python3
"""Issue 43's throughput table, from the logs of `scripts/batch_device.sh` (one per machine).

    python3 scripts/batch_table.py LOG [LOG ...] [--write]

Each LOG is a `batch.log` that `scripts/batch_device.sh` wrote (on a lent many-core machine,
or here: `OUT=DIR bash scripts/batch_device.sh`). Prints a markdown table: per machine and
photo size, `drbokeh batch --jobs auto` beside the `xargs -P CORES` loop of single-threaded
`drbokeh render` that ran right after it, and the batch's share of the loop's images per minute.
With `--write` the table replaces what stands between the `<!-- batch-throughput -->` anchors
of README.md and docs/performance.md.
"""
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent
ANCHOR = "<!-- batch-throughput -->"
RESULT = re.compile(r"^(?P<what>.+?): (?P<ok>\d+) of (?P<n>\d+) images of (?P<size>\d+x\d+) in (?P<wall>[\d.]+) s: (?P<ipm>[\d.]+) images/minute")
USE = re.compile(r"CPU (?P<cpu>\d+)% .* peak RSS (?P<rss>\d+) MB")


def parse(path):
    text = pathlib.Path(path).read_text()
    head = text.splitlines()[0]
    cores = re.search(r"cores (\d+)", head).group(1)
    cpu = head.split(";")[1].strip()
    runs, last = [], None
    for line in text.splitlines():
        if m := RESULT.match(line):
            last = dict(m.groupdict())
            runs.append(last)
        elif (u := USE.search(line)) and last is not None:
            last.update(u.groupdict())
    return f"{cpu}, {cores} cores", cores, runs


def mp(size):
    w, h = map(int, size.split("x"))
    return f"{w * h / 1e6:.1f} MP"


def rows(path):
    machine, cores, runs = parse(path)
    out = []
    for i, r in enumerate(runs):
        if not r["what"].startswith("batch"):
            continue
        loop = runs[i + 1] if i + 1 < len(runs) and runs[i + 1]["what"].startswith("xargs") else None
        how = re.search(r"\((.*)\)$", r["what"])
        how = how.group(1) if how else ""
        flags = r["what"].split("(")[0].replace("batch --jobs auto", "").strip()
        flags = re.sub(r"--config \S+", "8 GB budget", flags)
        if m := re.match(r"(\d+) in flight, threads \[(.*)\]", how):
            t = m.group(2).replace(", ", " or ")
            how = f"{m.group(1)} at a time, {t} thread{'' if t == '1' else 's'} each"
        label = "start build" if "does not report" in how else (how + (f", {flags}" if flags else ""))
        share = f"{100 * float(r['ipm']) / float(loop['ipm']):.0f}%" if loop else "-"
        out.append(
            f"| {machine} | `{pathlib.Path(path).name}` | {r['n']} × {mp(r['size'])} | {label} | {float(r['ipm']):.0f} ({r.get('rss', '?')} MB) | "
            + (f"{float(loop['ipm']):.0f} | {share} |" if loop else "- | - |")
        )
    return out


def table(paths):
    lines = [
        "| machine | log (one window) | photos | `batch --jobs auto` (and flags): schedule | batch: images/minute (peak RSS) | `xargs -P cores render --threads 1`: images/minute | batch / loop |",
        "| --- | --- | --- | --- | ---: | ---: | ---: |",
    ]
    for p in paths:
        lines += rows(p)
    return "\n".join(lines) + "\n"


def write(path, text):
    doc = path.read_text()
    a = doc.index(ANCHOR)
    b = doc.index(ANCHOR, a + len(ANCHOR))
    path.write_text(doc[: a + len(ANCHOR)] + "\n" + text + doc[b:])


def main():
    args = [a for a in sys.argv[1:] if a != "--write"]
    if not args:
        sys.exit(__doc__)
    text = table(args)
    print(text, end="")
    if "--write" in sys.argv:
        for f in ("README.md", "docs/performance.md"):
            write(ROOT / f, text)


if __name__ == "__main__":
    main()
