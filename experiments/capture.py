"""Capture (issue 4): success rate of `estimate` in wide mode over random pairs.

Each pair: N5 at 5.5 m on the optical axis with a uniformly random attitude R1, then
rotated by an angle uniform in [5°, 45°] about a random axis through its origin (R2 = ΔR
R1). Noise-free clouds. Success = rotation error of the camera-frame motion < 1° (and the
status); pairs whose previous cloud has no usable plane frame are counted separately.

    uv run python experiments/capture.py  →  results/capture_wide.json
"""

import time

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from _common import T_PAPER, write_json

import jaxpose as jp
from jaxpose.estimate import STATUS_TEXT, estimate_problem


def random_pair(key):
    k1, k2, k3 = jax.random.split(key, 3)
    R1 = jaxlie.SO3.sample_uniform(k1).as_matrix()
    axis = jax.random.normal(k2, (3,))
    angle = jnp.radians(jax.random.uniform(k3, minval=5.0, maxval=45.0))
    dR = jaxlie.SO3.exp(axis / jnp.linalg.norm(axis) * angle).as_matrix()
    return R1, dR @ R1, float(jnp.degrees(angle))


def main(pairs: int = 100, preset: str = "wide"):
    config = getattr(jp.Config, preset)(max_points=10240, max_cells=1024, grid_cells=160)
    camera, target = jp.Camera.camcube2(), jp.targets.n5()
    rows, t0 = [], time.perf_counter()
    for i in range(pairs):
        R1, R2, angle = random_pair(jax.random.key(i))
        prev, curr = jp.simulate(camera, target, R1, T_PAPER), jp.simulate(camera, target, R2, T_PAPER)
        try:
            problem = jp.Problem.build(prev, curr, config)
        except ValueError as err:
            rows.append({"pair": i, "angle_deg": angle, "error": str(err)})
            continue
        est = estimate_problem(problem, config, jax.random.key(10_000 + i))
        rot = float(np.degrees(jp.rotation_angle(est.rotation, R2 @ R1.T)))
        rows.append(
            {
                "pair": i,
                "angle_deg": angle,
                "rotation_error_deg": rot,
                "status": STATUS_TEXT[int(est.status)],
                "hard": float(est.hard),
                "accurate": rot < 1.0,
                "success": rot < 1.0 and bool(est.success),
                "false_success": rot >= 1.0 and bool(est.success),
            }
        )
        print(i, f"{angle:5.1f}°", f"err {rot:.3f}°", rows[-1]["status"], flush=True)
    done = [r for r in rows if "error" not in r]
    bins = {}
    for lo, hi in ((5, 15), (15, 25), (25, 35), (35, 45)):
        sel = [r for r in done if lo <= r["angle_deg"] < hi]
        bins[f"{lo}-{hi} deg"] = {"pairs": len(sel), "accurate": sum(r["accurate"] for r in sel)}
    summary = {
        "preset": preset,
        "pairs": pairs,
        "unusable_frame": len(rows) - len(done),
        "accurate": sum(r["accurate"] for r in done),
        "success": sum(r["success"] for r in done),
        "false_success": sum(r["false_success"] for r in done),
        "by_angle": bins,
        "seconds": time.perf_counter() - t0,
    }
    print(summary)
    write_json(f"capture_{preset}.json", {"summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
