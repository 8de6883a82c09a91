"""What the public program's compile time is made of, and three ways to shorten it that were
measured and not taken.

On one realistic-benchmark pair (N5, σ = 1 cm, `make_cases(1)`), default config sized from it,
each row compiles the whole public program (`_build_and_estimate`) in a fresh process (so that
nothing is cached) and reports the seconds of tracing and lowering, of compiling, and the
median of 9 warm runs:

- **copies**: the program as it is, and with the soft objective, the hard objective, or both
  replaced by a stub (a program that gives wrong answers, timed only to see what the
  objectives' traced copies cost to compile; the default program traces the soft objective
  twice, the search's batch and one batched evaluation of the estimate and the search's best,
  and the hard one once, a batched evaluation of the fine stage's result and its start);
- **all planes at once**: the objectives written over every cutting plane at once (`(P, M)`
  arrays, one gather and one scatter) instead of one traced block per plane, in the program;
- **XLA options**: `xla_cpu_use_fusion_emitters=false`, `xla_cpu_use_thunk_runtime=false`,
  `xla_backend_optimization_level=1`.

Then, in this process, the two formulations of the objectives side by side on the pair's
problem and on its coarse problem: one call, a batch of 1024 poses scored as the search scores
them (`lax.map` over chunks of 16) and one gradient, median milliseconds. The all-planes hard
objective gives the same values bit for bit; the soft one differs by rounding (≤ 1e-7).

    uv run python experiments/compile_costs.py → results/compile_costs.{json,md}
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import RESULTS, time_call, write_json

import jaxpose as jp
from jaxpose import _batch, _estimate, _objective, _search
from jaxpose._problem import round_half_up, sized_config
from jaxpose.evaluation import realistic

CORNERS = ((0, 0), (0, 1), (1, 0), (1, 1))


def plane_coords(problem, q):
    """h, a, b of every plane: `(P, M)` arrays (row i: plane i)."""
    axes = [j for j, _ in problem.planes]
    offsets = jnp.asarray([offset for _, offset in problem.planes], problem.d.dtype)[:, None]

    def pick(shift):
        return jnp.stack([q[(j + shift) % 3] for j in axes])

    h = pick(0) - offsets * problem.d
    a = (pick(1) - problem.lo[:, 0, None]) / problem.d + problem.ext[:, 0, None]
    b = (pick(2) - problem.lo[:, 1, None]) / problem.d + problem.ext[:, 1, None]
    return h, a, b


def flat_index(problem, a, b, inside=None):
    """Flat cell index for cells given per plane (leading axis P), the dump outside the grid."""
    extra = (1,) * (a.ndim - 1)
    size = problem.size.reshape(problem.num_planes, 2, *extra)
    in_grid = (a >= 0) & (a < size[:, 0]) & (b >= 0) & (b < size[:, 1])
    inside = in_grid if inside is None else inside & in_grid
    plane = jnp.arange(problem.num_planes).reshape(problem.num_planes, *extra)
    return jnp.where(inside, plane * problem.block + (a + 1) * (problem.grid_cells + 2) + (b + 1), problem.dump)


def hard_all_planes(p, problem):
    """`jp.hard_score` over every plane at once."""
    h, a, b = plane_coords(problem, _objective.to_moved_frame(p, problem))
    a, b = round_half_up(a), round_half_up(b)
    flat = flat_index(problem, a, b, problem.curr_valid & (jnp.abs(h) <= problem.d))
    bwd = _objective._ratio(jnp.sum(problem.rm_field[flat], axis=-1), jnp.sum(problem.r_field[flat], axis=-1))
    occupancy = jnp.zeros_like(problem.r_field).at[flat.ravel()].set(1.0).at[problem.dump].set(0.0)
    return jnp.mean((_objective._forward(occupancy, problem) + bwd) / 2)


def soft_all_planes(p, problem):
    """`jp.soft_score` over every plane and the 2 × 2 cells of each point at once."""
    tiny = jnp.finfo(problem.d.dtype).tiny
    w_sel = jnp.maximum(problem.select_width, tiny) * problem.d
    w_bin = jnp.clip(problem.bin_width, tiny, 1.0)
    h, a, b = plane_coords(problem, _objective.to_moved_frame(p, problem))
    sel = jnp.where(problem.curr_valid, _objective._smoothstep((problem.d - jnp.abs(h)) / w_sel + 0.5), 0.0)
    a0, b0 = jnp.floor(a), jnp.floor(b)
    da, db = (jnp.array([c[k] for c in CORNERS])[:, None] for k in (0, 1))
    kernel = _objective._cell_kernel
    w = sel[:, None] * kernel((a - a0)[:, None] - da, w_bin) * kernel((b - b0)[:, None] - db, w_bin)
    flat = flat_index(problem, a0.astype(jnp.int32)[:, None] + da, b0.astype(jnp.int32)[:, None] + db)
    per_corner = [jnp.sum(w * field[flat], axis=-1) for field in (problem.rm_field, problem.r_field)]
    num, den = (((s[:, 0] + s[:, 1]) + s[:, 2]) + s[:, 3] for s in per_corner)
    counts = jnp.zeros_like(problem.r_field).at[flat.ravel()].add(w.ravel())
    occupancy = _objective._smoothstep(counts).at[problem.dump].set(0.0)
    return jnp.mean((_objective._forward(occupancy, problem) + _objective._ratio(num, den)) / 2)


def stub(p, problem):
    """Not an objective: a stand-in that costs nothing to compile."""
    return jnp.sum(jnp.sin(p)) + jnp.sum(problem.curr[0][:4])


def patch(soft=None, hard=None) -> None:
    """Replace the objectives everywhere the public program calls them."""
    if soft is not None:
        _batch.OBJECTIVES["soft"] = _search.soft_score = _estimate.soft_score = soft
    if hard is not None:
        _batch.OBJECTIVES["hard"] = _estimate.hard_score = hard


VARIANTS = {
    "as is": {},
    "soft objective stubbed": {"soft": stub},
    "hard objective stubbed": {"hard": stub},
    "both stubbed": {"soft": stub, "hard": stub},
    "all planes at once": {"soft": soft_all_planes, "hard": hard_all_planes},
}
XLA_OPTIONS = (
    "--xla_cpu_use_fusion_emitters=false",
    "--xla_cpu_use_thunk_runtime=false",
    "--xla_backend_optimization_level=1",
)


def pair():
    case = realistic.make_cases(1, names=("n5",), levels=(1.0,))[0]
    return case, sized_config(case.prev, case.curr, jp.Config())


def median_ms(fn, *args, repeats: int = 9) -> float:
    """Median milliseconds of `repeats` calls after a first one (`time_call`)."""
    return 1e3 * time_call(fn, *args, repeats=repeats)["median_s"]


def child(variant: str) -> dict:
    """Compile the public program with `variant`'s objectives, in this (fresh) process."""
    patch(**VARIANTS[variant])
    case, config = pair()
    dynamic, static = eqx.partition((case.prev, case.curr, config, jax.random.key(0)), eqx.is_array)
    t0 = time.perf_counter()
    lowered = jax.jit(lambda d: _estimate._build_and_estimate(*eqx.combine(d, static))).lower(dynamic)
    t1 = time.perf_counter()
    program = lowered.compile()
    t2 = time.perf_counter()
    return {"lower_s": t1 - t0, "compile_s": t2 - t1, "warm_ms": median_ms(program, dynamic)}


