"""Where the soft objective's time goes, by ablation on the paper's N5 pair (4096 poses,
score_batch-style lax.map over chunks of 16). Each variant drops one stage of soft_score.

    uv run python experiments/profile_soft.py  →  results/profile_soft.json
"""

import jax
import jax.numpy as jnp
from _common import paper_cloud, time_call, write_json

import jaxpose as jp
from jaxpose import _objective as obj


def soft_parts(p, problem, scatter=True, gather=True):
    q = obj.to_moved_frame(p, problem)
    w_sel = problem.select_width * problem.d
    total = 0.0
    flats, weights = [], []
    for i in range(problem.num_planes):
        h, a, b = problem.plane_coords(q, i)
        sel = jnp.where(problem.curr_valid, obj._smoothstep((problem.d - jnp.abs(h)) / w_sel + 0.5), 0.0)
        a0, b0 = jnp.floor(a), jnp.floor(b)
        fa, fb = a - a0, b - b0
        a0, b0 = a0.astype(jnp.int32), b0.astype(jnp.int32)
        for da in (0, 1):
            for db in (0, 1):
                w = sel * obj._cell_kernel(fa - da, problem.bin_width) * obj._cell_kernel(fb - db, problem.bin_width)
                flat = problem.flat_index(i, a0 + da, b0 + db, problem.in_grid(i, a0 + da, b0 + db))
                total = total + (jnp.sum(w * problem.rm_field[flat]) if gather else jnp.sum(w * flat))
                flats.append(flat)
                weights.append(w)
    if scatter:
        counts = jnp.zeros_like(problem.r_field).at[jnp.concatenate(flats)].add(jnp.concatenate(weights))
        total = total + jnp.sum(obj._forward(obj._smoothstep(counts), problem))
    return total


def main(B: int = 4096):
    problem = jp.Problem.build(paper_cloud("n5", "previous"), paper_cloud("n5", "variant 2"))
    ps = jax.random.uniform(jax.random.key(0), (B, 6), minval=-0.1, maxval=0.1)
    variants = {
        "full soft_score": lambda p: obj.soft_score(p, problem),
        "kernels + backward gathers, no scatter": lambda p: soft_parts(p, problem, scatter=False),
        "kernels only (no gathers, no scatter)": lambda p: soft_parts(p, problem, scatter=False, gather=False),
        "transform only": lambda p: sum(jnp.sum(c) for c in obj.to_moved_frame(p, problem)),
    }
    rows = {}
    for name, f in variants.items():
        fn = jax.jit(lambda ps, f=f: jax.lax.map(f, ps, batch_size=16))
        res = time_call(fn, ps, repeats=3)
        rows[name] = {**res, "us_per_pose": res["median_s"] / B * 1e6}
        print(f"{name:42s} {rows[name]['us_per_pose']:7.1f} µs/pose")
    write_json("profile_soft.json", {"batch": B, "points": int(problem.curr.shape[1]), "rows": rows})


if __name__ == "__main__":
    main()
