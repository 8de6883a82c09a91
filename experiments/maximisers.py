"""How far the hard and soft objectives' maximisers sit from the truth on the paper's N5 pairs.

Soft: BFGS (optimistix) from the truth. Hard (piecewise constant): best of a 20 000-sample
random search within ±1°, ±1 cm of the truth. Same procedure as the test
`test_soft_maximiser_is_closer_to_truth_than_hard`, in float32.

    uv run python experiments/maximisers.py  →  results/maximisers.json
"""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from _common import T_PAPER, paper_cloud, paper_rotation, write_json

import jaxpose as jp
from jaxpose._batch import score_batch


def main(samples: int = 20000):
    scale = jnp.array([np.pi / 180] * 3 + [0.01] * 3)
    rows = []
    for variant in ("variant 1", "variant 2"):
        problem = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", variant))
        truth = jp.true_displacement(
            problem.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER
        )
        sol = optx.minimise(
            lambda y, pb: -jp.soft_score(y * scale, pb),
            optx.BFGS(rtol=1e-9, atol=1e-9),
            truth / scale,
            problem,
            max_steps=200,
            throw=False,
        )
        p_soft = sol.value * scale
        ps = truth + jax.random.uniform(jax.random.key(0), (samples, 6), minval=-1, maxval=1) * scale
        p_hard = ps[jnp.argmax(score_batch(ps, problem, "hard"))]

        def rot_err(p, truth=truth):
            return float(np.degrees(jp.rotation_angle(jp.rotation(*p[:3]), jp.rotation(*truth[:3]))))

        row = {
            "pair": f"N5 previous → {variant}",
            "soft_rotation_error_deg": rot_err(p_soft),
            "hard_rotation_error_deg": rot_err(p_hard),
            "soft_translation_error_cm": 100 * float(jnp.linalg.norm(p_soft[3:] - truth[3:])),
            "hard_translation_error_cm": 100 * float(jnp.linalg.norm(p_hard[3:] - truth[3:])),
        }
        rows.append(row)
        print(row)
    write_json("maximisers.json", {"rows": rows})


if __name__ == "__main__":
    main()
