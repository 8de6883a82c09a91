"""What the fine stage buys (issue 4): the default config with and without it.

- the paper's four noise-free pairs: largest angle (°) and translation-component (cm)
  errors in frame n, and time per pair;
- eight N5 pairs at 5.5 m in the paper's previous attitude, rotated 10° about a random
  axis, with 1 cm range noise: rotation error (°).

    uv run python experiments/fine_stage.py  →  results/fine_stage.json
"""

import math
import statistics
import time

import jax
import numpy as np
from _common import write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, estimate_problem
from jaxpose.evaluation.comparison import pair_errors
from jaxpose.sim import paper_pairs, paper_pose, rotated_pair

NOISY_PAIRS = 8


def run(pairs, config, repeats=1):
    rows = []
    for i, pair in enumerate(pairs):
        problem = jp.Problem.build(pair.prev, pair.curr, config)
        key = jax.random.key(i)
        jax.block_until_ready(estimate_problem(problem, config, key))  # compile
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            est = jax.block_until_ready(estimate_problem(problem, config, key))
            times.append(time.perf_counter() - t0)
        e = pair_errors(pair, est.rotation, est.translation, problem.frame)
        rows.append({"pair": pair.label, **e, "status": STATUS_NAME[int(est.status)],
                     "seconds": statistics.median(times)})  # fmt: skip
        print(rows[-1])
    return rows


def main():
    camera = jp.Camera.camcube2(noise_sigma=0.01)
    attitude = paper_pose("previous")[0]
    noisy = [rotated_pair(jax.random.key(i), math.radians(10), attitude=attitude, camera=camera)
             for i in range(NOISY_PAIRS)]  # fmt: skip
    out = {}
    for fine, stage in (("default", jp.Config().fine), ("none", None)):
        config = jp.Config(capacities=jp.Capacities(max_points=6144), fine=stage)
        paper = run(paper_pairs(), config, repeats=3)
        noise = run(noisy, config)
        rot = np.array([r["rotation_error_deg"] for r in noise])
        out[fine] = {
            "paper_max_angle_error_deg": max(r["angle_error_deg"] for r in paper),
            "paper_max_translation_error_cm": max(r["translation_error_cm"] for r in paper),
            "paper_median_ms": 1000 * statistics.median(r["seconds"] for r in paper),
            "noisy_rotation_error_deg_median": float(np.median(rot)),
            "noisy_rotation_error_deg_max": float(rot.max()),
            "noisy_success": sum(r["status"] == "success" for r in noise),
            "paper": paper,
            "noisy": noise,
        }
        print(fine, {k: v for k, v in out[fine].items() if not isinstance(v, list)})
    write_json("fine_stage.json", out)


if __name__ == "__main__":
    main()
