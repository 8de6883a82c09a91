"""Consistency of `Estimate.covariance` on varied data: the rotation NEES on realistic pairs,
and the calibration of `jaxpose._uncertainty.COVARIANCE_SCALE` on them.

`uv run python experiments/nees_realistic.py [--seed 5] [--pairs 6]`
→ `results/nees_realistic_seed<seed>.{json,md}` (a check of the covariance on one draw)

`uv run python experiments/nees_realistic.py --calibrate [--seeds 2 3 4] [--pairs 6]`
→ `results/covariance_calibration.{json,md}` (the factor the covariance needs on those draws)

Pairs: the realistic benchmark's generator (`jaxpose.evaluation.realistic.make_cases`, every
built-in target, σ = 0.5, 1 and 2 cm, `--pairs` pairs each, draws other than the benchmark's
seed 0 and its held-out seed 1), estimated with the default config through
`jp.estimate_batch` (one compiled program per draw, capacities sized over all its pairs).

Per pair: the rotation error e = log(R̂ Rᵀ) (radians, camera frame) and its NEES
eᵀ Σ_rr⁻¹ e against the rotation block of `Estimate.covariance`. A consistent covariance gives
χ²(3): mean 3, median 2.37, and 5 % of pairs above 7.81. The check reports, per target, for
the successes and for the other statuses apart: pairs, mean, median, and the fraction above
7.81, and the false successes (success, but more than 1° or 1 cm off: `realistic.errors`).

The calibration multiplies the covariance by a factor k and finds the k at which the median
NEES of the successes is χ²(3)'s median. A larger covariance also turns successes into
`Status.uncertain` (`jaxpose._estimate.is_uncertain`), which changes the set the median is
taken over, so k is found by bisection with the set recomputed at each k. The median, not the
mean: a few fits with a biased minimum (NEES in the hundreds) would set the mean alone. The
factor is relative to the `COVARIANCE_SCALE` of the run; the scale it implies is their
product, and after the scale is set, the same command gives k ≈ 1.
"""

from __future__ import annotations

import argparse
import collections

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from _common import RESULTS, stacked, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, is_uncertain
from jaxpose._uncertainty import COVARIANCE_SCALE, nees
from jaxpose.evaluation import realistic

CHI2_3_95 = 7.81
"""The 95th percentile of χ²(3)."""

CHI2_3_MEDIAN = 2.366
"""The median of χ²(3)."""


def rotation_error(estimate_rotation, true_rotation) -> np.ndarray:
    """e = log(R̂ Rᵀ), radians, camera frame."""
    return np.asarray(jaxlie.SO3.from_matrix(np.asarray(estimate_rotation, float) @ true_rotation.T).log())


def pairs_of(seed: int, pairs: int) -> list[dict]:
    """One record per noisy pair of the draw `seed`: target, σ (cm), status, the rotation
    error e (radians), `Estimate.covariance` (camera frame, rad then m), the spread (radians)
    and whether the estimate is found."""
    cases = [c for c in realistic.make_cases(pairs, seed=seed) if c.sigma_cm > 0]
    prev, curr = stacked([c.prev for c in cases]), stacked([c.curr for c in cases])
    est = jax.block_until_ready(jp.estimate_batch(prev, curr, key=jax.random.key(seed)))
    return [
        {
            "target": case.target,
            "sigma_cm": case.sigma_cm,
            "status": STATUS_NAME[int(est.status[i])],
            "error": rotation_error(est.rotation[i], case.rotation),
            "covariance": np.asarray(est.covariance[i], float),
            "spread": float(est.spread[i]),
            "found": realistic.errors(case, est.rotation[i], est.translation[i])["found"],
        }
        for i, case in enumerate(cases)
    ]


def rotation_nees(record: dict, factor: float = 1.0) -> float:
    """`jaxpose._uncertainty.nees` of a record's rotation error against its covariance's
    rotation block × factor."""
    return float(nees(record["error"], factor * record["covariance"][:3, :3]))


def successes_at(records: list[dict], factor: float, config: jp.Config) -> np.ndarray:
    """Which records' estimates are successes with their covariance × factor: successes of the
    run that `is_uncertain` still passes (a larger covariance only turns successes into
    `uncertain`)."""
    covariance = jnp.asarray(factor * np.stack([r["covariance"] for r in records]))
    spread = jnp.asarray([r["spread"] for r in records])
    uncertain = jax.vmap(is_uncertain, in_axes=(0, None, 0))(covariance, config, spread)
    return np.array([r["status"] == "success" for r in records]) & ~np.asarray(uncertain)


