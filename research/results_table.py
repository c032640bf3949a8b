"""Compare evaluation results: the Table 3 layout in Markdown, and paired per-shape differences.

    python -m research.results_table BASE.json OTHER.json [...] [--bootstrap 10000] [--icp] [--fscore | --missing]
    python -m research.results_table RESULT.json [...] --surfaces

Every file is written by ``python -m research.evaluate`` on the same split; ``A.json+B.json`` joins
one model's results on several splits (the held-out seed's 780 shapes) into one.  Besides the per-category
table, each result after the first is compared with the first shape by shape: the difference of
category means with a 95% bootstrap interval (shapes resampled within categories) and how many
shapes each side wins and how many tie, so that a gap can be told from test-set noise.  ``--icp``
compares the Chamfer distances after
ICP alignment (results evaluated with ``--icp``); ``--fscore`` the F-score at 1% of the truth's
diagonal instead (higher is better; after ICP with ``--icp``); ``--missing`` compares completion's
missing-part distance.  ``--surfaces`` compares, within each result, the closed surface with the
patches, both sampled by area (``research.evaluate`` measures both surfaces for the image and
completion tasks).  Completion results get a last row: the partial input itself.  Shapes a model decoded to nothing have no
value and are left out of its pairs; the table counts them.  Results of the foreground network
(``research.evaluate`` on a foreground model) are compared by mask IoU, where higher is better.
"""

from __future__ import annotations

import gzip
import json
import os
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.cli import command_parser

from .results import finite, join_results

# The per-shape measure compared, by (--fscore, --icp): the keys research.evaluate writes.
COMPARED = {(False, False): "chamfer_x1e3", (False, True): "chamfer_icp_x1e3",
            (True, False): "fscore", (True, True): "fscore_icp"}


@dataclass
class PairedDifference:
    """Category mean of a per-shape measure (a Chamfer distance x1e3 unless said otherwise) of
    ``other`` minus ``base``, over the shapes both evaluated; per shape, who is better (a lower value,
    or a higher one for a measure where higher is better) or neither:
    ``base_wins + other_wins + ties == shapes``."""

    mean: float
    low: float
    high: float
    base_wins: int
    other_wins: int
    ties: int
    shapes: int


