"""Where the soft objective's maximiser sits when the current cloud is (a) the previous
cloud's own points moved rigidly by the true motion, and (b) a fresh simulation of the moved
target (new pixel rays: what a camera sees). BFGS (optimistix) from the truth in float64;
distances from the truth in frame n (degrees, cm). (a) isolates the objective's geometry,
(b) adds resampling: the gap between the two is the resampling bias.

    uv run python experiments/resampling_bias.py  →  results/resampling_bias.json
"""

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from _common import T_PAPER, paper_cloud, paper_rotation, write_json  # noqa: E402

import jaxpose as jp  # noqa: E402

SCALE = jnp.array([np.pi / 180] * 3 + [0.01] * 3)


def maximiser_offset(prev, curr, truth_fn):
    problem = jp.Problem.build(prev, curr, jp.Config.thorough(max_points=5120))
    truth = truth_fn(problem.frame)
    sol = optx.minimise(
        lambda y, pb: -jp.soft_score(y * SCALE, pb),
        optx.BFGS(rtol=1e-9, atol=1e-9),
        truth / SCALE + 0.3,  # start 0.3° / 0.3 cm off, so the optimiser has to move
        problem,
        max_steps=300,
        throw=False,
    )
    return np.asarray(sol.value - truth / SCALE)


def main():
    rows = []
    for shape in ("n1", "n5"):
        prev = paper_cloud(shape, "previous")
        for variant in ("variant 1", "variant 2"):
            R1, R2 = paper_rotation("previous"), paper_rotation(variant)
            R = R2 @ R1.T
            t = T_PAPER - R @ T_PAPER
            rigid = jp.Cloud(jnp.where(prev.valid[:, None], prev.points @ R.T + t, 0.0), prev.valid)

            def truth_fn(frame, R1=R1, R2=R2):
                return jp.true_displacement(frame, R1, T_PAPER, R2, T_PAPER)

            a = maximiser_offset(prev, rigid, truth_fn)
            b = maximiser_offset(prev, paper_cloud(shape, variant), truth_fn)
            row = {
                "pair": f"{shape} {variant}",
                "rigid_copy_offset_deg_cm": a.round(6).tolist(),
                "resimulated_offset_deg_cm": b.round(4).tolist(),
                "rigid_max_deg": float(np.max(np.abs(a[:3]))),
                "resimulated_max_deg": float(np.max(np.abs(b[:3]))),
                "rigid_max_cm": float(np.max(np.abs(a[3:]))),
                "resimulated_max_cm": float(np.max(np.abs(b[3:]))),
            }
            rows.append(row)
            print(row)
    write_json("resampling_bias.json", {"objective": "soft (thorough config)", "rows": rows})


if __name__ == "__main__":
    main()
