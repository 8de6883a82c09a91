"""estimate speed and accuracy on the paper's four pairs, accuracy on random views, and
vmapped-batch throughput, for the default config, `Config.fast()` and `full_search()` (the
full-pattern search with the near-plane fine stage, `experiments/_common.py`).

Median of repeated runs after compile, compile time separately; errors in frame n against
`true_displacement` (degrees, centimetres). Per pair two times: `ms` is
`estimate_problem` on a built `Problem` (the search, refine and fine stage), `end_to_end_ms`
is `Problem.build` and `estimate_problem` in one jitted call (what `jaxpose.estimate` costs
once compiled). The random views are `capture_pair(i, seed=1, 3°, 20°)`, i < 16: N5 at
5.5 m, random attitude, a 3–20° turn about a random axis, noise-free.

    uv run python experiments/bench_estimate.py [batch ...]  →  results/bench_estimate.json

Batch sizes default to 8. Each config runs at one fixed capacity (5120 points on the paper's
pairs, 8192 on the random views), so one program serves all its pairs. On an accelerator the
file is `bench_estimate_<backend>.json`
(e.g. `bench_estimate_gpu.json`), so a GPU run does not overwrite the CPU numbers.
"""

import sys

import jax
import jax.numpy as jnp
import numpy as np
from _common import T_PAPER, full_search, paper_cloud, paper_rotation, time_call, write_json

import jaxpose as jp
from jaxpose._estimate import STATUS_NAME, STATUS_TEXT, estimate_problem
from jaxpose.evaluation.comparison import outcome_counts
from jaxpose.sim import capture_pair

PRESETS = {"default": jp.Config, "fast": jp.Config.fast, "full_search": full_search}


def capacity(points: int) -> jp.Capacities:
    return jp.Capacities(max_points=points, max_prev_points=points)


DEG_CM = np.array([180 / np.pi] * 3 + [100] * 3)


def paper_rows(name: str, config: jp.Config, repeats: int) -> list[dict]:
    end_to_end = jax.jit(lambda prev, curr, key: estimate_problem(jp.Problem.build(prev, curr, config), config, key))
    rows = []
    for shape in ("n1", "n5"):
        prev = paper_cloud(shape, "previous")
        for variant in ("variant 1", "variant 2"):
            curr = paper_cloud(shape, variant)
            problem = jp.Problem.build(prev, curr, config)
            key = jax.random.key(0)
            res = time_call(estimate_problem, problem, config, key, repeats=repeats)
            whole = time_call(end_to_end, prev, curr, key, repeats=repeats)
            est = estimate_problem(problem, config, key)
            truth = jp.true_displacement(
                est.frame, paper_rotation("previous"), T_PAPER, paper_rotation(variant), T_PAPER
            )
            err = np.asarray(est.params - truth) * DEG_CM
            rows.append(
                {
                    "shape": shape,
                    "pair": variant,
                    **res,
                    "ms": res["median_s"] * 1e3,
                    "end_to_end_ms": whole["median_s"] * 1e3,
                    "end_to_end_compile_s": whole["compile_s"],
                    "status": STATUS_TEXT[int(est.status)],
                    "hard": float(est.hard),
                    "error_deg_cm": err.round(6).tolist(),
                    "local_steps": int(est.stats["refine_steps"]),
                    "fine_steps": int(est.stats["fine_steps"]),
                }
            )
            print(
                f"{name:8s} {shape} {variant}: {rows[-1]['ms']:.1f} ms, with build {rows[-1]['end_to_end_ms']:.1f} ms "
                f"(compile {res['compile_s']:.1f} s) err {np.round(err, 5)} {rows[-1]['status']}"
            )
    return rows


def random_views(name: str, config: jp.Config, count: int = 16) -> dict:
    """Accuracy and statuses of `config` on the random views."""
    run = jax.jit(lambda pb, key: estimate_problem(pb, config, key))
    rot, shift, success, status, refused = [], [], [], [], 0
    for i in range(count):
        pair = capture_pair(i, seed=1, low_deg=3.0, high_deg=20.0)
        try:
            problem = jp.Problem.build(pair.prev, pair.curr, config)
        except ValueError:  # a pattern larger than the grid: counted, not scored
            refused += 1
            continue
        est = run(problem, jax.random.key(0))
        truth = jp.true_displacement(est.frame, pair.R1, pair.t1, pair.R2, pair.t2)
        err = np.abs(np.asarray(est.params - truth)) * DEG_CM
        rot.append(float(err[:3].max()))
        shift.append(float(err[3:].max()))
        success.append(bool(est.success))
        status.append(STATUS_NAME[int(est.status)])
    rot, shift = np.array(rot), np.array(shift)
    counts = outcome_counts(rot < 1.0, success)
    out = {
        "pairs": count,
        "refused": refused,
        "found_lt_1deg": counts["found"],
        "reported_success": int(np.sum(success)),
        "false_success_ge_1deg": counts["false_success"],
        "rotation_error_deg": {"median": float(np.median(rot)), "max": float(rot.max())},
        "translation_error_cm": {"median": float(np.median(shift)), "p90": float(np.quantile(shift, 0.9))},
        "translation_error_cm_all": shift.round(4).tolist(),
        "status_all": status,
    }
    print(
        f"{name:8s} random views: found {out['found_lt_1deg']}/{count - refused}, success {out['reported_success']}, "
        f"rot median {np.median(rot):.4f}° max {rot.max():.3f}°, shift median {np.median(shift):.3f} cm "
        f"p90 {out['translation_error_cm']['p90']:.3f} cm"
    )
    return out


def main(repeats: int = 7, batches: tuple[int, ...] = (8,)):
    out = {}
    for name, preset in PRESETS.items():
        config = preset(capacities=capacity(5120))
        out[name] = {"pairs": paper_rows(name, config, repeats)}
        out[name]["random_views"] = random_views(name, preset(capacities=capacity(8192)))
        # Throughput of vmapped batches of pairs (one compile per batch size).
        prob = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", "variant 2"), config)
        fn = jax.jit(jax.vmap(lambda pb, k, c=config: estimate_problem(pb, c, k)))
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