def load_results(path: str | Path) -> dict:
    """An evaluation JSON with per-shape rows, or the same gzipped (``.json.gz``, as results are
    kept in docs/results) (ValueError if it is not one)."""
    try:
        raw = Path(path).read_bytes()
        res = json.loads(gzip.decompress(raw) if str(path).endswith(".gz") else raw)
    except (OSError, EOFError, zlib.error, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable results file ({type(exc).__name__})") from None
    if not isinstance(res, dict) or "per_shape" not in res:
        raise ValueError(f"{path}: no per-shape rows; evaluate again with python -m research.evaluate")
    return res


def load_joined(arg: str) -> dict:
    """The result of one command-line argument: a results JSON, or several joined by ``+``
    (``test.json+val.json+train.json``: one model on the splits of one dataset, see
    :func:`research.results.join_results`)."""
    if Path(arg).is_file() or "+" not in arg:
        return load_results(arg)
    return join_results([load_results(p) for p in arg.split("+")])


def _stem(path: str) -> str:
    """A results file's name without ``.json`` or ``.json.gz``."""
    name = Path(path).name
    return name.removesuffix(".gz").removesuffix(".json")


def _label(arg: str) -> str:
    return _stem(arg) if Path(arg).is_file() else "+".join(_stem(p) for p in arg.split("+"))


def markdown_table(results: list[dict], labels: list[str], metric: str = "chamfer_x1e3") -> str:
    """Per-category test means, category mean, empty outputs and mean octree sizes, one row per result."""
    for r in results:
        if metric not in r:
            how = "with --icp" if "icp" in metric else "again (results evaluated before it was measured lack it)"
            raise ValueError(f"{r.get('run', 'a result')} has no {metric}: evaluate it {how}")
    cats = sorted({row["category"] for r in results for row in r["per_shape"]})
    lines = ["| run | " + " | ".join(cats) + " | **mean** | empty outputs | decoded nodes | truth nodes |",
             "|---|" + "---|" * (len(cats) + 4)]
    for label, r in zip(labels, results):
        o = r["octree"]
        digits = 3 if "fscore" in metric else 2
        cells = [f"{r[metric][c]:.{digits}f}" if finite(r[metric].get(c)) else "—" for c in cats]
        mean = r.get(f"{metric}_category_mean")
        mean_cell = f"**{mean:.3f}**" if finite(mean) else "—"
        decoded = f"{o['decoded_nodes']:.0f}" if finite(o.get("decoded_nodes")) else "—"
        truth = f"{o['truth_nodes']:.0f}" if finite(o.get("truth_nodes")) else "—"
        lines.append(f"| {label} | " + " | ".join(cells) +
                     f" | {mean_cell} | {r.get('empty_outputs', 0)} | {decoded} | {truth} |")
    floor = results[0].get(f"input_{metric}")
    if isinstance(floor, dict):        # completion: what the partial input itself scores
        cells = [f"{floor[c]:.2f}" if finite(floor.get(c)) else "—" for c in cats]
        mean = results[0].get(f"input_{metric}_category_mean")
        lines.append("| the partial input itself | " + " | ".join(cells) +
                     f" | {f'**{mean:.3f}**' if finite(mean) else '—'} | — | — | — |")
    return "\n".join(lines)


def paired_difference(base: dict, other: dict, draws: int = 10_000, seed: int = 0,
                      metric: str = "chamfer_x1e3", other_metric: str | None = None,
                      higher_is_better: bool = False) -> PairedDifference:
    """Difference of category means (``other_metric`` of ``other`` minus ``metric`` of ``base``;
    by default the same metric) over the shapes both results hold a value for, with a
    stratified bootstrap; ``higher_is_better`` for a measure such as the mask IoU."""
    other_metric = other_metric or metric
    a = {(r["category"], r["shape_id"]): r.get(metric) for r in base["per_shape"] if finite(r.get(metric))}
    b = {(r["category"], r["shape_id"]): r.get(other_metric) for r in other["per_shape"]
         if finite(r.get(other_metric))}
    common = sorted(set(a) & set(b))
    if not common:
        raise ValueError("the two results share no shapes with a value")
    rng = np.random.default_rng(seed)
    diffs_by_cat: dict[str, np.ndarray] = {}
    for cat in sorted({c for c, _ in common}):
        keys = [k for k in common if k[0] == cat]
        diffs_by_cat[cat] = np.array([b[k] - a[k] for k in keys])
    mean = float(np.mean([d.mean() for d in diffs_by_cat.values()]))
    boot = np.zeros(draws)
    for d in diffs_by_cat.values():
        boot += d[rng.integers(0, len(d), size=(draws, len(d)))].mean(1)
    boot /= len(diffs_by_cat)
    low, high = np.percentile(boot, [2.5, 97.5])
    all_d = np.concatenate(list(diffs_by_cat.values()))
    base_wins, other_wins = int((all_d > 0).sum()), int((all_d < 0).sum())
    if higher_is_better:
        base_wins, other_wins = other_wins, base_wins
    return PairedDifference(mean, float(low), float(high), base_wins, other_wins, int((all_d == 0).sum()),
                            len(common))


def mask_table(results: list[dict], labels: list[str]) -> str:
    """Foreground results: per-category mask IoU, the category mean, the median, the share of
    photos above 0.9 and the thin parts' recall (category mean; — for results without it), one
    row per result."""
    cats = sorted({row["category"] for r in results for row in r["per_shape"]})
    lines = ["| run | " + " | ".join(cats) + " | **mean** | median | above 0.9 | thin-part recall | photos |",
             "|---|" + "---|" * (len(cats) + 5)]
    for label, r in zip(labels, results):
        cells = [f"{r['mask_iou'][c]:.3f}" if finite(r["mask_iou"].get(c)) else "—" for c in cats]
        thin = f"{r['thin_recall_category_mean']:.3f}" if finite(r.get("thin_recall_category_mean")) else "—"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | **{r['mask_iou_category_mean']:.3f}** | "
                     f"{r['mask_iou_median']:.3f} | {r['mask_iou_above_0.9']:.0%} | {thin} | {r['shapes']} |")
    return "\n".join(lines)


