"""Fine-stage settings on several draws of the realistic benchmark at once, GICP on the same clouds.

`uv run --extra peers python experiments/fine_draws.py [--levels 0.5] [--seeds 0,1,2,3] [--pairs 8]
[--variants default,residual=plane_to_plane,neighbours=10] [--from-truth] [--free-space-margin M] [--out NAME]`

Each seed draws `--pairs` pairs per target at each level (`make_cases(seed=s)`, the pairs that
draw has at that level: seed 0 holds the committed benchmark's), so four seeds give 224 pairs per
level instead of the benchmark's 56, enough to tell settings apart whose medians differ by
10–20 % (on 56 pairs the medians move by that much with the draw alone). A variant is "default"
or `FineStage` fields joined by "+", e.g. `neighbours=10+anchor=point`, another section's
field as "section.field", e.g. `patterns.cell_steps=0` (values parsed as Python literals
where they are, else kept as text). Whole calls run one compiled
`_build_and_estimate` per variant (one capacity bucket for every pair, key `fold_in(key(0), i)`
as `fine_variants.py` runs them); `--from-truth` runs the fine stage alone from each pair's true
motion instead (at σ ≤ 1 cm the whole call ends there too: docs, Findings, where the fine stage
stops under noise). Prints, per level and variant, `fine_variants.report` and
`report_by_target` against GICP (found < 1° and < 5 cm, successes, false successes, median
errors, the pairs not found; medians per target); with `--out NAME` also writes
`results/NAME.json` (every row). `--free-space-margin M` sets `_estimate.FREE_SPACE_MARGIN`
(metres) for the whole process (docs, Findings: free space decides between fits far apart).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import dataclasses

from _common import write_json
from fine_variants import fine_config, fine_constants, gicp_rows, jaxpose_rows, report, report_by_target, truth_rows

import jaxpose as jp
from jaxpose import _estimate
from jaxpose.evaluation import realistic


def variant_config(spec: str) -> jp.Config:
    """The default config with the fields of `spec` ("default" or "a=1+b=x"): `FineStage`
    fields by name, another section's as "section.field" (e.g. `patterns.cell_steps=0`)."""
    config = jp.Config()
    if spec == "default":
        return config
    settings = {}
    for part in spec.split("+"):
        name, text = part.split("=", 1)
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            value = text
        if "." in name:
            section, field = name.split(".", 1)
            changed = dataclasses.replace(getattr(config, section), **{field: value})
            config = dataclasses.replace(config, **{section: changed})
        else:
            settings[name] = value
    return fine_config(config, **settings)


def draws(levels, seeds, pairs) -> dict[float, list[tuple[int, realistic.Case]]]:
    """(seed, pair) of every seed at each level (only those pairs are simulated)."""
    out = {}
    for sigma in levels:
        tag = f"σ{sigma:g} "
        out[sigma] = [
            (seed, case)
            for seed in seeds
            for case in realistic.make_cases(pairs=pairs, seed=seed, keep=lambda label, tag=tag: tag in label)
        ]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", default="0.5")
    parser.add_argument("--seeds", default="0,1,2,3")
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--variants", default="default,residual=plane_to_plane")
    parser.add_argument("--from-truth", action="store_true")
    parser.add_argument("--out", default="")
    parser.add_argument("--free-space-margin", type=float, default=None)
    args = parser.parse_args()
    margin = args.free_space_margin
    with fine_constants(_estimate, FREE_SPACE_MARGIN=margin) if margin is not None else contextlib.nullcontext():
        run_draws(args)


def run_draws(args):
    levels = tuple(float(x) for x in args.levels.split(","))
    seeds = tuple(int(x) for x in args.seeds.split(","))
    variants = args.variants.split(",")
    configs = {spec: variant_config(spec) for spec in variants}
    run = truth_rows if args.from_truth else jaxpose_rows
    payload = {"args": vars(args), "levels": {}}
    for sigma, drawn in draws(levels, seeds, args.pairs).items():
        cases = [case for _, case in drawn]
        print(f"σ {sigma:g} cm, {len(cases)} pairs (seeds {args.seeds})", flush=True)
        rows = {"GICP": gicp_rows(cases)}
        for spec in variants:
            rows[spec], compile_s = run(cases, configs[spec])
            report(spec, cases, rows[spec], rows["GICP"], compile_s, [sigma])
            report_by_target(cases, rows[spec], rows["GICP"], [sigma])
        labels = [f"seed {seed}: {case.label}" for seed, case in drawn]
        payload["levels"][f"{sigma:g}"] = {"pairs": labels, "rows": rows}
    if args.out:
        write_json(f"{args.out}.json", payload)


if __name__ == "__main__":
    main()
