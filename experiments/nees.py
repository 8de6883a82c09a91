"""Consistency of the Hessian covariance (issue 7): calibrate, then check NEES.

Pairs: N5 at 5.5 m in the paper's previous attitude, rotated 10° about a random axis, 1 cm
range noise. On a calibration set the scale s² of Σ = s² H⁻¹ is chosen so that the mean
NEES is 6; on an independent validation set the mean NEES should then lie in the two-sided
95 % interval of χ²(6N)/N.

    uv run python experiments/nees.py  →  results/nees.json
"""

import math

import jax
import numpy as np
from _common import write_json
from scipy.stats import chi2

import jaxpose as jp
from jaxpose.estimate import SUCCESS, estimate_problem
from jaxpose.scenarios import paper_pose, rotated_pair
from jaxpose.uncertainty import curvature

PAIRS = 20  # per set
CONFIG = jp.Config.accurate(max_points=6144, recentre=0)


def run(offset):
    camera = jp.Camera.camcube2(noise_sigma=0.01)
    quad = []
    hess = jax.jit(curvature)
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
    return np.asarray(quad)


def main():
    calibration, validation = run(0), run(10_000)
    scale2 = float(np.mean(calibration) / 6)
    n = len(validation)
    mean_nees = float(np.mean(validation) / scale2)
    bounds = (chi2.ppf(0.025, 6 * n) / n, chi2.ppf(0.975, 6 * n) / n)
    bounds = (float(bounds[0]), float(bounds[1]))
    consistent = bool(bounds[0] <= mean_nees <= bounds[1])
    print(f"s² = {scale2:.3g}; validation mean NEES {mean_nees:.2f} over {n} pairs, 95 % bounds {bounds}: "
          f"{'consistent' if consistent else 'NOT consistent'}")  # fmt: skip
    write_json(
        "nees.json",
        {"pairs_per_set": PAIRS, "calibration_used": len(calibration), "validation_used": n, "scale2": scale2,
         "validation_mean_nees": mean_nees, "bounds_95": bounds, "consistent": consistent,
         "validation_nees": (validation / scale2).round(3).tolist()},
    )  # fmt: skip


if __name__ == "__main__":
    main()
