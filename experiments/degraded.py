"""Success rate and error of `estimate` on degraded data (issue 6): 5 % outliers, 20 %
dropout, 1 cm range noise, and a view that cuts part of the target off.

The paper's N5 pairs (previous → variant 1 and → variant 2) at 5.5 m, `trials` keys each,
default config. Outliers replace 5 % of the valid points of *both* clouds with points drawn
uniformly in a 1 m cube around the target. The truncated view shifts the target 2.0 m
sideways, to the edge of the 40° field of view at 5.5 m, so part of it leaves the view (the
share of points kept is reported). Success =
status SUCCESS and rotation error < 1°; the table also gives the share with rotation error
< 1° whatever the status. Errors in frame n (degrees, cm).

    uv run python experiments/degraded.py  →  results/degraded.json, results/degraded.md
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, T_PAPER, paper_rotation, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_TEXT, estimate_problem

CONDITIONS = {
    "clean": {},
    "5 % outliers": {"outliers": 0.05},
    "20 % dropout": {"dropout": 0.2},
    "1 cm range noise": {"noise": 0.01},
    "truncated view": {"shift": 2.0},
}


def target_position(condition: dict):
    """Camera-frame position of the target (metres): the paper's, shifted sideways for the
    truncated view."""
    return T_PAPER + jnp.array([condition.get("shift", 0.0), 0.0, 0.0])


def degraded_cloud(rotation, condition: dict, key) -> jp.Cloud:
    k_sim, k_pick, k_out = jax.random.split(key, 3)
    camera = dataclasses.replace(
        jp.Camera.camcube2(), noise_sigma=condition.get("noise", 0.0), dropout=condition.get("dropout", 0.0)
    )
    t = target_position(condition)
    cloud = jp.simulate(camera, jp.targets.n5(), rotation, t, key=k_sim)
    fraction = condition.get("outliers", 0.0)
    if fraction:
        swap = cloud.valid & (jax.random.uniform(k_pick, cloud.valid.shape) < fraction)
        junk = t + jax.random.uniform(k_out, cloud.points.shape, minval=-0.5, maxval=0.5)
        cloud = jp.Cloud(jnp.where(swap[:, None], junk, cloud.points), cloud.valid)
    return cloud


def main(trials: int = 10):
    config = jp.Config(capacities=jp.Capacities(max_points=5120))
    header = "| condition | success | rot. error < 1° | median rot. error ° | median transl. error cm | statuses |"
    rows, table = [], [header, "|---|---|---|---|---|---|"]
    for name, condition in CONDITIONS.items():
        rot_err, trans_err, ok, statuses = [], [], [], {}
        for variant in ("variant 1", "variant 2"):
            R1, R2 = paper_rotation("previous"), paper_rotation(variant)
            for trial in range(trials):
                k1, k2, k3 = jax.random.split(jax.random.key(1000 * trial + len(variant)), 3)
                prev, curr = degraded_cloud(R1, condition, k1), degraded_cloud(R2, condition, k2)
                try:
                    problem = jp.Problem.build(prev, curr, config)
                except ValueError as err:
                    statuses["ValueError"] = statuses.get("ValueError", 0) + 1
                    print(name, variant, trial, "ValueError:", err)
                    ok.append(False)
                    continue
                est = estimate_problem(problem, config, k3)
                t = target_position(condition)
                truth = jp.true_displacement(est.frame, R1, t, R2, t)
                rot = float(np.degrees(jp.rotation_angle(jp.rotation(*est.params[:3]), jp.rotation(*truth[:3]))))
                rot_err.append(rot)
                trans_err.append(100 * float(jnp.linalg.norm(est.params[3:] - truth[3:])))
                status = STATUS_TEXT[int(est.status)]
                statuses[status] = statuses.get(status, 0) + 1
                ok.append(bool(est.success) and rot < 1.0)
        row = {
            "condition": name,
            "pairs": len(ok),
            "success_rate": float(np.mean(ok)),
            "accurate_rate": float(np.mean(np.array(rot_err) < 1.0)) if rot_err else 0.0,
            "median_rotation_error_deg": float(np.median(rot_err)) if rot_err else None,
            "median_translation_error_cm": float(np.median(trans_err)) if trans_err else None,
            "max_rotation_error_deg": float(np.max(rot_err)) if rot_err else None,
            "statuses": statuses,
        }
        rows.append(row)
        table.append(
            f"| {name} | {100 * row['success_rate']:.0f} % of {len(ok)} | {100 * row['accurate_rate']:.0f} % "
            f"| {row['median_rotation_error_deg']:.3f} "
            f"| {row['median_translation_error_cm']:.3f} | {', '.join(f'{k}: {v}' for k, v in statuses.items())} |"
        )
        print(table[-1])
    full = int(degraded_cloud(paper_rotation("previous"), {}, jax.random.key(0)).num_valid)
    cut = int(degraded_cloud(paper_rotation("previous"), CONDITIONS["truncated view"], jax.random.key(0)).num_valid)
    print(f"truncated view keeps {cut} of {full} points of the previous frame")
    payload = {"config": "default", "trials_per_pair": trials, "truncated_view_points": [cut, full], "rows": rows}
    write_json("degraded.json", payload)
    (RESULTS / "degraded.md").write_text("\n".join(table) + "\n")


if __name__ == "__main__":
    main()
