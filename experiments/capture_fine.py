"""The capture preset's fine stage, A/B on the capture set (issue 23): `Config.capture()` with
its own fine stage (`planar_fraction` 0.7, planes through the centroids, one-way residuals)
against the default fine stage one-way (`FineStage(symmetric=False)`) and the default fine stage
as it is (two-way residuals on noisy views), on the same pairs and keys in the same run. The
global stage is the same in all three, so the hypotheses' modes are; the fine stage moves the
best hypothesis's accuracy, the statuses and so the false successes, and the time.

    uv run python experiments/capture_fine.py [pairs per bin]
        → results/capture_fine.{json,md}

Per variant: found, truth among the hypotheses, false successes, all four of N5's motions
among, the median rotation and centroid errors of the found pairs per target and noise level,
and the median warm time per pair (s).
"""

from __future__ import annotations

import statistics
import sys
import time

import jax
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose.evaluation import capture

VARIANTS = {
    "capture (planar 0.7, centroid anchor, one-way)": {},
    "default fine stage, one-way": {"fine": jp.FineStage(symmetric=False)},
    "default fine stage (two-way on noisy views)": {"fine": jp.FineStage()},
}
"""`Config.capture(**changes)` per variant."""


def group_errors(rows: list[dict]) -> dict:
    """Per target and noise level: the median rotation (°) and centroid (cm) errors of the
    pairs whose best hypothesis was found."""
    out = {}
    for key in dict.fromkeys((r["target"], r["sigma_cm"]) for r in rows):
        found = [r for r in rows if (r["target"], r["sigma_cm"]) == key and r["best_found"]]
        name = f"{key[0]} σ{key[1]:g}"
        out[name] = {
            "found": len(found),
            "rotation_deg": statistics.median(r["rotation_error_deg"] for r in found) if found else None,
            "centroid_cm": statistics.median(r["centroid_error_cm"] for r in found) if found else None,
        }
    return out


def summary(rows: list[dict]) -> dict:
    return {
        "found": sum(r["found"] for r in rows),
        "among": sum(r["among"] for r in rows),
        "false_success": sum(map(capture.false_success, rows)),
        "n5_all_equivalents": sum(bool(r["all_equivalents"]) for r in rows if r["target"] == "n5"),
        "median_s": statistics.median(r["seconds"] for r in rows),
        "errors": group_errors(rows),
    }


def main(pairs: int = 3) -> None:
    t0 = time.perf_counter()
    cases, rejected = capture.make_cases(pairs)
    print(f"{len(cases)} pairs ({rejected} draws rejected)", flush=True)
    report = {
        "command": f"uv run python experiments/capture_fine.py {pairs}",
        "pairs": len(cases),
        "backend": jax.default_backend(),
        "variants": {},
    }
    for name, changes in VARIANTS.items():
        rows, first_calls = capture.run_jaxpose(cases, jp.Config.capture(**changes))
        report["variants"][name] = {**summary(rows), "first_calls_s": first_calls, "rows": rows}
        print(name, {k: v for k, v in report["variants"][name].items() if k != "rows"}, flush=True)
    report["seconds"] = time.perf_counter() - t0
    write_json("capture_fine.json", report)
    (RESULTS / "capture_fine.md").write_text(markdown(report))
    print(markdown(report))


def markdown(report: dict) -> str:
    variants = report["variants"]
    lines = [
        f"{report['pairs']} capture pairs, `Config.capture(**changes)`, the same keys.",
        "",
        "| fine stage | found | truth among | false succ. | N5 all four among | median s |",
        "|---|---|---|---|---|---|",
    ]
    for name, v in variants.items():
        lines.append(
            f"| {name} | {v['found']} | {v['among']} | {v['false_success']} | {v['n5_all_equivalents']} "
            f"| {v['median_s']:.2f} |"
        )
    groups = list(next(iter(variants.values()))["errors"])
    lines += ["", "Median errors of the found pairs, rotation ° / centroid cm (found):", ""]
    lines += ["| fine stage | " + " | ".join(groups) + " |", "|---|" + "---|" * len(groups)]
    for name, v in variants.items():
        cells = []
        for g in groups:
            e = v["errors"][g]
            cells.append("–" if e["found"] == 0 else f"{e['rotation_deg']:.3f} / {e['centroid_cm']:.3f} ({e['found']})")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
