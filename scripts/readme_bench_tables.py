#!/usr/bin/env python3
"""Copies the tables of docs/bench/report.md (made by `drbokeh bench ... --out docs/bench`)
into README.md between their anchors, so the README's bench tables are never typed by hand."""
import pathlib, sys

root = pathlib.Path(__file__).resolve().parent.parent
report = (root / "docs/bench/report.md").read_text()
readme_path = root / "README.md"
readme = readme_path.read_text()


def section(md, head):
    i = md.index(head)
    i = md.index("\n\n", i) + 2
    return md[i:md.index("\n\n", i)]


def replace_between(text, start, end, new):
    i = text.index(start) + len(start)
    j = text.index(end, i)
    return text[:i] + new + text[j:]


blocks = [
    ("Mean over the 50 scenes of seed 1 (from `docs/bench/report.md`):\n\n", "\n\nPer category, official profile", "## Summary (mean over cases)"),
    ("Per category, official profile (mean PSNR sRGB / SSIM sRGB, exact kernel):\n\n", "\n\nPer category, physical profile", "## Per category (mean PSNR sRGB / SSIM sRGB, official profile"),
    ("Per category, physical profile (exact kernel; the gather has no profile):\n\n", "\n\nHeld-out seed 2", "## Per category (mean PSNR sRGB / SSIM sRGB, physical profile"),
    ("against the others, case by case:\n\n", "\nCase by case, the physical profile", "## Dr.Bokeh (exact 2 layers, exact kernel) against the others"),
]
for start, end, head in blocks:
    readme = replace_between(readme, start, end, section(report, head) + ("\n" if end.startswith("\nCase") else ""))
readme_path.write_text(readme)
print("README bench tables updated from docs/bench/report.md", file=sys.stderr)
