"""Fine-stage settings on the realistic benchmark's pairs, beside GICP in the same run.

    uv run --extra peers python experiments/realistic_settings.py --pairs 1 --fixed \
        default near=fine_prev_slab:3.0,fine_curr_slab:2.0,fine_points:896,fine_anchor:point

Each argument is NAME or NAME=FIELD:VALUE,… (Config fields over the default config). With
`--fixed` every pair runs at one capacity (20,480 points, a 256-cell grid, 8,192 cells): one
compile per setting instead of one per bucket, the same results, slower calls. Prints one
table by noise level, GICP beside, and writes results/realistic_settings.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import math

from _common import write_json

import jaxpose as jp
from jaxpose.evaluation import realistic

FIXED = {"max_points": 20480, "max_prev_points": 20480, "grid_cells": 256, "max_cells": 8192}


def parse(spec: str) -> tuple[str, jp.Config]:
    name, _, fields = spec.partition("=")
    changes = {}
    for item in filter(None, fields.split(",")):
        field, value = item.split(":")
        default = getattr(jp.Config(), field)
        kind = type(default) if default is not None else int
        kind = float if kind is float or value == "inf" else kind
        changes[field] = math.inf if value == "inf" else kind(value) if kind is not bool else value == "True"
    return name, dataclasses.replace(jp.Config(), **changes)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("settings", nargs="+")
    parser.add_argument("--pairs", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--fixed", action="store_true", help="one capacity for every pair")
    args = parser.parse_args()
    cases = realistic.make_cases(args.pairs, args.seed)
    rows = realistic.run_peer("small_gicp GICP", realistic.gicp, cases)
    for spec in args.settings:
        name, config = parse(spec)
        if args.fixed:
            config = dataclasses.replace(config, **FIXED)
        mine, _ = realistic.run_jaxpose(cases, config, seed=args.seed)
        rows += [r | {"method": f"jaxpose {name}"} for r in mine]
    summary = realistic.summarise(rows)
    print(realistic.markdown(sorted(summary, key=lambda s: (s["sigma_cm"], s["method"]))))
    write_json("realistic_settings.json", {"settings": args.settings, "pairs": len(cases), "summary": summary})


if __name__ == "__main__":
    main()
