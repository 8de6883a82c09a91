"""Whether a bisection on the k-th distance beats `lax.top_k` in the build's k-nearest search.

`_neighbours.k_nearest` reads the 144 voxel candidates of each previous-side point
(`candidates`) and keeps the `FineStage.neighbours` nearest with `lax.top_k`. The variant
here finds each row's k-th smallest squared distance exactly, by bisection on its float bit
pattern (as `_fine.median_magnitude` does for the residuals' median), and then gathers the
candidates at or below it (ties cut by column order) with one scatter into k slots. Per pair
(N5, the satellite, the upper stage and the mesh debris at σ = 0 and 1 cm, the default
config sized from the pair), each jitted alone on the problem's own previous side, median of
`repeats` warm calls:

- `candidates_ms`: the candidates alone (their squared distances);
- `top_k_ms`: `k_nearest` as the package runs it (candidates, then `lax.top_k`);
- `kth_ms`: the candidates, then the bisection for the k-th distance alone;
- `bisect_ms`: the candidates, the bisection and the gather: a drop-in `k_nearest`
  (its neighbours in column order, not nearest first);
- `same_sets`: whether the bisection's neighbours are `top_k`'s, as sets, on every row.

    uv run python experiments/knn_select.py [pairs] [repeats] → results/knn_select.json
"""

from __future__ import annotations

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, machine, time_call, write_json

import jaxpose as jp
from jaxpose import _neighbours
from jaxpose._fine import NEIGHBOUR_SLOTS
from jaxpose._problem import _build, sized_config
from jaxpose.evaluation import realistic

NAMES = ("n5", "satellite", "upper_stage", "debris")


def kth_smallest(d2, k: int):
    """The k-th smallest entry of each row of the non-negative (S, C) `d2` (inf allowed),
    exactly: bisection on the bit patterns, one count per bit."""
    itype = jnp.int64 if d2.dtype.itemsize == 8 else jnp.int32
    bits = jax.lax.bitcast_convert_type(d2, itype).T  # (C, S): the counts vectorise along S

    def halve(_, bounds):
        lo, hi = bounds  # fewer than k entries at or below lo; at least k at or below hi
        mid = lo + (hi - lo) // 2
        enough = jnp.sum((bits <= mid[None]).astype(jnp.int32), axis=0) >= k
        return jnp.where(enough, lo, mid), jnp.where(enough, mid, hi)

    start = (jnp.full(d2.shape[0], -1, itype), jnp.max(bits, axis=0))
    _, found = jax.lax.fori_loop(0, 8 * d2.dtype.itemsize, halve, start)
    return jax.lax.bitcast_convert_type(found, d2.dtype)


def bisect_select(d2, k: int):
    """Column indices (S, k) of each row's k smallest entries, in column order, and those entries."""
    kth = kth_smallest(d2, k)[:, None]
    less, ties = d2 < kth, d2 == kth
    room = k - jnp.sum(less, axis=1, keepdims=True)
    keep = less | (ties & (jnp.cumsum(ties.astype(jnp.int32), axis=1) <= room))
    slot = jnp.where(keep, jnp.cumsum(keep.astype(jnp.int32), axis=1) - 1, k)
    S, C = d2.shape
    columns = jnp.broadcast_to(jnp.arange(C, dtype=jnp.int32), (S, C))
    pos = jnp.zeros((S, k + 1), jnp.int32).at[jnp.arange(S)[:, None], slot].set(columns, mode="drop")[:, :k]
    return pos, jnp.take_along_axis(d2, pos, 1)


def row(case, repeats: int) -> dict:
    config = sized_config(case.prev, case.curr, jp.Config())
    problem = eqx.filter_jit(_build)(case.prev, case.curr, config)
    grid, previous, k = problem.fine.grid, problem.fine.points, config.fine.neighbours

    def distances(q):
        return _neighbours.candidates(grid, q, NEIGHBOUR_SLOTS).distance2

    def by_bisection(q):
        cand = _neighbours.candidates(grid, q, NEIGHBOUR_SLOTS)
        pos, d2 = bisect_select(cand.distance2, k)
        return grid.order[jnp.take_along_axis(cand.sorted_index, pos, 1)], d2

    variants = {
        "candidates_ms": jax.jit(distances),
        "top_k_ms": jax.jit(lambda q: _neighbours.k_nearest(grid, q, k, NEIGHBOUR_SLOTS)),
        "kth_ms": jax.jit(lambda q: kth_smallest(distances(q), k)),
        "bisect_ms": jax.jit(by_bisection),
    }
    out = {"label": case.label, "previous_points": int(previous.shape[1]), "k": k}
    for name, f in variants.items():
        jax.block_until_ready(f(previous))
        out[name] = 1e3 * time_call(lambda f=f: f(previous), repeats=repeats)["median_s"]
    (ia, da), (ib, db) = variants["top_k_ms"](previous), variants["bisect_ms"](previous)
    same = np.array_equal(np.sort(np.asarray(da), 1), np.sort(np.asarray(db), 1))
    finite = np.isfinite(np.asarray(da))
    sa = np.sort(np.where(finite, np.asarray(ia), -1), 1)
    sb = np.sort(np.where(np.isfinite(np.asarray(db)), np.asarray(ib), -1), 1)
    out["same_sets"] = bool(same and np.array_equal(sa, sb))
    return out


def main(pairs: int = 1, repeats: int = 15) -> None:
    rows = []
    for case in realistic.make_cases(pairs, names=NAMES, levels=(0.0, 1.0)):
        rows.append(row(case, repeats))
        r = rows[-1]
        print(
            f"{r['label']:20s} candidates {r['candidates_ms']:5.2f}  top_k {r['top_k_ms']:5.2f}",
            f"kth {r['kth_ms']:5.2f}  bisect {r['bisect_ms']:5.2f} ms  same sets {r['same_sets']}",
            flush=True,
        )
    write_json("knn_select.json", {"machine": machine(), "pairs": pairs, "repeats": repeats, "rows": rows})
    print("wrote", RESULTS / "knn_select.json")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