def fresh(variant: str, xla_flags: str = "") -> dict:
    env = {**os.environ, "XLA_FLAGS": xla_flags}
    out = subprocess.run(
        [sys.executable, __file__, "--child", variant], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def formulations() -> list[dict]:
    """Both formulations on the pair's problem and its coarse problem: one call, a batch of
    1024 poses as the search scores them, one gradient (median ms); the largest difference
    of their values over the batch."""
    case, config = pair()
    problem = jp.Problem.build(case.prev, case.curr, config)
    ps = jax.random.uniform(jax.random.key(0), (1024, 6), minval=-1.0, maxval=1.0) * jnp.array([0.3] * 3 + [0.1] * 3)
    rows = []
    pairs = (("hard", jp.hard_score, hard_all_planes), ("soft", jp.soft_score, soft_all_planes))
    for level, prob in (("problem", problem), ("coarse problem", problem.coarse)):
        for name, per_plane, all_planes in pairs:
            values = {}
            for form, fn in (("per plane", per_plane), ("all planes", all_planes)):
                batch = jax.jit(lambda ps, pb, fn=fn: jax.lax.map(lambda p: fn(p, pb), ps, batch_size=16))
                values[form] = batch(ps, prob)
                rows.append(
                    {
                        "objective": name,
                        "level": level,
                        "form": form,
                        "one_ms": median_ms(jax.jit(fn), ps[0], prob),
                        "batch_1024_ms": median_ms(batch, ps, prob),
                        "grad_ms": median_ms(jax.jit(jax.grad(fn)), ps[0], prob),
                    }
                )
            rows[-1]["max_difference"] = float(jnp.max(jnp.abs(values["per plane"] - values["all planes"])))
            print(rows[-2], rows[-1], flush=True)
    return rows


def markdown(programs: list[dict], forms: list[dict]) -> str:
    lines = [
        "| program | XLA_FLAGS | lower s | compile s | warm ms |",
        "|---|---|---|---|---|",
        *(
            f"| {r['variant']} | {r['xla_flags'] or '–'} | {r['lower_s']:.1f} | {r['compile_s']:.1f} "
            f"| {r['warm_ms']:.0f} |"
            for r in programs
        ),
        "",
        "| objective | problem | form | one call ms | 1024 poses ms | gradient ms |",
        "|---|---|---|---|---|---|",
        *(
            f"| {r['objective']} | {r['level']} | {r['form']} | {r['one_ms']:.3f} | {r['batch_1024_ms']:.1f} "
            f"| {r['grad_ms']:.3f} |"
            for r in forms
        ),
    ]
    return "\n".join(lines) + "\n"


def main() -> None:
    programs = []
    for variant in VARIANTS:
        programs.append({"variant": variant, "xla_flags": "", **fresh(variant)})
        print(programs[-1], flush=True)
    for flags in XLA_OPTIONS:
        programs.append({"variant": "as is", "xla_flags": flags, **fresh("as is", flags)})
        print(programs[-1], flush=True)
    forms = formulations()
    write_json("compile_costs.json", {"pair": "n5 σ1 #0", "programs": programs, "formulations": forms})
    (RESULTS / "compile_costs.md").write_text(markdown(programs, forms))


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        print(json.dumps(child(sys.argv[2])))
    else:
        main()
