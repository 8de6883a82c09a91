"""Every fit of the default fine stage on chosen pairs of the realistic benchmark.

`uv run python experiments/fine_runs.py [PREFIX ...] [--seed S] [--out FILE.json]`

For each pair of `jaxpose.evaluation.realistic.make_cases(8, seed=S)` (S = 0: the benchmark's pairs)
whose label starts with one of the prefixes (only those are simulated; default: the upper
stage at σ 0.5, 1 and 2 cm, and the satellite at σ 2 cm), the default `estimate` with the
benchmark's key, then the fine stage's passes again from the same starts
(`_estimate.fine_passes`: from the refine's result, from rest, from the best of those turned
by ±`FineStage.turn_deg` about the near-symmetry axis where the view has one, and the
polish). Per fit: its rotation error (degrees) and
centroid error (cm) against the truth, inlier fraction and inlier RMS residual (mm); an
inactive fit has no inliers. With the status and errors of the estimate and of the soft
refine that started the first fit, and the ratio of the previous cloud's two largest
principal moments. This shows how far apart the right and the wrong fits of a near-symmetric
target are (docs, Findings: turns about a near-symmetry axis), and how far a fit slides
along the faces from where the refine left it (docs, Findings: slides along the faces).
`--plane-source` sets `FineStage.plane_source` (docs, Findings: planes among every previous
point). `results/fine_runs_TARGET.json` hold every pair's fits per target (`fine_runs.py TARGET --out
results/fine_runs_TARGET.json`), which `fine_ranking.py` ranks by other rules.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from fine_variants import fine_config

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, estimate_problem, fine_passes, symmetry_turns
from jaxpose._poses import motion_from_displacement
from jaxpose._problem import _build, sized_config
from jaxpose.evaluation import realistic

DEFAULT_PREFIXES = ("upper_stage σ0.5", "upper_stage σ1", "upper_stage σ2", "satellite σ2")


@eqx.filter_jit
def _fits(prev, curr, config, key):
    """The estimate, the fine stage's passes from its starts, and their camera-frame motions."""
    problem = _build(prev, curr, config)
    est = estimate_problem(problem, config, key)
    starts = jnp.stack([est.refine.params, jnp.zeros(6, est.params.dtype)])
    turns = symmetry_turns(problem.frame, config) if config.fine.turn_deg > 0 else None
    runs = fine_passes(problem, config, starts, turns)

    def motion(p):
        return motion_from_displacement(problem.frame.origin, problem.frame.axes, p)

    return est, runs, jax.vmap(motion)(runs.params), motion(est.refine.params), problem.frame.inertia


def benchmark_position(case) -> int:
    """The pair's position in `make_cases(8)`, the whole benchmark (its key there)."""
    names, levels = jp.targets.BUILT_IN, realistic.LEVELS_CM
    return (names.index(case.target) * len(levels) + levels.index(case.sigma_cm)) * 8 + case.index


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("prefixes", nargs="*", default=list(DEFAULT_PREFIXES))
    parser.add_argument("--out", type=Path, default=None, help="write the rows as JSON here")
    parser.add_argument("--seed", type=int, default=0, help="the draw (make_cases(seed=...)); 0: the benchmark's")
    parser.add_argument(
        "--plane-source",
        default="selected",
        choices=("selected", "all", "all_centroids"),
        help="FineStage.plane_source",
    )
    args = parser.parse_args()
    base = fine_config(jp.Config(), plane_source=args.plane_source)
    rows = []

    def wanted(label):
        return any(label.startswith(prefix) for prefix in args.prefixes)

    for case in realistic.make_cases(8, seed=args.seed, keep=wanted):
        i = benchmark_position(case)
        prev, curr = case.prev.floating(), case.curr.floating()
        config = sized_config(prev, curr, base)
        est, runs, (Rs, ts), (R_refine, t_refine), moments = _fits(
            prev, curr, config, jax.random.fold_in(jax.random.key(0), i)
        )
        error = realistic.errors(case, est.rotation, est.translation)
        refine = realistic.errors(case, R_refine, t_refine)
        fits = [realistic.errors(case, Rs[k], ts[k]) for k in range(Rs.shape[0])]
        row = {
            "label": case.label,
            "status": STATUS_NAME[int(est.status)],
            "rotation_error_deg": round(error["rotation_error_deg"], 4),
            "centroid_error_cm": round(error["centroid_error_cm"], 4),
            "refine_rotation_error_deg": round(refine["rotation_error_deg"], 3),
            "refine_centroid_error_cm": round(refine["centroid_error_cm"], 3),
            "moment_ratio": round(float(moments[1] / moments[0]), 4),
            "fits_rotation_error_deg": [round(f["rotation_error_deg"], 4) for f in fits],
            "fits_centroid_error_cm": [round(f["centroid_error_cm"], 4) for f in fits],
            "fits_inliers": np.round(np.asarray(runs.inliers), 4).tolist(),
            "fits_rms_mm": np.round(np.asarray(runs.rms) * 1000, 2).tolist(),
            "fits_conflict": np.round(np.asarray(runs.conflict), 5).tolist(),
            "fits_converged": np.asarray(runs.converged).tolist(),
        }
        rows.append(row)
        print(json.dumps(row, ensure_ascii=False), flush=True)
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=1, ensure_ascii=False))


if __name__ == "__main__":
    main()