def surfaces_table(results: list[dict], labels: list[str], draws: int = 10_000) -> str:
    """Markdown: per result, the closed surface against the patches (Chamfer x1e3 and F-score
    category means, both sampled by area), the paired Chamfer difference, the open meshes and
    the meshes with faces crossing others (with the median share of such faces; "-" for results
    measured before it was)."""
    lines = ["Closed surface against the patches, both sampled by area (closed − patches, Chamfer x1e3 "
             "category mean, 95% bootstrap):",
             "| run | patches | closed | difference | 95% interval | patches better / closed better / tie "
             "| F-score patches / closed | not closed | crossing themselves (median share) | shapes |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for label, r in zip(labels, results):
        if r.get("watertight_chamfer_x1e3_category_mean") is None:
            raise ValueError(f"{label} has no closed-surface figures: give results of the image or completion task")
        d = paired_difference(r, r, draws, metric="patches_area_chamfer_x1e3",
                              other_metric="watertight_chamfer_x1e3")
        lines.append(f"| {label} | {r['patches_area_chamfer_x1e3_category_mean']:.3f} | "
                     f"{r['watertight_chamfer_x1e3_category_mean']:.3f} | {d.mean:+.3f} | "
                     f"[{d.low:+.3f}, {d.high:+.3f}] | {d.base_wins} / {d.other_wins} / {d.ties} | "
                     f"{r['patches_area_fscore_category_mean']:.3f} / {r['watertight_fscore_category_mean']:.3f} | "
                     f"{r['watertight_not_closed']} | {_crossing(r['per_shape'])} | {d.shapes} |")
    return "\n".join(lines)


def _crossing(rows: list[dict]) -> str:
    """How many outputs have faces crossing others, and the median share of such faces."""
    shares = [row["watertight_crossing_share"] for row in rows if row.get("watertight_crossing_share") is not None]
    if not shares:
        return "-"
    measured = "" if len(shares) == len(rows) else f" of {len(shares)} measured"
    return f"{sum(1 for x in shares if x > 0)}{measured} ({100 * float(np.median(shares)):.1f}%)"


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.results_table", __doc__, [
        "python -m research.results_table aocnn.json ocnn-patch.json --bootstrap 10000",
        "python -m research.results_table img.json img-psg.json --icp",
        "python -m research.results_table img.json img-atlasnet.json --icp --fscore",
        "python -m research.results_table image.json completion.json --surfaces",
        "python -m research.results_table base_test.json+base_val.json other_test.json+other_val.json --missing"])
    ap.add_argument("results", nargs="+",
                    help="results JSONs of python -m research.evaluate, the first the base; A.json+B.json joins the "
                         "results of one model on several splits into one")
    ap.add_argument("--bootstrap", type=int, default=10_000, help="bootstrap draws for the intervals (default 10000)")
    ap.add_argument("--icp", action="store_true", help="compare the Chamfer distances after ICP alignment")
    ap.add_argument("--fscore", action="store_true",
                    help="compare the F-score at 1%% of the truth's diagonal (higher is better) instead of the "
                         "Chamfer distance; with --icp after ICP alignment")
    ap.add_argument("--missing", action="store_true",
                    help="completion: compare the missing part's distance to the output instead of the Chamfer distance")
    ap.add_argument("--surfaces", action="store_true",
                    help="compare, within each result, the closed surface with the patches (both sampled by area)")
    args = ap.parse_args(argv)
    try:
        if args.bootstrap < 100:
            raise ValueError("--bootstrap must be at least 100")
        results = [load_joined(p) for p in args.results]
        labels = [_label(p) + (f" (oracle {r['oracle']})" if r.get("oracle", "none") != "none" else "")
                  for r, p in zip(results, args.results)]
        if args.fscore + args.missing + args.surfaces > 1 or args.icp and (args.missing or args.surfaces):
            raise ValueError("give one of --fscore, --missing and --surfaces (--icp goes with --fscore or alone)")
        if args.surfaces:
            print(surfaces_table(results, labels, args.bootstrap))
            return 0
        masks = [r.get("task") == "foreground" for r in results]
        if any(masks) and not all(masks):
            raise ValueError("foreground results (mask IoU) can only be compared with foreground results")
        if all(masks) and (args.icp or args.missing or args.fscore):
            raise ValueError("--icp, --fscore and --missing go with shape results, not the foreground network's masks")
        if all(masks):
            metric, what = "mask_iou", "mask IoU"
            print(mask_table(results, labels))
        else:
            metric = "missing_x1e3" if args.missing else COMPARED[args.fscore, args.icp]
            what = ("missing part's distance x1e3" if args.missing else
                    ("F-score at 1% of the diagonal" if args.fscore else "Chamfer x1e3") +
                    (" after ICP" if args.icp else ""))
            print(markdown_table(results, labels, metric))
        if len(results) > 1:
            print(f"\nPaired against {labels[0]} (other − base, {what} category mean, 95% bootstrap):")
            print("| run | difference | 95% interval | base better / other better / tie | shapes |\n|---|---|---|---|---|")
            for label, r in zip(labels[1:], results[1:]):
                d = paired_difference(results[0], r, args.bootstrap, metric=metric,
                                      higher_is_better=all(masks) or args.fscore)
                print(f"| {label} | {d.mean:+.3f} | [{d.low:+.3f}, {d.high:+.3f}] | "
                      f"{d.base_wins} / {d.other_wins} / {d.ties} | {d.shapes} |")
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:          # e.g. piped into head: stop quietly, as other CLI tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 0


if __name__ == "__main__":
    sys.exit(main())