def outcome(records: list[dict], factor: float, config: jp.Config) -> dict:
    """Successes, false successes and the successes' NEES median / fraction above 7.81 at a factor."""
    kept = [r for r, success in zip(records, successes_at(records, factor, config), strict=True) if success]
    values = np.array([rotation_nees(r, factor) for r in kept])
    return {
        "factor": factor,
        "scale": factor * COVARIANCE_SCALE,
        "successes": len(kept),
        "false_successes": sum(not r["found"] for r in kept),
        "median_nees": float(np.median(values)),
        "above_95": float(np.mean(values > CHI2_3_95)),
    }


def calibrated_factor(records: list[dict], config: jp.Config) -> float:
    """The factor at which the successes' median NEES is χ²(3)'s median (bisection on log k)."""
    low, high = 0.1, 10.0
    for _ in range(40):
        mid = np.sqrt(low * high)
        low, high = (mid, high) if outcome(records, mid, config)["median_nees"] > CHI2_3_MEDIAN else (low, mid)
    return float(np.sqrt(low * high))


def calibrate(seeds: list[int], pairs: int) -> None:
    config = jp.Config()
    records = [r for seed in seeds for r in pairs_of(seed, pairs)]
    factor = calibrated_factor(records, config)
    rows = [outcome(records, k, config) for k in (1.0, factor)]
    lines = [
        f"Calibration of `COVARIANCE_SCALE` (run with {COVARIANCE_SCALE}) on realistic draws {seeds} "
        f"({pairs} pairs per target and σ = 0.5 / 1 / 2 cm, {len(records)} pairs): the factor at which "
        "the successes' median rotation NEES is χ²(3)'s, 2.37.",
        "",
        "| factor | scale | successes | false successes | median NEES | above 7.81 |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['factor']:.3f} | {row['scale']:.2f} | {row['successes']} | {row['false_successes']} | "
            f"{row['median_nees']:.2f} | {row['above_95']:.2f} |"
        )
    table = "\n".join(lines) + "\n"
    print(table)
    write_json(
        "covariance_calibration.json",
        {"seeds": seeds, "pairs": pairs, "run_scale": COVARIANCE_SCALE, "factor": factor, "rows": rows},
    )
    (RESULTS / "covariance_calibration.md").write_text(table)


def summarise(records: list[dict]) -> list[dict]:
    """Per target and for all: NEES over the successes and over the other statuses apart,
    and the false successes."""
    groups = collections.defaultdict(list)
    for r in records:
        success = r["status"] == "success"
        for target in (r["target"], "all"):
            groups[(target, success)].append(r)
    summary = []
    for (target, success), group in sorted(groups.items(), key=lambda kv: (kv[0][0] == "all", kv[0])):
        v = np.array([rotation_nees(r) for r in group])
        summary.append(
            {
                "target": target,
                "success": success,
                "pairs": len(v),
                "mean": float(v.mean()),
                "median": float(np.median(v)),
                "above_95": float(np.mean(v > CHI2_3_95)),
                "false_successes": sum(success and not r["found"] for r in group),
            }
        )
    return summary


def check(seed: int, pairs: int) -> None:
    summary = summarise(pairs_of(seed, pairs))
    lines = [
        f"Rotation NEES of `Estimate.covariance` (`COVARIANCE_SCALE` {COVARIANCE_SCALE}), realistic pairs "
        f"(seed {seed}, {pairs} per target and σ = 0.5 / 1 / 2 cm), default config; χ²(3): mean 3, median 2.37, "
        "5 % above 7.81.",
        "",
        "| target | status | pairs | mean | median | above 7.81 | false successes |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summary:
        status = "success" if s["success"] else "other"
        false = s["false_successes"] if s["success"] else "–"
        lines.append(
            f"| {s['target']} | {status} | {s['pairs']} | {s['mean']:.2f} | {s['median']:.2f} | "
            f"{s['above_95']:.2f} | {false} |"
        )
    table = "\n".join(lines) + "\n"
    print(table)
    name = f"nees_realistic_seed{seed}"
    write_json(f"{name}.json", {"seed": seed, "pairs": pairs, "scale": COVARIANCE_SCALE, "summary": summary})
    (RESULTS / f"{name}.md").write_text(table)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=5, help="the draw to check")
    parser.add_argument("--pairs", type=int, default=6, help="pairs per target and noise level")
    parser.add_argument("--calibrate", action="store_true", help="calibrate the scale on --seeds")
    parser.add_argument("--seeds", type=int, nargs="+", default=[2, 3, 4], help="the draws to calibrate on")
    args = parser.parse_args()
    if args.calibrate:
        calibrate(args.seeds, args.pairs)
    else:
        check(args.seed, args.pairs)


if __name__ == "__main__":
    main()
