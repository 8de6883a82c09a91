"""What the public call's stages cost and what they buy, on the realistic benchmark's pairs, GICP in the same run.

Each variant runs in its own process (a patched solver must not meet a program compiled with
the other one) over `make_cases(pairs)`: every built-in target at σ = 0, 0.5, 1 and 2 cm, one
compiled program for all pairs (`sized_batch_config`), the default config otherwise. Per pair:
the compiled build-and-estimate call's time, rotation and centroid errors (camera frame c),
status; small_gicp's GICP (as in the realistic benchmark) on the same clouds in the same run.

Variants:

- `default`: the package as it is (the fine stage's rounds by optimistix's Gauss–Newton with
  Cholesky on the normal equations, `_fine.least_squares_solver`; the refine on 4096 current
  points);
- `qr`: the fine stage's rounds by optimistix's Levenberg–Marquardt with its default QR of the
  stacked [J; √λ I];
- `levenberg_marquardt`: Levenberg–Marquardt with the same Cholesky on the normal equations;
- `refine_all`: the refine on all the current points (`Refine.points=None`);
- `points2048`, `points8192`: `FineStage.points` instead of 4096;
- `no_rest`: `FineStage.from_rest=False`.

    uv run --extra peers python experiments/call_costs.py [pairs] [variant ...]
        → results/call_costs.{json,md}
        (default: 1 pair per target and level; qr levenberg_marquardt refine_all default)
"""

from __future__ import annotations

import dataclasses
import json
import statistics
import subprocess
import sys
import time

import jax
from _common import RESULTS, write_json

VARIANTS = ("default", "qr", "refine_all", "levenberg_marquardt", "points2048", "points8192", "no_rest")


def variant_config(variant: str):
    import jaxpose as jp

    config = jp.Config()
    if variant.startswith("points"):
        return dataclasses.replace(config, fine=dataclasses.replace(config.fine, points=int(variant[6:])))
    if variant == "refine_all":
        return dataclasses.replace(config, refine=dataclasses.replace(config.refine, points=None))
    if variant == "no_rest":
        return dataclasses.replace(config, fine=dataclasses.replace(config.fine, from_rest=False))
    return config


def run_variant(variant: str, pairs: int) -> dict:
    """One variant's rows (this process only)."""
    import lineax as lx
    import optimistix as optx

    from jaxpose import _fine
    from jaxpose._estimate import STATUS_NAME, _estimate_pair
    from jaxpose._problem import sized_batch_config
    from jaxpose.evaluation import realistic

    if variant == "qr":
        _fine.least_squares_solver = lambda tol: optx.LevenbergMarquardt(rtol=tol, atol=tol)
    if variant == "levenberg_marquardt":
        _fine.least_squares_solver = lambda tol: optx.LevenbergMarquardt(
            rtol=tol, atol=tol, linear_solver=lx.Normal(lx.Cholesky())
        )
    cases = realistic.make_cases(pairs)
    config = sized_batch_config([(c.prev, c.curr) for c in cases], variant_config(variant))
    key0 = jax.random.key(0)
    t0 = time.perf_counter()
    jax.block_until_ready(_estimate_pair(cases[0].prev, cases[0].curr, config, key0))
    compile_s = time.perf_counter() - t0
    rows = []
    for i, case in enumerate(cases):
        t0 = time.perf_counter()
        est, _, _ = jax.block_until_ready(_estimate_pair(case.prev, case.curr, config, jax.random.fold_in(key0, i)))
        ms = 1e3 * (time.perf_counter() - t0)
        prev, curr = case.prev.compact(), case.curr.compact()
        t0 = time.perf_counter()
        R, t = realistic.gicp(prev, curr)
        gicp_ms = 1e3 * (time.perf_counter() - t0)
        rows.append(
            {
                "target": case.target,
                "sigma_cm": case.sigma_cm,
                "ms": ms,
                "status": STATUS_NAME[int(est.status)],
                **realistic.errors(case, est.rotation, est.translation),
                "gicp_ms": gicp_ms,
                "gicp": realistic.errors(case, R, t),
            }
        )
    return {"variant": variant, "compile_s": compile_s, "rows": rows}


def summary(rows: list[dict]) -> dict:
    found = [r["found"] for r in rows]
    return {
        "pairs": len(rows),
        "found": sum(found),
        "false_success": sum(r["status"] == "success" and not r["found"] for r in rows),
        "rotation_median_deg": statistics.median(r["rotation_error_deg"] for r in rows),
        "centroid_median_cm": statistics.median(r["centroid_error_cm"] for r in rows),
        "median_ms": statistics.median(r["ms"] for r in rows),
        "gicp_found": sum(r["gicp"]["found"] for r in rows),
        "gicp_rotation_median_deg": statistics.median(r["gicp"]["rotation_error_deg"] for r in rows),
        "gicp_centroid_median_cm": statistics.median(r["gicp"]["centroid_error_cm"] for r in rows),
        "gicp_median_ms": statistics.median(r["gicp_ms"] for r in rows),
    }


def markdown(results: list[dict]) -> str:
    lines = [
        "| variant | σ, cm | found | false succ. | rot median ° | cen median cm | median ms "
        "| GICP found | GICP rot ° | GICP cen cm | GICP ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for result in results:
        levels = sorted({r["sigma_cm"] for r in result["rows"]})
        for sigma in [*levels, "all"]:
            rows = [r for r in result["rows"] if sigma == "all" or r["sigma_cm"] == sigma]
            s = summary(rows)
            lines.append(
                f"| {result['variant']} | {sigma} | {s['found']}/{s['pairs']} | {s['false_success']} "
                f"| {s['rotation_median_deg']:.4f} | {s['centroid_median_cm']:.4f} | {s['median_ms']:.0f} "
                f"| {s['gicp_found']}/{s['pairs']} | {s['gicp_rotation_median_deg']:.4f} "
                f"| {s['gicp_centroid_median_cm']:.4f} | {s['gicp_median_ms']:.0f} |"
            )
    return "\n".join(lines) + "\n"


def main(pairs: int = 1, *variants: str) -> None:
    variants = variants or ("qr", "levenberg_marquardt", "refine_all", "default")
    unknown = set(variants) - set(VARIANTS)
    if unknown:
        raise SystemExit(f"unknown variants {sorted(unknown)}; choose from {VARIANTS}")
    results = []
    for variant in variants:
        out = subprocess.run(
            [sys.executable, __file__, "--one", str(pairs), variant], capture_output=True, text=True, check=True
        )
        results.append(json.loads(out.stdout.strip().splitlines()[-1]))
        print(variant, json.dumps(summary(results[-1]["rows"])), flush=True)
    table = markdown(results)
    print(table)
    write_json("call_costs.json", {"pairs_per_cell": pairs, "results": results})
    (RESULTS / "call_costs.md").write_text(table)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--one"]:
        print(json.dumps(run_variant(sys.argv[3], int(sys.argv[2]))))
    else:
        main(*(int(a) if i == 0 else a for i, a in enumerate(sys.argv[1:])))
