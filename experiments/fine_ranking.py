"""Other rules for ranking the fine stage's fits, offline on the fits of `fine_runs.py`.

`uv run python experiments/fine_ranking.py [FILE.json ...]` (default: every
`results/fine_runs_*.json`, written by `uv run python experiments/fine_runs.py TARGET --out
results/fine_runs_TARGET.json`) → `results/fine_ranking.{json,md}`.

Each row of those files holds one pair's fine-stage fits (from the refine's result, from
rest, turned both ways about a near-symmetry axis; the polish, last, is left out) with their
inlier fractions, inlier RMS residuals and errors against the truth. Each rule picks one fit
per pair; against the library's rule (`_estimate.prefers`: more inliers, or within
`FINE_TIE` the smaller RMS) it reports, per noise level, the pairs where the pick differs,
those it makes better or worse (rotation error lower or higher by more than 0.05°, or
within that the centroid by more than 0.05 cm), the pairs it brings within 1° or takes
out of it, and the summed change of the rotation error (°).

The rules:

- `inliers`: the larger inlier fraction, no tie band;
- `truncated 3 cm` and `truncated 1 cm`: the least mean truncated square, (1 − f)·g² + f·RMS²
  for the inlier fraction f and the gate g (3 cm is `FineStage.inlier`): what a robust cost
  that counts each outlier at the gate ranks by.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

from _common import RESULTS, write_json

from jaxpose._estimate import FINE_TIE, prefers

THRESHOLD_DEG, THRESHOLD_CM, FOUND_DEG = 0.05, 0.05, 1.0


def by_library_rule(fits) -> int:
    """The fit `_estimate.prefers` keeps (more inliers, or within `FINE_TIE` the smaller RMS),
    taking the live fits (some inliers) in order as the library's contests do."""
    best = None
    for i, (inliers, rms) in enumerate(fits):
        fit = SimpleNamespace(inliers=inliers, rms=rms)
        if inliers > 0 and (best is None or bool(prefers(best[1], fit))):
            best = (i, fit)
    return 0 if best is None else best[0]


def by_inliers(fits) -> int:
    """The larger inlier fraction, no tie band (equal fractions: the smaller RMS)."""
    live = [i for i, (inliers, _) in enumerate(fits) if inliers > 0]
    return max(live, key=lambda i: (fits[i][0], -fits[i][1]), default=0)


def by_truncated_square(fits, gate_mm: float) -> int:
    costs = [(1 - f) * gate_mm**2 + f * rms**2 if f > 0 else float("inf") for f, rms in fits]
    return min(range(len(fits)), key=costs.__getitem__)


RULES = {
    "inliers": by_inliers,
    "truncated 3 cm": lambda fits: by_truncated_square(fits, 30.0),
    "truncated 1 cm": lambda fits: by_truncated_square(fits, 10.0),
}


def compare(rows: list[dict]) -> dict:
    """Per rule and noise level, how its picks differ from the library's (see the module)."""
    out = defaultdict(lambda: defaultdict(lambda: defaultdict(float)))
    for row in rows:
        fits = list(zip(row["fits_inliers"][:-1], row["fits_rms_mm"][:-1], strict=True))
        rotation, centroid = row["fits_rotation_error_deg"], row["fits_centroid_error_cm"]
        library = by_library_rule(fits)
        level = row["label"].split()[1]
        for name, rule in RULES.items():
            pick = rule(fits)
            tally = out[name][level]
            tally["pairs"] += 1
            if pick == library:
                continue
            d_rot, d_cen = rotation[pick] - rotation[library], centroid[pick] - centroid[library]
            tally["differ"] += 1
            close = abs(d_rot) <= THRESHOLD_DEG
            tally["better"] += d_rot < -THRESHOLD_DEG or (close and d_cen < -THRESHOLD_CM)
            tally["worse"] += d_rot > THRESHOLD_DEG or (close and d_cen > THRESHOLD_CM)
            tally["found gained"] += rotation[pick] < FOUND_DEG <= rotation[library]
            tally["found lost"] += rotation[library] < FOUND_DEG <= rotation[pick]
            tally["rotation change deg"] += d_rot
    return {name: {level: dict(t) for level, t in levels.items()} for name, levels in out.items()}


def markdown(result: dict, files: list[str]) -> str:
    head = (
        f"Fine-stage fits of {', '.join(files)} ranked by other rules, against `prefers` (FINE_TIE {FINE_TIE}).\n\n"
        "| rule | σ | pairs | picks differ | better / worse | within 1°: gained / lost | rotation change, ° |\n"
        "|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for name, levels in result.items():
        for level, t in sorted(levels.items()):
            lines.append(
                f"| {name} | {level} | {t['pairs']:.0f} | {t.get('differ', 0):.0f} | "
                f"{t.get('better', 0):.0f} / {t.get('worse', 0):.0f} | "
                f"{t.get('found gained', 0):.0f} / {t.get('found lost', 0):.0f} | "
                f"{t.get('rotation change deg', 0.0):+.2f} |"
            )
    return head + "\n".join(lines) + "\n"


def main(paths: list[Path]) -> None:
    rows, seen = [], set()
    for path in paths:
        for row in json.loads(path.read_text()):
            if row["label"] not in seen:
                seen.add(row["label"])
                rows.append(row)
    result = compare(rows)
    names = [p.name for p in paths]
    text = markdown(result, names)
    print(text)
    (RESULTS / "fine_ranking.md").write_text(text)
    write_json("fine_ranking.json", {"files": names, "pairs": len(rows), "rules": result})


if __name__ == "__main__":
    main([Path(a) for a in sys.argv[1:]] or sorted(RESULTS.glob("fine_runs_*.json")))
