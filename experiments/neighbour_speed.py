"""What the voxel neighbour search costs the public call, on realistic-benchmark pairs.

For N5, the satellite, the upper stage and the mesh debris at σ = 0 and 1 cm
(`make_cases(pairs)`), with the default config sized from each pair:

- `call_ms`: the warm public call `jp.estimate(prev, curr, key=...)`, median of `repeats`
  after a first (compiling) call;
- `searches`: how many voxel searches (`_neighbours.candidates` over the current points or
  the previous side) one call runs, counted by a debug callback in a separate call, and
  `gathered`: how many of them searched only the points a finish round could not certify
  (`_fine.CERTIFIED_BUFFER`: a quarter of the selected points, gathered);
- `nearest_ms`, `k_nearest_ms`: one `nearest` of the fine stage's current points at the
  search's best, and the build's `k_nearest` (`FineStage.neighbours` of every previous-side
  point), each jitted alone, median of `repeats`;
- the estimate itself (`params`, frame n; rotation and centroid errors; success), so that
  two commits' runs can be compared for identical results.

    uv run python experiments/neighbour_speed.py [pairs] [repeats] [label]
        → results/neighbour_speed[_label].json
"""

from __future__ import annotations

import collections
import sys

import equinox as eqx
import jax
import numpy as np
from _common import RESULTS, time_call, write_json

import jaxpose as jp
from jaxpose import _neighbours, _programs
from jaxpose._fine import NEIGHBOUR_SLOTS, _moved, select_current
from jaxpose._problem import _build, sized_config
from jaxpose._search import restarted_search
from jaxpose.evaluation import realistic

NAMES = ("n5", "satellite", "upper_stage", "debris")


def count_searches(case, key) -> tuple[int, int]:
    """Voxel searches in one public call, all of them and those of a gathered subset of the
    current points (fewer queries than the largest search): a debug callback in
    `_neighbours.candidates`, traced into the call's program (compiled anew: the programs are
    released before and after), counted on its second run, so that the timed call runs a
    program without the callback."""
    counts = collections.Counter()
    original = _neighbours.candidates

    def counted(grid, queries, *rest):
        size = queries.shape[1]
        jax.debug.callback(lambda: counts.update([size]))
        return original(grid, queries, *rest)

    _neighbours.candidates = counted
    _programs.release_all()  # a program of the same bucket, compiled without the callback
    try:
        jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
        counts.clear()
        jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
    finally:
        _neighbours.candidates = original
        _programs.release_all()
    largest = max(counts, default=0)
    return sum(counts.values()), sum(n for size, n in counts.items() if size < largest)


def row(case, repeats: int) -> dict:
    key = jax.random.key(case.index)
    searches, gathered = count_searches(case, key)
    call = lambda: jp.estimate(case.prev, case.curr, key=key)  # noqa: E731
    est = call()
    jax.block_until_ready(est.params)
    call_ms = 1e3 * time_call(lambda: call().params, repeats=repeats)["median_s"]
    config = sized_config(case.prev, case.curr, jp.Config())
    problem = eqx.filter_jit(_build)(case.prev, case.curr, config)
    best = eqx.filter_jit(restarted_search)(problem, config, key).params
    current, _ = select_current(problem, config, best)
    queries = _moved(best, current)
    grid, previous = problem.fine.grid, problem.fine.points
    nearest = jax.jit(lambda q: _neighbours.nearest(grid, q, NEIGHBOUR_SLOTS))
    k_nearest = jax.jit(lambda q: _neighbours.k_nearest(grid, q, config.fine.neighbours, NEIGHBOUR_SLOTS))
    err = realistic.errors(case, est.rotation, est.translation)
    return {
        "label": case.label,
        "call_ms": call_ms,
        "searches": searches,
        "gathered": gathered,
        "nearest_ms": 1e3 * time_call(lambda: nearest(queries), repeats=repeats)["median_s"],
        "k_nearest_ms": 1e3 * time_call(lambda: k_nearest(previous), repeats=repeats)["median_s"],
        "rotation_error_deg": err["rotation_error_deg"],
        "centroid_error_cm": err["centroid_error_cm"],
        "success": bool(est.success),
        "params": np.asarray(est.params).tolist(),
    }


def main(pairs: int = 1, repeats: int = 9, label: str = "") -> None:
    rows = []
    for case in realistic.make_cases(pairs, names=NAMES, levels=(0.0, 1.0)):
        rows.append(row(case, repeats))
        r = rows[-1]
        print(
            f"{r['label']:20s} call {r['call_ms']:6.1f} ms  searches {r['searches']:2d} ({r['gathered']} gathered)",
            f"nearest {r['nearest_ms']:5.2f} ms  k_nearest {r['k_nearest_ms']:5.2f} ms",
            f"rot {r['rotation_error_deg']:.4f}°  success {r['success']}",
            flush=True,
        )
    name = f"neighbour_speed_{label}.json" if label else "neighbour_speed.json"
    write_json(name, {"pairs": pairs, "repeats": repeats, "rows": rows})
    print("wrote", RESULTS / name)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(*(int(a) for a in args[:2]), *args[2:3])
