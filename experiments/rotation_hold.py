"""How firmly the matched faces hold each fit's rotation (`Estimate.hold.lever`) and
translation (`Estimate.slide.grip`) on varied data, against the fit's error: where
`Thresholds.min_rotation_lever` and `Thresholds.min_translation_grip` come from.

`uv run python experiments/rotation_hold.py [--seeds 2 3] [--pairs 6]`
→ `results/rotation_hold.{json,md}`

Pairs: the realistic benchmark's generator (`jaxpose.evaluation.realistic.make_cases`, every
built-in target, σ = 0, 0.5, 1 and 2 cm, `--pairs` pairs each, draws other than the
benchmark's seed 0 and its held-out seed 1), estimated with the default config through
`jp.estimate_batch` (one compiled program per draw, key = the draw's seed). Per pair: the
status, the status with both checks off (`Thresholds(min_rotation_lever=0,
min_translation_grip=0)`, the same fits), the rotation and centroid errors
(`realistic.errors`), the lever and the grip. The tables list every pair whose lever is
below `LISTED_CM`, and every pair whose grip is below `LISTED_GRIP`, with the smallest value
among the others.
"""

from __future__ import annotations

import argparse

import jax
from _common import RESULTS, stacked, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME
from jaxpose.evaluation import realistic

LEVELS_CM = (0.0, 0.5, 1.0, 2.0)
LISTED_CM = 1.0
"""Pairs with a lever below this (centimetres) are listed one by one."""
LISTED_GRIP = 0.03
"""Pairs with a grip below this are listed one by one."""


def draw_rows(seed: int, pairs: int) -> list[dict]:
    """One row per pair of draw `seed`: label, status, errors (°, cm), lever (cm) and grip."""
    cases = realistic.make_cases(pairs, seed=seed, levels=LEVELS_CM)
    prev, curr = stacked([c.prev for c in cases]), stacked([c.curr for c in cases])
    est = jp.estimate_batch(prev, curr, key=jax.random.key(seed))
    without = jp.Config(thresholds=jp.Thresholds(min_rotation_lever=0.0, min_translation_grip=0.0))
    before = jp.estimate_batch(prev, curr, without, key=jax.random.key(seed)).status
    rows = []
    for i, case in enumerate(cases):
        err = realistic.errors(case, est.rotation[i], est.translation[i])
        rows.append(
            {
                "seed": seed,
                "pair": case.label,
                "status": STATUS_NAME[int(est.status[i])],
                "status_without_check": STATUS_NAME[int(before[i])],
                "rotation_error_deg": err["rotation_error_deg"],
                "centroid_error_cm": err["centroid_error_cm"],
                "lever_cm": 100 * float(est.hold.lever[i]),
                "grip": float(est.slide.grip[i]),
            }
        )
    return rows


def listed(rows: list[dict], key: str, below: float, header: str, cell, unit: str = "") -> list[str]:
    """The rows whose `key` is below `below`, smallest first, as table lines, then the smallest
    value among the others (with `unit`)."""
    low = sorted((r for r in rows if r[key] < below), key=lambda r: r[key])
    others = [r[key] for r in rows if r[key] >= below]
    lines = [
        f"| draw | pair | {header} | rotation error, ° | centroid error, cm | status | without the checks |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in low:
        lines.append(
            f"| {r['seed']} | {r['pair']} | {cell(r[key])} | {r['rotation_error_deg']:.3f} | "
            f"{r['centroid_error_cm']:.3f} | {r['status']} | {r['status_without_check']} |"
        )
    name = header.split(",")[0]
    smallest = f"Smallest {name} of the other {len(others)} pairs: {cell(min(others))}{unit}."
    return lines + ["", smallest if others else ""]


def markdown(rows: list[dict], threshold_cm: float, threshold_grip: float) -> str:
    lines = [
        f"Pairs with a lever below {LISTED_CM:g} cm, of {len(rows)} (`Thresholds.min_rotation_lever` = "
        f"{threshold_cm:g} cm; the status is the default config's, with both checks):",
        "",
        *listed(rows, "lever_cm", LISTED_CM, "lever, cm", lambda v: f"{v:.2f}", " cm"),
        "",
        f"Pairs with a grip below {LISTED_GRIP:g}, of {len(rows)} (`Thresholds.min_translation_grip` = "
        f"{threshold_grip:g}):",
        "",
        *listed(rows, "grip", LISTED_GRIP, "grip", lambda v: f"{v:.4f}"),
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    parser.add_argument("--pairs", type=int, default=6)
    args = parser.parse_args()
    rows = [row for seed in args.seeds for row in draw_rows(seed, args.pairs)]
    thresholds = jp.Config().thresholds
    threshold_cm = 100 * float(thresholds.min_rotation_lever)
    write_json("rotation_hold.json", {"seeds": args.seeds, "pairs": args.pairs, "rows": rows})
    table = markdown(rows, threshold_cm, float(thresholds.min_translation_grip))
    (RESULTS / "rotation_hold.md").write_text(table)
    print(table)


if __name__ == "__main__":
    main()
