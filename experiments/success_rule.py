"""How the success rule's uncertainty bound trades successes for false successes, on four draws.

`uv run python experiments/success_rule.py [--levels 0,0.5,1,2] [--seeds 0,1,2,3]`
→ `results/success_rule.{json,md}`

The pairs of `fine_draws.py` (`--pairs` per target and level from each seed's draw of the
realistic benchmark; seed 0 holds the committed benchmark's), each level through one
compiled `_build_and_estimate` of the default config sized over its pairs, keys
`fold_in(key(0), i)`: the same estimates as `fine_draws.py --variants default`. Per pair it
keeps what `Status.uncertain` reads (`jaxpose._estimate.is_uncertain`): the largest rotation
standard deviation of `Estimate.covariance` and the spread of equally good fits, combined as
√(std² + (spread / 2)²) (°), with the status and the errors (`realistic.errors`: found is
< 1° and < 5 cm). The table counts, per level, the successes and false successes (success,
not found) that remain when `Thresholds.max_rotation_std_deg` is lowered to each of
`BOUNDS`: a lower bound can only turn successes into `uncertain`. It also gives the ratio
of each success's rotation error to its combined standard deviation (median / p90 / max):
how far the covariance's promise holds at each noise level.
"""

from __future__ import annotations

import argparse

import numpy as np
from _common import RESULTS, write_json
from fine_draws import draws
from fine_variants import jaxpose_rows

import jaxpose as jp
from jaxpose._estimate import SUCCESS
from jaxpose._uncertainty import rotation_std

BOUNDS = (1 / 3, 0.3, 0.25, 0.2)
"""Bounds (°) on the combined standard deviation: the default 1/3 and three lower ones."""


def uncertainty(est) -> dict:
    """What `Status.uncertain` reads of one estimate (°): the largest rotation std, the spread
    of equally good fits, and the two combined as `is_uncertain` combines them."""
    std = float(np.degrees(rotation_std(est.covariance)))
    spread = float(np.degrees(est.spread))
    return {"std_deg": std, "spread_deg": spread, "combined_std_deg": float(np.hypot(std, spread / 2))}


def level_rows(drawn) -> list[dict]:
    """Every pair of one level through one compiled default call (`fine_variants.jaxpose_rows`)."""
    rows, _ = jaxpose_rows([case for _, case in drawn], jp.Config(), extra=uncertainty)
    return [{"pair": f"seed {seed}: {case.label}", **row} for (seed, case), row in zip(drawn, rows, strict=True)]


def summary(rows: list[dict]) -> dict:
    """Successes and false successes under each of `BOUNDS`, and the error / std ratios."""
    successes = [r for r in rows if r["status"] == SUCCESS]
    kept = {f"{bound:.3f}": [r for r in successes if r["combined_std_deg"] <= bound] for bound in BOUNDS}
    ratio = np.array([r["rotation_error_deg"] / r["combined_std_deg"] for r in successes])
    return {
        "pairs": len(rows),
        "bounds": {b: {"successes": len(k), "false": sum(not r["found"] for r in k)} for b, k in kept.items()},
        "ratio": {"median": float(np.median(ratio)), "p90": float(np.quantile(ratio, 0.9)), "max": float(ratio.max())},
        "false_successes": [r for r in successes if not r["found"]],
    }


def markdown(levels: dict[str, dict]) -> str:
    bounds = [f"{b:.3f}" for b in BOUNDS]
    head = (
        "| σ, cm | pairs | "
        + " | ".join(f"successes (false) at {b}°" for b in bounds)
        + " | rotation error / combined std: median / p90 / max |\n|---|---|"
        + "---|" * (len(bounds) + 1)
        + "\n"
    )
    lines = []
    for level, s in levels.items():
        cells = " | ".join(f"{s['bounds'][b]['successes']} ({s['bounds'][b]['false']})" for b in bounds)
        r = s["ratio"]
        lines.append(f"| {level} | {s['pairs']} | {cells} | {r['median']:.2f} / {r['p90']:.2f} / {r['max']:.2f} |")
    return head + "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", default="0,0.5,1,2")
    parser.add_argument("--seeds", default="0,1,2,3")
    parser.add_argument("--pairs", type=int, default=8)
    args = parser.parse_args()
    levels = tuple(float(x) for x in args.levels.split(","))
    seeds = tuple(int(x) for x in args.seeds.split(","))
    out = {}
    for sigma, drawn in draws(levels, seeds, args.pairs).items():
        rows = level_rows(drawn)
        out[f"{sigma:g}"] = {**summary(rows), "rows": rows}
        print(f"σ {sigma:g} cm:", {b: v for b, v in out[f"{sigma:g}"]["bounds"].items()}, flush=True)
    table = markdown(out)
    print(table)
    write_json("success_rule.json", {"args": vars(args), "levels": out})
    (RESULTS / "success_rule.md").write_text(table)


if __name__ == "__main__":
    main()
