"""How far apart the default fine stage's two fits end: from the search's best and from rest.

`uv run python experiments/fine_starts_apart.py [pairs]` → `results/fine_starts_apart.json`

For each pair of `jaxpose.evaluation.realistic.make_cases(pairs)` (every target and noise
level of the realistic benchmark, seed 0), the default config sized from the pair, the global
search with the pair's index as key, then `fine_refine` from the search's best and from rest
(p = 0), each jitted apart. Per pair: the two fits' Gauss–Newton steps over all rounds, the
rotation angle between their results (degrees) and the largest difference of their
translation parameters (cm, frame n), and whether they ended in the same place (within
`SAME_DEG` and `SAME_CM`). The steps of the fit from rest on those pairs bound what stopping
it on reaching the first fit's minimum could save (issue 22), and the spread on the others
shows how far apart the fine stage's stop leaves two starts under range noise (issue 21).
"""

from __future__ import annotations

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import machine, write_json

import jaxpose as jp
from jaxpose._estimate import rotation_between
from jaxpose._fine import fine_refine
from jaxpose._problem import _build, sized_config
from jaxpose._search import restarted_search
from jaxpose.evaluation import realistic

SAME_DEG = 0.01
SAME_CM = 0.05

build = eqx.filter_jit(_build)
search = eqx.filter_jit(restarted_search)
fine = eqx.filter_jit(fine_refine)


def pair_row(case) -> dict:
    """The two fits of one pair (see the module docstring)."""
    config = sized_config(case.prev, case.curr, jp.Config())
    problem = build(case.prev, case.curr, config)
    glob = search(problem, config, jax.random.key(case.index))
    first = fine(problem, config, glob.params)
    rest = fine(problem, config, jnp.zeros(6, glob.params.dtype))
    angle = float(np.degrees(rotation_between(first.params, rest.params)))
    shift = 100 * float(np.max(np.abs(np.asarray(first.params[3:] - rest.params[3:]))))
    return {
        "pair": case.label,
        "sigma_cm": case.sigma_cm,
        "first_steps": int(first.steps),
        "rest_steps": int(rest.steps),
        "apart_deg": angle,
        "apart_cm": shift,
        "same": bool(angle < SAME_DEG and shift < SAME_CM),
    }


def main(pairs: int = 1) -> None:
    rows = []
    for case in realistic.make_cases(pairs):
        rows.append(pair_row(case))
        print(rows[-1], flush=True)
    same = [r for r in rows if r["same"]]
    steps = sum(r["first_steps"] + r["rest_steps"] for r in rows)
    summary = {
        "pairs": len(rows),
        "same": len(same),
        "fine_steps": steps,
        "rest_steps_where_same": sum(r["rest_steps"] for r in same),
        "apart_deg_median_where_not_same": float(np.median([r["apart_deg"] for r in rows if not r["same"]] or [0.0])),
    }
    print(summary)
    write_json("fine_starts_apart.json", {"machine": machine(), "summary": summary, "rows": rows})


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
