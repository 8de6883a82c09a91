"""Where the fine stage stops under range noise: a whole call's result fitted again, beside the fit
from the true motion.

`uv run python experiments/fine_restart.py [--pairs 8] [--levels 0.5,1,2] [--seed 0]`
→ `results/fine_restart.{json,md}`

For `--pairs` pairs per target and noise level of the realistic benchmark (the benchmark's own
pairs with the default levels and seed: `make_cases(levels=(0, 0.5, 1, 2))`, those of the chosen
levels kept), each pair runs:

- the whole default call (`_build_and_estimate`, one compiled program for all pairs, key
  `fold_in(key(0), i)` as `fine_variants.py` runs it);
- the fine stage alone (`fine_refine`) started again at that call's result ("again");
- the fine stage alone started at the true motion ("from the truth", what
  `fine_minimum.py` calls the objective's own minimum);
- the last two with `_fine.NOISE_STEP` = 0, so that only `ROUND_TOL` or `FineStage.rounds`
  ends a fit.

If the objective had one minimum that the rounds reach, "again" and "from the truth" would end
in the same place. Reported per level and per target: median rotation (°) and centroid (cm)
errors of each fit, the share of converged fits, and how far "again" moved from the whole call
and ended from the fit from the truth (median rotation angle between them, °).
"""

from __future__ import annotations

import argparse
import functools
import statistics

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import RESULTS, write_json
from fine_variants import fine_constants

import jaxpose as jp
from jaxpose import _fine
from jaxpose._estimate import _build_and_estimate, rotation_between
from jaxpose._fine import fine_refine
from jaxpose._poses import displacement_from_motion, motion_from_displacement
from jaxpose._problem import sized_batch_config
from jaxpose._programs import release_all
from jaxpose.evaluation import realistic

FITS = ("whole", "again", "truth", "again_no_noise_stop", "truth_no_noise_stop")


def fit_errors(case, problem, p) -> tuple[float, float]:
    """Rotation (°) and centroid (cm) errors of p (frame n) against the case's true motion."""
    R, t = motion_from_displacement(problem.frame.origin, problem.frame.axes, p)
    e = realistic.errors(case, R, t)
    return e["rotation_error_deg"], e["centroid_error_cm"]


def restart_rows(cases, config) -> list[dict]:
    """Each case's whole call, then the fine stage from its result and from the truth, with
    the noise-scaled stop and without it (`FITS`)."""
    release_all()
    run = eqx.filter_jit(_build_and_estimate)
    rows = []
    for i, case in enumerate(cases):
        est, _, _ = run(case.prev, case.curr, config, jax.random.fold_in(jax.random.key(0), i))
        problem = jp.Problem.build(case.prev, case.curr, config)
        truth = displacement_from_motion(problem.frame.origin, problem.frame.axes, case.rotation, case.translation)
        starts = {"again": est.params, "truth": truth.astype(problem.d.dtype)}
        params = {"whole": est.params}
        converged = {"whole": bool(est.fine.converged)}
        for stop, suffix in ((_fine.NOISE_STEP, ""), (0.0, "_no_noise_stop")):
            fit = noise_stop_fit(stop)
            for name, start in starts.items():
                result = fit(problem, config, start)
                params[name + suffix] = result.params
                converged[name + suffix] = bool(result.converged)
        row = {"target": case.target, "sigma_cm": case.sigma_cm, "pair": case.index, "status": int(est.status)}
        for name in FITS:
            rot, cen = fit_errors(case, problem, params[name])
            row[name] = {"rotation_error_deg": rot, "centroid_error_cm": cen, "converged": converged[name]}
        row["again_moved_deg"] = float(jnp.degrees(rotation_between(params["whole"], params["again"])))
        row["again_to_truth_deg"] = float(jnp.degrees(rotation_between(params["again"], params["truth"])))
        rows.append(row)
        print(
            f"{case.label:24s} "
            + " | ".join(f"{n} {row[n]['rotation_error_deg']:.3f} {row[n]['centroid_error_cm']:.3f}" for n in FITS),
            flush=True,
        )
    return rows


@functools.cache
def noise_stop_fit(stop: float):
    """`fine_refine`, jitted with `_fine.NOISE_STEP` = `stop` (read when it is traced)."""

    def fit(problem, config, start):
        with fine_constants(NOISE_STEP=stop):
            return fine_refine(problem, config, start)

    return eqx.filter_jit(fit)


def summary(rows) -> dict:
    """Medians of each fit's errors, its share of converged fits, and the medians of how far
    "again" moved and ended from the fit from the truth."""
    out = {"pairs": len(rows)}
    for name in FITS:
        out[name] = {
            "rotation_median_deg": statistics.median(r[name]["rotation_error_deg"] for r in rows),
            "centroid_median_cm": statistics.median(r[name]["centroid_error_cm"] for r in rows),
            "converged": sum(r[name]["converged"] for r in rows),
        }
    out["again_moved_median_deg"] = statistics.median(r["again_moved_deg"] for r in rows)
    out["again_to_truth_median_deg"] = statistics.median(r["again_to_truth_deg"] for r in rows)
    return out


def table(groups: dict) -> list[str]:
    head = (
        "| group | pairs | whole call | again | from the truth | again, no noise stop | from the truth, no noise "
        "stop | again moved, ° | again to truth, ° |"
    )
    lines = [head, "|" + "---|" * 9]
    for label, s in groups.items():
        cells = [
            f"{s[n]['rotation_median_deg']:.3f}° / {s[n]['centroid_median_cm']:.3f} cm ({s[n]['converged']} conv.)"
            for n in FITS
        ]
        lines.append(
            f"| {label} | {s['pairs']} | "
            + " | ".join(cells)
            + f" | {s['again_moved_median_deg']:.3f} | {s['again_to_truth_median_deg']:.3f} |"
        )
    return lines


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=8)
    parser.add_argument("--levels", default="0.5,1,2")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    levels = tuple(float(x) for x in args.levels.split(","))
    cases = [
        c
        for c in realistic.make_cases(pairs=args.pairs, levels=realistic.LEVELS_CM, seed=args.seed)
        if c.sigma_cm in levels
    ]
    config = sized_batch_config([(c.prev, c.curr) for c in cases], jp.Config())
    rows = restart_rows(cases, config)
    by_level = {f"σ {s:g} cm": summary([r for r in rows if r["sigma_cm"] == s]) for s in levels}
    by_target = {
        f"{t}, σ {s:g} cm": summary([r for r in rows if r["sigma_cm"] == s and r["target"] == t])
        for s in levels
        for t in dict.fromkeys(c.target for c in cases)
    }
    write_json(
        "fine_restart.json",
        {"args": vars(args), "by_level": by_level, "by_target": by_target, "rows": rows},
    )
    lines = [
        f"`experiments/fine_restart.py --pairs {args.pairs} --levels {args.levels} --seed {args.seed}`: "
        "median rotation / centroid error of each fit and its converged fits; the last two columns: "
        "median rotation angle between the whole call's result and the refit from it, and between that "
        "refit and the fit from the truth.",
        "",
        *table(by_level),
        "",
        *table(by_target),
    ]
    (RESULTS / "fine_restart.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
