"""Consistency of the measurement covariances (issue 7): NEES over a Monte Carlo run.

Pairs: N5 at 5.5 m in the paper's previous attitude, rotated 10° about a random axis, 1 cm
range noise. Two covariances of the estimate p̂ (the fine stage's result):

- **soft Hessian**: Σ = s² H⁻¹ of the soft objective (`uncertainty.covariance`); f is not a
  likelihood, so s² is chosen on a calibration set (mean NEES = 6) and checked on an
  independent validation set;
- **fine least squares**: Σ = σ̂² (JᵀJ)⁻¹ of the fine stage (`fine.fine_covariance`), used as
  it is (no calibration) on both sets, and also with a scale calibrated the same way.

Consistent means: the validation mean NEES lies in the two-sided 95 % interval of χ²(6N)/N.

    uv run python experiments/nees.py  →  results/nees.json
"""

import dataclasses
import math

import jax
import numpy as np
from _common import NEAR_PLANE_FINE, full_search, write_json
from scipy.stats import chi2

import jaxpose as jp
from jaxpose._estimate import SUCCESS, estimate_problem
from jaxpose._fine import fine_covariance
from jaxpose._uncertainty import curvature
from jaxpose.sim import paper_pose, rotated_pair

PAIRS = 20  # per set
# The centroid anchor of `Config.tracking()`, whose registrations the scale is used for.
CONFIG = full_search(
    6144,
    search=dataclasses.replace(full_search().search, recentre=0),
    fine=dataclasses.replace(NEAR_PLANE_FINE, anchor="centroid"),
)


def run(offset):
    camera = jp.Camera.camcube2(noise_sigma=0.01)
    quad, fine_nees = [], []
    hess = jax.jit(curvature)
    fine_cov = jax.jit(fine_covariance, static_argnums=1)
    for j in range(PAIRS):
        key = jax.random.key(offset + j)
        pair = rotated_pair(key, math.radians(10), attitude=paper_pose("previous")[0], camera=camera)
        problem = jp.Problem.build(pair.prev, pair.curr, CONFIG)
        est = estimate_problem(problem, CONFIG, jax.random.key(j))
        if int(est.status) != SUCCESS:
            continue
        error = np.asarray(est.params - jp.true_displacement(problem.frame, pair.R1, pair.t1, pair.R2, pair.t2))
        H = np.asarray(hess(est.params, problem))
        quad.append(float(error @ H @ error))  # NEES × s²
        fine_nees.append(float(error @ np.linalg.solve(np.asarray(fine_cov(problem, CONFIG, est.params)), error)))
    return np.asarray(quad), np.asarray(fine_nees)


def check(name, calibration, validation, calibrate=True):
    scale2 = float(np.mean(calibration) / 6) if calibrate else 1.0
    n = len(validation)
    mean_nees = float(np.mean(validation) / scale2)
    bounds = (float(chi2.ppf(0.025, 6 * n) / n), float(chi2.ppf(0.975, 6 * n) / n))
    consistent = bool(bounds[0] <= mean_nees <= bounds[1])
    print(f"{name}: s² = {scale2:.3g}; validation mean NEES {mean_nees:.2f} over {n} pairs, 95 % bounds "
          f"({bounds[0]:.2f}, {bounds[1]:.2f}): {'consistent' if consistent else 'NOT consistent'}")  # fmt: skip
    return {"scale2": scale2, "calibration_used": len(calibration), "validation_used": n,
            "validation_mean_nees": mean_nees, "bounds_95": bounds, "consistent": consistent,
            "validation_nees": (validation / scale2).round(3).tolist()}  # fmt: skip


def main():
    (soft_cal, fine_cal), (soft_val, fine_val) = run(0), run(10_000)
    write_json(
        "nees.json",
        {
            "pairs_per_set": PAIRS,
            "soft_hessian_calibrated": check("soft Hessian, calibrated", soft_cal, soft_val),
            "fine_least_squares_as_is": check("fine LS, as is", fine_cal, np.concatenate([fine_cal, fine_val]), False),
            "fine_least_squares_calibrated": check("fine LS, calibrated", fine_cal, fine_val),
        },
    )


if __name__ == "__main__":
    main()
