"""How a warm public call's fine rounds match, and its voxel searches by query count.

For `neighbour_speed.py`'s 8 realistic pairs (N5, satellite, upper stage, debris; σ 0 and
1 cm), a debug callback counts each fine round by mode (`first`: a run's first round, voxel
search; `graph`: one step of graph descent, `GRAPH_SHIFT`; `approach` and `finish`: certified
matches, `CERTIFIED_BUFFER`) and each `_neighbours.candidates` call by its number of queries
(the selected current points for a whole search, a quarter of them for a gathered one), on
the second of two calls (the programs are released first so that the callbacks are traced).

    uv run python experiments/round_modes.py   (prints one line per pair)
"""

import collections

import jax
from neighbour_speed import NAMES

import jaxpose as jp
from jaxpose import _fine, _neighbours, _programs
from jaxpose.evaluation import realistic

rounds = collections.Counter()
sizes = collections.Counter()
orig_rm, orig_c = _fine._round_matches, _neighbours.candidates


def rm(fine, q, live, lasts, local, first, inlier):
    jax.debug.callback(
        lambda f, l, fin: rounds.update(["first" if f else "graph" if l else "finish" if fin else "approach"]),
        first,
        local,
        lasts[3],
    )
    return orig_rm(fine, q, live, lasts, local, first, inlier)


def c(grid, queries, *rest):
    n = queries.shape[1]
    jax.debug.callback(lambda: sizes.update([n]))
    return orig_c(grid, queries, *rest)


_fine._round_matches = rm
_neighbours.candidates = c
for case in realistic.make_cases(1, names=NAMES, levels=(0.0, 1.0)):
    key = jax.random.key(case.index)
    _programs.release_all()
    jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
    rounds.clear()
    sizes.clear()
    jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
    print(f"{case.label:20s} rounds {dict(rounds)}  searches by size {dict(sorted(sizes.items()))}", flush=True)
