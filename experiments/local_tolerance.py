"""The refine's stopping tolerance (`Config.local_tol`, units of 1° and 1 cm) against its
status and error: the paper's four pairs × 3 keys, default config otherwise. Error = largest
|found − truth| component in frame n (degrees or cm).

    uv run python experiments/local_tolerance.py  →  results/local_tolerance.json
"""

import jax
import numpy as np
from _common import T_PAPER, paper_cloud, paper_rotation, write_json

import jaxpose as jp
from jaxpose.estimate import SUCCESS, estimate_problem


def main(keys: int = 3):
    rows = []
    for tol in (1e-5, 1e-4, 3e-4):
        config = jp.Config.thorough(max_points=5120, local_tol=tol)
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
                    runs.append((int(est.status) == SUCCESS, int(est.local_steps), float(err.max())))
        ok, steps, err = zip(*runs, strict=True)
        rows.append(
            {
                "local_tol": tol,
                "runs": len(runs),
                "success": int(sum(ok)),
                "median_local_steps": float(np.median(steps)),
                "max_error_deg_or_cm": max(err),
                "median_error_deg_or_cm": float(np.median(err)),
            }
        )
        print(rows[-1])
    write_json("local_tolerance.json", {"rows": rows})


if __name__ == "__main__":
    main()
