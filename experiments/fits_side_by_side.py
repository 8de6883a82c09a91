"""The fine stage's first two fits one after another against side by side under `jax.vmap`.

The default call runs its fits one after another (`_estimate.fine_passes`, a `lax.scan`).
On a CPU whose time per call is mostly the number of kernels run, two fits batched under
`jax.vmap` might cost little more than one. For N5, the satellite, the upper stage and
Chibis-M at σ = 0 and 1 cm (`make_cases(1)`), with the default config sized from each pair,
at the global search's best (frame n), this times (median of 7 warm calls, milliseconds):

- `one`, `rest`: `fine_refine` from the search's best and from rest, each alone;
- `sequential`: both in one jitted program, one after the other;
- `vmapped`: both as one `jax.vmap` over the two starts;
- `call`: the whole compiled build-and-estimate program;

with each fit's Gauss–Newton steps (all rounds), alone and vmapped.

    uv run python experiments/fits_side_by_side.py → results/fits_side_by_side.{json,md}
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import RESULTS, time_call, write_json

import jaxpose as jp
from jaxpose._estimate import _estimate_pair
from jaxpose._fine import fine_refine
from jaxpose._problem import _build, sized_config
from jaxpose._search import restarted_search
from jaxpose.evaluation import realistic

TARGETS = ("n5", "satellite", "upper_stage", "chibis_m")
LEVELS = (0.0, 1.0)
REPEATS = 7

build = eqx.filter_jit(_build)
search = eqx.filter_jit(restarted_search)
fine = eqx.filter_jit(fine_refine)


@eqx.filter_jit
def sequential(problem, config, starts):
    """The two fits one after the other in one program."""
    return fine_refine(problem, config, starts[0]), fine_refine(problem, config, starts[1])


@eqx.filter_jit
def vmapped(problem, config, starts):
    """The two fits as one batch."""
    return jax.vmap(lambda start: fine_refine(problem, config, start))(starts)


def median_ms(fn) -> float:
    return 1e3 * time_call(fn, repeats=REPEATS)["median_s"]


def row(case) -> dict:
    config = sized_config(case.prev, case.curr, jp.Config())
    key = jax.random.key(case.index)
    problem = build(case.prev, case.curr, config)
    start = search(problem, config, key).params
    rest = jnp.zeros(6, start.dtype)
    starts = jnp.stack([start, rest])
    batch = vmapped(problem, config, starts)
    return {
        "label": case.label,
        "steps": [int(fine(problem, config, start).steps), int(fine(problem, config, rest).steps)],
        "steps_vmapped": [int(s) for s in batch.steps],
        "one_ms": median_ms(lambda: fine(problem, config, start)),
        "rest_ms": median_ms(lambda: fine(problem, config, rest)),
        "sequential_ms": median_ms(lambda: sequential(problem, config, starts)),
        "vmapped_ms": median_ms(lambda: vmapped(problem, config, starts)),
        "call_ms": median_ms(lambda: _estimate_pair(case.prev, case.curr, config, key)),
    }


def markdown(rows: list[dict]) -> str:
    lines = [
        "| pair | steps (best / rest) | one ms | rest ms | sequential ms | vmapped ms | call ms |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = " | ".join(f"{r[k]:.1f}" for k in ("one_ms", "rest_ms", "sequential_ms", "vmapped_ms", "call_ms"))
        lines.append(f"| {r['label']} | {r['steps'][0]} / {r['steps'][1]} | {cells} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    rows = []
    for case in realistic.make_cases(1, names=TARGETS, levels=LEVELS):
        rows.append(row(case))
        print(rows[-1], flush=True)
    write_json("fits_side_by_side.json", {"repeats": REPEATS, "rows": rows})
    (RESULTS / "fits_side_by_side.md").write_text(markdown(rows))
    print(markdown(rows))


if __name__ == "__main__":
    main()
