"""Time of each stage of `estimate` on realistic pairs (build, global search, refine, fine
stage from the refine's result and from rest), each stage jitted on its own, median of
`repeats` calls after a first (compile) call, milliseconds.

    uv run python experiments/stage_times.py [repeats]  → results/stage_times.json
"""

from __future__ import annotations

import statistics
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import write_json

import jaxpose as jp
from jaxpose._fine import fine_refine
from jaxpose._problem import _build, sized_config
from jaxpose._search import local_refine, restarted_search
from jaxpose.evaluation import realistic


def timed(fn, *args, repeats: int):
    out = jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return out, 1e3 * statistics.median(times)


def main(repeats: int = 5) -> None:
    build, search = eqx.filter_jit(_build), eqx.filter_jit(restarted_search)
    refine, fine = eqx.filter_jit(local_refine), eqx.filter_jit(fine_refine)
    rows = []
    for case in realistic.make_cases(1, names=("n5", "satellite", "upper_stage"), levels=(0.0, 1.0)):
        config = sized_config(case.prev, case.curr, jp.Config())
        problem, build_ms = timed(build, case.prev, case.curr, config, repeats=repeats)
        glob, global_ms = timed(search, problem, config, jax.random.key(0), repeats=repeats)
        loc, refine_ms = timed(refine, problem, config, glob.params, repeats=repeats)
        _, fine_ms = timed(fine, problem, config, loc.params, repeats=repeats)
        _, rest_ms = timed(fine, problem, config, jnp.zeros(6), repeats=repeats)
        row = {"pair": case.label, "build": build_ms, "global": global_ms, "refine": refine_ms}
        rows.append(row | {"fine_from_refine": fine_ms, "fine_from_rest": rest_ms})
        print({k: (round(v, 1) if isinstance(v, float) else v) for k, v in rows[-1].items()}, flush=True)
    write_json("stage_times.json", {"repeats": repeats, "rows": rows})


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
