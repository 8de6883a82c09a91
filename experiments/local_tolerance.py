"""A stage's stopping tolerance against status, steps and error: the paper's four pairs × 3
keys. Error = largest |found − truth| component in frame n (degrees or cm).

- default: the refine's `Config.local_tol` (units of 1° and 1 cm) in `Config.thorough()`;
- `fine`: the fine stage's `Config.fine_tol` (LM's rtol = atol, same units) in the default
  config, with the fine stage's LM steps over all its rounds (`Estimate.stats["fine_steps"]`).

    uv run python experiments/local_tolerance.py       →  results/local_tolerance.json
    uv run python experiments/local_tolerance.py fine  →  results/fine_tolerance.json

Steps and errors only, no timings (they do not depend on what else runs on the machine).
"""

import sys

import jax
import numpy as np
from _common import T_PAPER, paper_cloud, paper_rotation, write_json

import jaxpose as jp
from jaxpose._estimate import SUCCESS, estimate_problem

SWEEPS = {
    # name: (Config field, values, preset, Estimate field counting the stage's steps, output)
    "local": ("local_tol", (1e-5, 1e-4, 3e-4), "thorough", "local_steps", "local_tolerance.json"),
    "fine": ("fine_tol", (1e-6, 1e-5, 1e-4, 1e-3), "accurate", "fine_steps", "fine_tolerance.json"),
}


def main(sweep: str = "local", keys: int = 3):
    field, values, preset, steps_field, output = SWEEPS[sweep]
    rows = []
    for tol in values:
        config = getattr(jp.Config, preset)(max_points=5120, **{field: tol})
        runs = []
        for shape in ("n1", "n5"):
            for variant in ("variant 1", "variant 2"):
                problem = jp.Problem.build(paper_cloud(shape, "previous"), paper_cloud(shape, variant), config)
                for k in range(keys):
                    est = estimate_problem(problem, config, jax.random.key(k))
                    truth = jp.true_displacement(
                        est.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER
                    )
                    err = np.abs(np.asarray(est.params - truth)) * np.array([180 / np.pi] * 3 + [100] * 3)
                    runs.append((int(est.status) == SUCCESS, int(getattr(est, steps_field)), float(err.max())))
        ok, steps, err = zip(*runs, strict=True)
        rows.append(
            {
                field: tol,
                "preset": preset,
                "runs": len(runs),
                "success": int(sum(ok)),
                f"median_{steps_field}": float(np.median(steps)),
                f"max_{steps_field}": int(max(steps)),
                "max_error_deg_or_cm": max(err),
                "median_error_deg_or_cm": float(np.median(err)),
            }
        )
        print(rows[-1])
    write_json(output, {"rows": rows})


if __name__ == "__main__":
    main(*sys.argv[1:2])
