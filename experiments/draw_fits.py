"""Every fit of the fine stage on chosen pairs of a `fine_draws.py` run, as that run met them.

    uv run python experiments/draw_fits.py SIGMA SEEDS LABEL [LABEL ...]
        e.g. draw_fits.py 0 4,5,6,7 "seed 5: upper_stage σ0 #4"

`fine_draws.py` runs every pair of a noise level through one compiled program, with one
capacity bucket sized for all of them (`sized_batch_config`) and the key `fold_in(key(0), i)`
of the pair's position i in the level; which fits a call meets depends on both. This rebuilds
that level's pairs (`fine_draws.draws`), the same bucket and key, and for each labelled pair
(as `fine_draws.py` prints them) prints the estimate's status and rotation error, then each
fit of `_estimate.fine_passes` (as `fine_runs.py` runs them): rotation error (°), centroid
error (cm), inlier fraction, RMS residual (mm), free-space conflict share and convergence.
Then the same pair through `jp.estimate` (capacities from the pair alone) with the
benchmark's key for its position (`fine_runs.benchmark_position`) and with `key(0)`.
"""

from __future__ import annotations

import sys

import jax
from fine_draws import draws
from fine_runs import _fits, benchmark_position

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME
from jaxpose._problem import sized_batch_config
from jaxpose.evaluation import realistic


def show(label: str, case, est) -> None:
    error = realistic.errors(case, est.rotation, est.translation)
    print(f"{label}: {STATUS_NAME[int(est.status)]}, {error['rotation_error_deg']:.3f}°")


def main(sigma: str, seeds: str, *labels: str) -> None:
    level = float(sigma)
    pairs = draws([level], [int(s) for s in seeds.split(",")], 8)[level]
    config = sized_batch_config([(case.prev, case.curr) for _, case in pairs], jp.Config())
    for i, (seed, case) in enumerate(pairs):
        label = f"seed {seed}: {case.label}"
        if label not in labels:
            continue
        est, runs, (Rs, ts), _, _ = _fits(case.prev, case.curr, config, jax.random.fold_in(jax.random.key(0), i))
        show(label, case, est)
        for k in range(Rs.shape[0]):
            fit = realistic.errors(case, Rs[k], ts[k])
            print(
                f"  fit {k}: {fit['rotation_error_deg']:.3f}°, {fit['centroid_error_cm']:.3f} cm, "
                f"inliers {float(runs.inliers[k]):.4f}, RMS {1e3 * float(runs.rms[k]):.2f} mm, "
                f"conflict {float(runs.conflict[k]):.4f}, converged {bool(runs.converged[k])}"
            )
        for name, key in (
            ("benchmark key", jax.random.fold_in(jax.random.key(0), benchmark_position(case))),
            ("key(0)", jax.random.key(0)),
        ):
            show(f"  jp.estimate, {name}", case, jp.estimate(case.prev, case.curr, key=key))


if __name__ == "__main__":
    main(*sys.argv[1:])
