"""Where the public call's time goes: each stage jitted apart, on realistic-benchmark pairs.

For N5, the satellite and the upper stage at σ = 0 and 1 cm (`make_cases(pairs)`), with the
default config sized from each pair (`sized_config`), the median of `repeats` warm calls of:

- `build`: `Problem.build`'s compiled body; `build_no_fine`: the same without the fine
  stage's previous side (its voxel grid, k-nearest neighbours and normals);
- `knn`: the k-nearest-neighbour search of the fine stage's normals alone (20 of the 144
  voxel candidates of each of the previous side's points);
- `nearest`: one round's matching, the nearest previous point of each current point;
- `search`: the global search; `refine`, `refine_all`: the refine on `Refine.points` and on
  every current point, where the config has a refine (the default has none: then the columns
  are left out and the fine stage starts at the search's best);
- `fine`, `fine_rest`: the fine stage from the refine's result (or the search's best) and
  from rest, with their Gauss–Newton steps (all rounds);
- `call`: the whole compiled build-and-estimate program.

    uv run python experiments/stage_times.py [pairs] [repeats] → results/stage_times.{json,md}
"""

from __future__ import annotations

import dataclasses
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import RESULTS, time_call, write_json

import jaxpose as jp
from jaxpose._estimate import _estimate_pair
from jaxpose._fine import NEIGHBOUR_SLOTS, _moved, fine_refine, select_current
from jaxpose._neighbours import k_nearest, nearest
from jaxpose._problem import _build, sized_config
from jaxpose._search import local_refine, restarted_search
from jaxpose.evaluation import realistic

COLUMNS = ("call", "build", "build_no_fine", "knn", "nearest", "search", "refine", "refine_all", "fine", "fine_rest")


def median_ms(fn, repeats: int) -> float:
    """The median of `repeats` warm calls of `fn`, milliseconds (`time_call`)."""
    return 1e3 * time_call(fn, repeats=repeats)["median_s"]


build = eqx.filter_jit(_build)
search = eqx.filter_jit(restarted_search)
refine = eqx.filter_jit(local_refine)
fine = eqx.filter_jit(fine_refine)
knn = eqx.filter_jit(lambda f, k: k_nearest(f.grid, f.points, k, NEIGHBOUR_SLOTS))
match = eqx.filter_jit(lambda f, b: nearest(f.grid, b, NEIGHBOUR_SLOTS))


def stage_row(case, repeats: int) -> dict:
    config = sized_config(case.prev, case.curr, jp.Config())
    key = jax.random.key(case.index)
    problem = build(case.prev, case.curr, config)
    glob = search(problem, config, key)
    # The default config has no refine (`Config.refine` None): the fine stage starts at the search's best.
    has_refine = config.refine is not None
    start = refine(problem, config, glob.params).params if has_refine else glob.params
    current, _ = select_current(problem, config, start)
    current = _moved(start, current)
    no_fine = dataclasses.replace(config, fine=None)
    times = {
        "call": median_ms(lambda: _estimate_pair(case.prev, case.curr, config, key), repeats),
        "build": median_ms(lambda: build(case.prev, case.curr, config), repeats),
        "build_no_fine": median_ms(lambda: build(case.prev, case.curr, no_fine), repeats),
        "knn": median_ms(lambda: knn(problem.fine, config.fine.neighbours), repeats),
        "nearest": median_ms(lambda: match(problem.fine, current), repeats),
        "search": median_ms(lambda: search(problem, config, key), repeats),
        "fine": median_ms(lambda: fine(problem, config, start), repeats),
        "fine_rest": median_ms(lambda: fine(problem, config, jnp.zeros(6)), repeats),
    }
    steps = {
        "fine_steps": int(fine(problem, config, start).steps),
        "fine_rest_steps": int(fine(problem, config, jnp.zeros(6)).steps),
    }
    if has_refine:
        all_points = dataclasses.replace(config, refine=dataclasses.replace(config.refine, points=None))
        times["refine"] = median_ms(lambda: refine(problem, config, glob.params), repeats)
        times["refine_all"] = median_ms(lambda: refine(problem, all_points, glob.params), repeats)
    return {
        "label": case.label,
        "current_points": int(case.curr.num_valid),
        "capacities": dataclasses.asdict(config.capacities),
        **times,
        **steps,
    }


def markdown(rows: list[dict]) -> str:
    head = "| pair | current points | " + " | ".join(f"{c} ms" for c in COLUMNS) + " | fine steps (refine / rest) |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 3)]
    for r in rows:
        cells = " | ".join(f"{r[c]:.1f}" if c in r else "–" for c in COLUMNS)
        lines.append(f"| {r['label']} | {r['current_points']} | {cells} | {r['fine_steps']} / {r['fine_rest_steps']} |")
    return "\n".join(lines) + "\n"


def main(pairs: int = 2, repeats: int = 5) -> None:
    rows = []
    for case in realistic.make_cases(pairs, names=("n5", "satellite", "upper_stage"), levels=(0.0, 1.0)):
        rows.append(stage_row(case, repeats))
        print(rows[-1], flush=True)
    table = markdown(rows)
    print(table)
    write_json("stage_times.json", {"pairs": pairs, "repeats": repeats, "rows": rows})
    (RESULTS / "stage_times.md").write_text(table)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
