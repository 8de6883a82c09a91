"""estimate speed and accuracy on the paper's four pairs, and vmapped-batch throughput.

Median of repeated runs after compile, compile time separately; errors in frame n against
`true_displacement` (degrees, centimetres).

    uv run python experiments/bench_estimate.py [batch ...]  →  results/bench_estimate.json

Batch sizes default to 8. On an accelerator the file is `bench_estimate_<backend>.json`
(e.g. `bench_estimate_gpu.json`), so a GPU run does not overwrite the CPU numbers.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np
from _common import T_PAPER, paper_cloud, paper_rotation, time_call, write_json

import jaxpose as jp
from jaxpose.estimate import STATUS_TEXT, estimate_problem


def main(repeats: int = 5, batches: tuple[int, ...] = (8,)):
    out = {}
    for name in ("fast", "accurate"):
        config = getattr(jp.Config, name)(max_points=5120)
        rows = []
        for shape in ("n1", "n5"):
            prev = paper_cloud(shape, "previous")
            for variant in ("variant 1", "variant 2"):
                problem = jp.Problem.build(prev, paper_cloud(shape, variant), config)
                res = time_call(estimate_problem, problem, config, jax.random.key(0), repeats=repeats)
                est = estimate_problem(problem, config, jax.random.key(0))
                truth = jp.true_displacement(
                    est.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER
                )
                err = np.asarray(est.params - truth) * np.array([180 / np.pi] * 3 + [100] * 3)
                rows.append(
                    {
                        "shape": shape,
                        "pair": variant,
                        **res,
                        "ms": res["median_s"] * 1e3,
                        "status": STATUS_TEXT[int(est.status)],
                        "hard": float(est.hard),
                        "error_deg_cm": err.round(4).tolist(),
                        "local_steps": int(est.local_steps),
                    }
                )
                print(
                    f"{name:8s} {shape} {variant}: {rows[-1]['ms']:.0f} ms (compile {res['compile_s']:.1f} s) "
                    f"err {np.round(err, 3)} {rows[-1]['status']}"
                )
        # Throughput of vmapped batches of pairs (one compile per batch size).
        prob = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", "variant 2"), config)
        fn = jax.jit(jax.vmap(lambda pb, k, c=config: estimate_problem(pb, c, k)))
        out[name] = {"pairs": rows}
        for batch in batches:
            probs = jax.tree.map(lambda x, b=batch: jnp.broadcast_to(x, (b, *jnp.shape(x))), prob)
            keys = jax.random.split(jax.random.key(1), batch)
            resb = time_call(fn, probs, keys, repeats=max(2, repeats // 2))
            print(
                f"{name:8s} vmap batch {batch}: {batch / resb['median_s']:.1f} pairs/s "
                f"(compile {resb['compile_s']:.1f} s)"
            )
            out[name][f"vmap_{batch}"] = {**resb, "pairs_per_s": batch / resb["median_s"]}
    backend = jax.default_backend()
    write_json("bench_estimate.json" if backend == "cpu" else f"bench_estimate_{backend}.json", out)


if __name__ == "__main__":
    main(batches=tuple(int(b) for b in sys.argv[1:]) or (8,))
