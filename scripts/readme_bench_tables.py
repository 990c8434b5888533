#!/usr/bin/env python3
"""Copies the tables of docs/bench/report.md (made by `drbokeh bench ... --out docs/bench`)
into the documentation pages (README.md's headline table, docs/guide.md, docs/dfd.md,
docs/benchmarks.md) between their anchors, and computes the pipeline tables (issue 12: the tool's
defaults from photo + depth + matte against the baselines fed the same inputs, exact and
realistic depth, per category, seeds 1 and 2) from docs/bench*/report.csv, and copies the depth-from-defocus means and acceptance checks of
docs/dfd-bench*/report.md and docs/dfd-heldout*/report.md (`drbokeh bench --dfd`), so the README's bench tables are never
typed by hand.

`--check` writes nothing: it exits 1 (naming the pages) when a committed table differs from
what the reports give, so a stale table fails the test script."""
import collections, csv, pathlib, sys

root = pathlib.Path(__file__).resolve().parent.parent
report = (root / "docs/bench/report.md").read_text()
# The pages with anchors, read as one text (a separator between them) so each replacement
# finds its anchor wherever it lives; split back at the end.
PAGES = ["README.md", "docs/guide.md", "docs/dfd.md", "docs/benchmarks.md"]
SEP = "\n<!-- drbokeh: page boundary -->\n"
originals = [(root / p).read_text() for p in PAGES]
readme = SEP.join(originals)


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

CATEGORIES = [("all", "all cases"), ("fg_in_focus", "foreground in focus"), ("bg_in_focus", "background in focus"),
              ("between", "focus between the layers"), ("thin", "thin structures"), ("highlights", "HDR highlights behind edges")]


