"""What one round of the fine stage costs, by part, on realistic-benchmark pairs.

For the satellite and N5 at σ = 0 and 1 cm (`make_cases(1)`), default config sized from each
pair, at the global search's best (frame n), each part jitted alone, median of `repeats` warm
calls (milliseconds):

- `match_ms`: the voxel search of the selected current points with the matches' planes and
  robust weights (`_fine._correspond`, `_fine._robust_weights`);
- `solve_ms`, `solve_steps`: optimistix's Gauss–Newton on that round's fixed matches
  (`_fine.least_squares_solver`, `FineStage.steps`), as `fine_refine` runs it;
- `one_step_ms`: the same solver stopped after one step;
- `residuals_ms`: one evaluation of the round's residual function.

    uv run python experiments/round_costs.py [repeats] → results/round_costs.json
"""

from __future__ import annotations

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from _common import RESULTS, time_call, write_json

import jaxpose as jp
from jaxpose import _fine
from jaxpose._problem import _build, sized_config
from jaxpose._search import restarted_search
from jaxpose.evaluation import realistic


def round_row(case, repeats: int) -> dict:
    config = sized_config(case.prev, case.curr, jp.Config())
    problem = eqx.filter_jit(_build)(case.prev, case.curr, config)
    best = eqx.filter_jit(restarted_search)(problem, config, jax.random.key(case.index)).params
    inlier = jnp.asarray(config.fine.inlier, best.dtype)
    b, live = _fine.select_current(problem, config, best)
    scale = jnp.asarray(_fine.PARAMETER_SCALE, best.dtype)
    solver = _fine.least_squares_solver(config.fine.tol)

    @jax.jit
    def match(p):
        matched, weight, _ = _fine._correspond(p, b, live, problem.fine, inlier)
        r0 = _fine._residuals(p, b, matched, weight)
        return matched, weight, jnp.sqrt(_fine._robust_weights(r0, weight))

    def residuals(y, args):
        matched, weight, root_w = args
        p = y * scale
        plane = root_w * _fine._residuals(p, b, matched, weight)
        point = _fine.POINT_WEIGHT * root_w[None] * (_fine._moved(p, b) - matched.points)
        return plane / _fine.RESIDUAL_UNIT, point / _fine.RESIDUAL_UNIT

    def solver_run(steps):
        @jax.jit
        def run(y, args):
            sol = optx.least_squares(residuals, solver, y, args, max_steps=steps, throw=False)
            return sol.value, sol.stats["num_steps"]

        return run

    solve, one_step = solver_run(config.fine.steps), solver_run(1)
    y, args = best / scale, match(best)
    ms = lambda fn, *a: 1e3 * time_call(lambda: fn(*a), repeats=repeats)["median_s"]  # noqa: E731
    return {
        "label": case.label,
        "match_ms": ms(match, best),
        "solve_ms": ms(solve, y, args),
        "solve_steps": int(solve(y, args)[1]),
        "one_step_ms": ms(one_step, y, args),
        "residuals_ms": ms(jax.jit(residuals), y, args),
    }


def main(repeats: int = 15) -> None:
    rows = []
    for case in realistic.make_cases(1, names=("satellite", "n5"), levels=(0.0, 1.0)):
        rows.append(round_row(case, repeats))
        print(rows[-1], flush=True)
    write_json("round_costs.json", {"repeats": repeats, "rows": rows})
    print("wrote", RESULTS / "round_costs.json")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
