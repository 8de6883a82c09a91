"""Scoring throughput of the hard and soft objectives on the paper's N5 pair.

Poses scored per second for batch sizes 1 … 4096 (median of repeated runs after compile,
compile time separately), with `score_batch` (lax.map over chunks of 16) and, for
comparison, plain `jax.vmap`.

    uv run python experiments/bench_scoring.py  →  results/bench_scoring.json
"""

import jax
import jax.numpy as jnp
from _common import paper_cloud, time_call, write_json

import jaxpose as jp
from jaxpose._batch import score_batch


def main(batches=(1, 16, 256, 4096), repeats: int = 5):
    problem = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", "variant 2"))
    rows = []
    for objective in ("hard", "soft"):
        for mode in ("score_batch", "vmap"):
            if mode == "score_batch":
                fn = jax.jit(lambda ps, pb, o=objective: score_batch(ps, pb, o))
            else:
                fn = jax.jit(jax.vmap({"hard": jp.hard_score, "soft": jp.soft_score}[objective], (0, None)))
            for B in batches:
                if mode == "vmap" and B > 256:
                    continue  # slow and memory hungry; the trend is clear by 256
                ps = jax.random.uniform(jax.random.key(B), (B, 6), minval=-0.1, maxval=0.1)
                res = time_call(fn, ps, problem, repeats=repeats)
                row = {"objective": objective, "mode": mode, "batch": B, **res, "poses_per_s": B / res["median_s"]}
                rows.append(row)
                print(
                    f"{objective:4s} {mode:11s} B={B:5d} {row['poses_per_s']:10.0f} poses/s "
                    f"(compile {res['compile_s']:.2f} s)"
                )
    grad = jax.jit(jax.grad(jp.soft_score))
    res = time_call(grad, jnp.zeros(6), problem, repeats=repeats * 4)
    rows.append({"objective": "soft_grad", "mode": "single", "batch": 1, **res, "poses_per_s": 1 / res["median_s"]})
    print(f"soft grad single: {1 / res['median_s']:.0f} /s (compile {res['compile_s']:.2f} s)")
    write_json(
        "bench_scoring.json",
        {"pair": "N5 previous → variant 2", "max_points": int(problem.curr.shape[1]), "rows": rows},
    )


if __name__ == "__main__":
    main()