def pipeline_table(depth):
    """Mean PSNR sRGB / PSNR linear / SSIM sRGB per seed and category: the pipeline, the
    scatter and the gather at the tool's defaults (exact or realistic depth), and Dr.Bokeh on
    the exact layers (physical profile, exact kernel) for reference."""
    variant = "physical-fast-q2" if depth == "exact" else "realistic-depth"
    cols = [("drbokeh-pipeline", variant), ("scatter-no-occlusion", variant),
            ("gather", "default" if depth == "exact" else "realistic-depth"), ("drbokeh-layers", "physical-exact")]
    out = ["| seed | category | cases | pipeline | scatter, no occlusion | gather | pipeline - best baseline (sRGB dB) | exact layers (oracle) |",
           "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for seed, folder in [(1, "docs/bench"), (2, "docs/bench-seed2")]:
        acc = collections.defaultdict(list)
        for r in csv.DictReader(open(root / folder / "report.csv")):
            if r.get("input", "linear") != "linear":  # the 8-bit inputs (issue 35): report.md's own section
                continue
            key = (r["method"], r["variant"])
            if key in cols:
                for c in r["categories"].split(";") + ["all"]:
                    acc[(c, key)].append((float(r["psnr_srgb"]), float(r["psnr_linear"]), float(r["ssim_srgb"])))
        for cat, label in CATEGORIES:
            means = []
            for k in cols:
                v = acc[(cat, k)]
                means.append(tuple(sum(x[i] for x in v) / len(v) for i in range(3)) if v else None)
            cells = [f"{m[0]:.2f} / {m[1]:.2f} / {m[2]:.4f}" if m else "-" for m in means]
            margin = means[0][0] - max(means[1][0], means[2][0])
            n = len(acc[(cat, cols[0])])
            out.append(f"| {seed} | {label} | {n} | {cells[0]} | {cells[1]} | {cells[2]} | {margin:+.2f} | {cells[3]} |")
    return "\n".join(out)


for depth in ["exact", "realistic"]:
    start, end = f"<!-- pipeline-table {depth} -->\n", f"<!-- /pipeline-table {depth} -->"
    if start in readme:
        readme = replace_between(readme, start, end, pipeline_table(depth) + "\n")


def options_table():
    """The pipeline's optional settings against its defaults, per seed and depth map: mean
    PSNR sRGB / PSNR linear / SSIM sRGB over all cases, and the number of cases where the
    option is better by PSNR sRGB. Variants absent from a report are left out."""
    options = [("layers-auto", "realistic-depth-layers-auto", "`--layers auto`"),
               ("patchmatch", "realistic-depth-patchmatch", "`--inpaint patchmatch`")]
    out = ["| seed | depth | setting | pipeline | better / worse cases (sRGB) |", "| ---: | --- | --- | ---: | ---: |"]
    for seed, folder in [(1, "docs/bench"), (2, "docs/bench-seed2")]:
        rows = collections.defaultdict(dict)
        for r in csv.DictReader(open(root / folder / "report.csv")):
            if r.get("input", "linear") != "linear":  # the 8-bit inputs (issue 35): report.md's own section
                continue
            if r["method"] == "drbokeh-pipeline":
                rows[r["variant"]][(r["scene"], r["setting"])] = (float(r["psnr_srgb"]), float(r["psnr_linear"]), float(r["ssim_srgb"]))
        for depth, base in [("exact", "physical-fast-q2"), ("realistic", "realistic-depth")]:
            cases = rows.get(base, {})
            if not cases:
                continue
            mean = lambda v: " / ".join(f"{sum(x[i] for x in v) / len(v):.{2 if i < 2 else 4}f}" for i in range(3))
            out.append(f"| {seed} | {depth} | defaults (2 layers, Telea) | {mean(list(cases.values()))} | |")
            for exact_v, real_v, label in options:
                v = rows.get(exact_v if depth == "exact" else real_v)
                if not v:
                    continue
                better = sum(1 for k, x in v.items() if k in cases and x[0] > cases[k][0] + 1e-3)
                worse = sum(1 for k, x in v.items() if k in cases and x[0] < cases[k][0] - 1e-3)
                out.append(f"| {seed} | {depth} | {label} | {mean(list(v.values()))} | {better} / {worse} |")
    return "\n".join(out)


if "<!-- pipeline-options -->\n" in readme:
    readme = replace_between(readme, "<!-- pipeline-options -->\n", "<!-- /pipeline-options -->", options_table() + "\n")
# Depth from defocus (bench --dfd): the means over all cases of each seed, and the
# acceptance bullets of both seeds, copied from the reports.
DFD_REPORTS = [
    ("seed1", "Seed 1", "docs/dfd-bench"),
    ("seed2", "Seed 2", "docs/dfd-bench-seed2"),
    ("heldout", "Held-out Mitsuba scenes", "docs/dfd-heldout"),
    ("heldout13", "Fresh held-out Mitsuba scenes (generator seed 13)", "docs/dfd-heldout13"),
    ("heldout21", "Third held-out Mitsuba set (generator seed 21)", "docs/dfd-heldout21"),
]
for key, _, folder in DFD_REPORTS:
    md = (root / folder / "report.md").read_text()
    start, end = f"<!-- dfd-table {key} -->\n", f"<!-- /dfd-table {key} -->"
    readme = replace_between(readme, start, end, section(md, "## All cases") + "\n")
# The literature's depth measures (AbsRel, RMSE, delta < 1.25) of the held-out Mitsuba sets,
# whose scenes state their depth range, side by side in one table per set.
for key, _, folder in DFD_REPORTS:
    md = (root / folder / "report.md").read_text()
    start, end = f"<!-- dfd-depth {key} -->\n", f"<!-- /dfd-depth {key} -->"
    if start in readme and "## Depth and inverse depth" in md:
        i = md.index("| method | depth AbsRel", md.index("## Depth and inverse depth"))
        readme = replace_between(readme, start, end, md[i:md.index("\n\n", i)] + "\n")
acc = []
for _, label, folder in DFD_REPORTS:
    md = (root / folder / "report.md").read_text()
    acc.append(f"{label}:\n\n" + section(md, "## Acceptance"))
readme = replace_between(readme, "<!-- dfd-acceptance -->\n", "<!-- /dfd-acceptance -->", "\n\n".join(acc) + "\n")
# Depth from defocus on 8-bit photos (`bench --dfd --inputs linear,srgb8,srgb8-psf`): per seed
# and input, the default method's disparity error against the two ablations and its far-focus
# re-render against the true map's, from the reports' report.csv (rows with an `input` column).
def dfd_inputs_table():
    out = ["| seed | input | cases | disparity MAE: default | no occlusion | Gaussian PSF | "
           "re-render gap to the true map, linear / sRGB dB (mean) | worst case, linear dB | true map's re-render, linear / sRGB dB |",
           "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for seed, folder in [(1, "docs/dfd-bench"), (2, "docs/dfd-bench-seed2")]:
        rows = list(csv.DictReader(open(root / folder / "report.csv")))
        inputs = list(dict.fromkeys(r.get("input") or "linear" for r in rows))
        for inp in inputs:
            by = collections.defaultdict(dict)
            for r in rows:
                if (r.get("input") or "linear") == inp:
                    by[r["method"]][r["scene"]] = r
            mean = lambda m, col: sum(min(float(r[col]), 100.0) for r in by[m].values()) / len(by[m])
            truth, ours = by["true-disparity"], by["drbokeh-physical"]
            gaps = [min(float(truth[k]["rerender_psnr_linear"]), 100.0) - min(float(ours[k]["rerender_psnr_linear"]), 100.0) for k in ours]
            out.append(f"| {seed} | `{inp}` | {len(ours)} | {mean('drbokeh-physical', 'disparity_mae'):.4f} | "
                       f"{mean('drbokeh-no-occlusion', 'disparity_mae'):.4f} | {mean('gauss-psf', 'disparity_mae'):.4f} | "
                       f"{mean('true-disparity', 'rerender_psnr_linear') - mean('drbokeh-physical', 'rerender_psnr_linear'):.2f} / "
                       f"{mean('true-disparity', 'rerender_psnr_srgb') - mean('drbokeh-physical', 'rerender_psnr_srgb'):.2f} | "
                       f"{max(gaps):.2f} | {mean('true-disparity', 'rerender_psnr_linear'):.2f} / {mean('true-disparity', 'rerender_psnr_srgb'):.2f} |")
    return "\n".join(out)


if "<!-- dfd-inputs -->\n" in readme:
    readme = replace_between(readme, "<!-- dfd-inputs -->\n", "<!-- /dfd-inputs -->", dfd_inputs_table() + "\n")
# Issue 38: depth from defocus from 8-bit photos before and after the clip model (the lights of
# the all-in-focus photo recovered and checked against the target, clipped samples taken as
# lower bounds): docs/dfd-8bit/SET-before/report.csv (the code before it) against the current
# reports, docs/dfd-bench*/ for the seeds and docs/dfd-8bit/hoNN-after/ for the held-out sets.
DFD_8BIT_SETS = [("seed 1", "docs/dfd-8bit/seed1-before", "docs/dfd-bench"),
                 ("seed 2", "docs/dfd-8bit/seed2-before", "docs/dfd-bench-seed2"),
                 ("held-out set 12", "docs/dfd-8bit/ho12-before", "docs/dfd-8bit/ho12-after"),
                 ("held-out set 13", "docs/dfd-8bit/ho13-before", "docs/dfd-8bit/ho13-after")]


def dfd_8bit_table():
    out = ["| set | input | cases | default MAE, before → after | better / worse cases | no occlusion, before → after | "
           "Gaussian PSF, before → after | re-render sRGB dB, before → after |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for label, before, after in DFD_8BIT_SETS:
        runs = []
        for folder in (before, after):
            by = collections.defaultdict(dict)
            for r in csv.DictReader(open(root / folder / "report.csv")):
                by[(r.get("input") or "linear", r["method"])][r["scene"]] = r
            runs.append(by)
        for inp in ["srgb8", "srgb8-psf"]:
            b, a = runs[0][(inp, "drbokeh-physical")], runs[1][(inp, "drbokeh-physical")]
            if not b or not a:
                continue
            mean = lambda run, m, col: sum(float(r[col]) for r in run[(inp, m)].values()) / len(run[(inp, m)])
            pair = lambda m, col, f: f"{mean(runs[0], m, col):{f}} → {mean(runs[1], m, col):{f}}"
            better = sum(float(a[k]["disparity_mae"]) < float(b[k]["disparity_mae"]) for k in a)
            worse = sum(float(a[k]["disparity_mae"]) > float(b[k]["disparity_mae"]) for k in a)
            out.append(f"| {label} | `{inp}` | {len(a)} | {pair('drbokeh-physical', 'disparity_mae', '.4f')} | {better} / {worse} | "
                       f"{pair('drbokeh-no-occlusion', 'disparity_mae', '.4f')} | {pair('gauss-psf', 'disparity_mae', '.4f')} | "
                       f"{pair('drbokeh-physical', 'rerender_psnr_srgb', '.2f')} |")
    return "\n".join(out)


if "<!-- dfd-8bit -->\n" in readme:
    readme = replace_between(readme, "<!-- dfd-8bit -->\n", "<!-- /dfd-8bit -->", dfd_8bit_table() + "\n")
# Issue 35: the highlights stage on the 8-bit inputs, from docs/highlights/*/report.csv
# (`drbokeh bench --methods pipeline,scatter,gather --scenes 20 --size 128x128 --seed S`,
# `--groundtruth ../shared/groundtruth` and `--groundtruth target/heldout` (docs/heldout/README.md
# makes those scenes); each report's own "Inputs compared" section has the per-category tables).
HIGHLIGHT_SETS = [("seed 3 (tuned on)", "docs/highlights/seed3"), ("seed 4 (held out)", "docs/highlights/seed4"),
                  ("Mitsuba scenes (not tuned on)", "docs/highlights/mitsuba"),
                  ("held-out Mitsuba set (never tuned on)", "docs/highlights/heldout")]


def highlights_table():
    out = ["| set | input | cases | pipeline, `auto` (sRGB / linear dB) | `off` | auto - off | worst category (sRGB) | "
           "no matte, estimator depth: pipeline - best baseline (sRGB / linear) | light put back / missing |",
           "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for label, folder in HIGHLIGHT_SETS:
        path = root / folder / "report.csv"
        if not path.exists():
            continue
        rows = list(csv.DictReader(open(path)))
        for inp in ["srgb8", "srgb8-psf"]:
            def pick(method, variant, cat=None):
                return [r for r in rows if r["input"] == inp and r["method"] == method and r["variant"] == variant
                        and (cat is None or cat in r["categories"].split(";"))]
            def mean(rs, col):
                return sum(float(r[col]) for r in rs) / len(rs) if rs else float("nan")
            auto, off = pick("drbokeh-pipeline", "physical-fast-q2"), pick("drbokeh-pipeline", "highlights-off")
            if not auto:
                continue
            a = (mean(auto, "psnr_srgb"), mean(auto, "psnr_linear"))
            o = (mean(off, "psnr_srgb"), mean(off, "psnr_linear"))
            worst = min((mean(pick("drbokeh-pipeline", "physical-fast-q2", c), "psnr_srgb") - mean(pick("drbokeh-pipeline", "highlights-off", c), "psnr_srgb"), name)
                        for c, name in CATEGORIES[1:] if pick("drbokeh-pipeline", "highlights-off", c))
            nm = pick("drbokeh-pipeline", "realistic-depth-no-matte")
            base = max((pick("scatter-no-occlusion", "realistic-depth"), pick("gather", "realistic-depth")), key=lambda rs: mean(rs, "psnr_srgb"))
            missing = sum(float(r["light_missing"] or 0) for r in auto)
            put_back = sum(float(r["light_missing"] or 0) * float(r["light_recovered"] or 0) for r in auto)
            out.append(f"| {label} | `{inp}` | {len(auto)} | {a[0]:.2f} / {a[1]:.2f} | {o[0]:.2f} / {o[1]:.2f} | "
                       f"{a[0] - o[0]:+.2f} / {a[1] - o[1]:+.2f} | {worst[0]:+.2f} ({worst[1]}) | "
                       f"{mean(nm, 'psnr_srgb') - mean(base, 'psnr_srgb'):+.2f} / {mean(nm, 'psnr_linear') - mean(base, 'psnr_linear'):+.2f} | "
                       f"{put_back / missing if missing else float('nan'):.2f} |")
    return "\n".join(out)


if "<!-- highlights-bench -->\n" in readme:
    readme = replace_between(readme, "<!-- highlights-bench -->\n", "<!-- /highlights-bench -->", highlights_table() + "\n")


def headline_table():
    """README's few headline figures, each from the same data as the table it links to."""
    def all_cases(depth):
        rows = [l for l in pipeline_table(depth).split("\n")[2:] if "| all cases |" in l]
        return [[c.strip() for c in r.strip("|").split("|")] for r in rows]
    out = ["| question | answer | measured in |", "| --- | --- | --- |"]
    for depth, what in [("exact", "the exact depth map and matte"), ("realistic", "a depth map as an estimator gives it (smoothed, 1/4 resolution) and a matte")]:
        for seed, _, n, pipe, scatter, gather, margin, _oracle in all_cases(depth):
            out.append(f"| Lens blur from a linear photo with {what}, against physically rendered ground truth (bench seed {seed}, {n} scenes) | "
                       f"{pipe.split(' / ')[0]} dB PSNR (sRGB), {margin} dB over the best naive baseline (scatter {scatter.split(' / ')[0]}, gather {gather.split(' / ')[0]}) | "
                       f"[benchmarks](docs/benchmarks.md#the-pipeline-against-the-baselines) |")
    held = [l for l in highlights_table().split("\n")[2:] if l.startswith("| seed 4")]
    for r in held:
        c = [x.strip() for x in r.strip("|").split("|")]
        out.append(f"| What users mostly have: an 8-bit photo (`{c[1].strip('`')}` input), a depth map as an estimator gives it, no matte (held-out seed 4, {c[2]} scenes): the pipeline against the best naive baseline | "
                   f"{c[7]} dB (sRGB / linear) | [guide](docs/guide.md#clipped-highlights---highlights-autooffboost) |")
    hl = [l for l in highlights_table().split("\n")[2:] if l.startswith("| Mitsuba")]
    for r in hl:
        c = [x.strip() for x in r.strip("|").split("|")]
        out.append(f"| The same from an 8-bit photo whose lights are clipped (`{c[1].strip('`')}` input, Mitsuba scenes): `--highlights auto` against `off` | "
                   f"{c[5]} dB (sRGB / linear) | [guide](docs/guide.md#clipped-highlights---highlights-autooffboost) |")
    return "\n".join(out)


if "<!-- headline -->\n" in readme:
    readme = replace_between(readme, "<!-- headline -->\n", "<!-- /headline -->", headline_table() + "\n")
pages = readme.split(SEP)
assert len(pages) == len(PAGES), "a page boundary was lost"
stale = [p for p, old, new in zip(PAGES, originals, pages) if old != new]
if "--check" in sys.argv[1:]:
    if stale:
        sys.exit(f"stale generated tables in {', '.join(stale)}: run python3 scripts/readme_bench_tables.py")
    print("generated tables up to date", file=sys.stderr)
else:
    for p, new in zip(PAGES, pages):
        (root / p).write_text(new)
    print(f"tables updated ({', '.join(stale) or 'no change'}) from docs/bench*/report.* and docs/dfd-*/report.md", file=sys.stderr)
