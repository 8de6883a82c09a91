"""float32 vs float64 (issue 6): the same estimate (default config, same key) on the paper's
four pairs, once per precision in a fresh process; differences in frame n (degrees, cm).

    uv run python experiments/precision.py  →  results/precision.json
"""

import numpy as np
from _common import run_child, write_json

CHILD = r"""
import json, sys
import jax
jax.config.update("jax_enable_x64", sys.argv[1] == "64")
sys.path.insert(0, "experiments")
from _common import paper_cloud
import jaxpose as jp
from jaxpose._estimate import estimate_problem
config = jp.Config(capacities=jp.Capacities(max_points=5120))
out = {}
for shape in ("n1", "n5"):
    for variant in ("variant 1", "variant 2"):
        pb = jp.Problem.build(paper_cloud(shape, "previous"), paper_cloud(shape, variant), config)
        est = estimate_problem(pb, config, jax.random.key(0))
        out[f"{shape} {variant}"] = {"params": [float(x) for x in est.params], "status": int(est.status),
                                     "global_params": [float(x) for x in est.search.params]}
print(json.dumps(out))
"""


def main():
    r32, r64 = run_child(CHILD, "32"), run_child(CHILD, "64")
    units = np.array([180 / np.pi] * 3 + [100] * 3)
    rows = []
    for pair in r32:
        diff = (np.array(r64[pair]["params"]) - np.array(r32[pair]["params"])) * units
        gdiff = (np.array(r64[pair]["global_params"]) - np.array(r32[pair]["global_params"])) * units
        rows.append(
            {
                "pair": pair,
                "max_angle_diff_deg": float(np.max(np.abs(diff[:3]))),
                "max_translation_diff_cm": float(np.max(np.abs(diff[3:]))),
                "global_stage_max_diff_deg_cm": [float(np.max(np.abs(gdiff[:3]))), float(np.max(np.abs(gdiff[3:])))],
                "status_32": r32[pair]["status"],
                "status_64": r64[pair]["status"],
            }
        )
        print(rows[-1])
    write_json("precision.json", {"config": "default", "key": 0, "rows": rows})


if __name__ == "__main__":
    main()
