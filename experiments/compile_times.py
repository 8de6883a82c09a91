"""Where the public call's compile time goes: each stage traced, lowered and compiled apart.

On one realistic-benchmark pair (N5, σ = 1 cm, `make_cases(1)`), with the default config sized
from it, the wall time of `jax.jit(...).lower(...)` (tracing and lowering) and of `.compile()`
for: the build (`Problem.build`'s body), the global search, the refine, one fine-stage run,
`estimate_problem` (search, refine, fine stage, status) and the whole public program
(`_build_and_estimate`). A cold process: nothing is cached in memory or on disk; run it with
`XLA_FLAGS=...` and a label to compare XLA's options. Every program is compiled as jaxpose
compiles its own (`jaxpose._programs.compile_lowered`, with its XLA options). Also the median
of 5 warm runs of the public program, and three cold traces of it (`jax.clear_caches()`
first: above, its parts were traced already), tracing and lowering apart.

    uv run python experiments/compile_times.py [label] → results/compile_times[_label].json
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import equinox as eqx
import jax
from _common import write_json

import jaxpose as jp
from jaxpose import _programs
from jaxpose._estimate import _build_and_estimate, estimate_problem
from jaxpose._fine import fine_refine
from jaxpose._problem import _build, sized_config
from jaxpose._search import local_refine, restarted_search
from jaxpose.evaluation import realistic


def compile_lowered(lowered):
    """`lowered` compiled as jaxpose compiles its programs; plain `compile()` with a jaxpose
    older than `_programs.compile_lowered`, so that the script also measures earlier commits
    (`PYTHONPATH=<checkout>`)."""
    return getattr(_programs, "compile_lowered", lambda low: low.compile())(lowered)


def cold_trace(fn, *args) -> dict:
    """Seconds to trace and to lower `fn` for `args` after `jax.clear_caches()`: what a new
    process pays before compiling, whatever was traced before in this one."""
    dynamic, static = eqx.partition(args, eqx.is_array)
    jax.clear_caches()
    t0 = time.perf_counter()
    traced = jax.jit(lambda d: fn(*eqx.combine(d, static))).trace(dynamic)
    t1 = time.perf_counter()
    traced.lower()
    return {"trace_s": t1 - t0, "lower_s": time.perf_counter() - t1}


def compile_times(fn, *args) -> tuple[dict, object]:
    """Lower and compile `fn` for `args` (arrays dynamic, the rest static); the seconds of
    each and the compiled program's output."""
    row, run = compiled(fn, *args)
    return row, run()


def compiled(fn, *args):
    """The seconds of lowering and compiling `fn` for `args`, and a call of the program."""
    dynamic, static = eqx.partition(args, eqx.is_array)
    t0 = time.perf_counter()
    lowered = jax.jit(lambda d: fn(*eqx.combine(d, static))).lower(dynamic)
    t1 = time.perf_counter()
    program = compile_lowered(lowered)
    t2 = time.perf_counter()
    return {"lower_s": t1 - t0, "compile_s": t2 - t1}, lambda: program(dynamic)


def main() -> None:
    case = realistic.make_cases(1, names=("n5",), levels=(1.0,))[0]
    config = sized_config(case.prev, case.curr, jp.Config())
    key = jax.random.key(0)
    rows = {}
    rows["build"], problem = compile_times(_build, case.prev, case.curr, config)
    rows["search"], glob = compile_times(restarted_search, problem, config, key)
    rows["refine"], loc = compile_times(local_refine, problem, config, glob.params)
    rows["one fine run"], _ = compile_times(fine_refine, problem, config, loc.params)
    rows["estimate_problem"], _ = compile_times(estimate_problem, problem, config, key)
    rows["public program"], public = compiled(_build_and_estimate, case.prev, case.curr, config, key)
    for name, row in rows.items():
        print(f"{name}: lower {row['lower_s']:.2f} s, compile {row['compile_s']:.2f} s", flush=True)
    run_ms = 1e3 * warm_median(public)
    print(f"public program, warm run: {run_ms:.0f} ms")
    traces = [cold_trace(_build_and_estimate, case.prev, case.curr, config, key) for _ in range(3)]
    cold = ", ".join(f"trace {t['trace_s']:.2f} s + lower {t['lower_s']:.2f} s" for t in traces)
    print(f"public program, cold: {cold}")
    label = f"_{sys.argv[1]}" if len(sys.argv) > 1 else ""
    write_json(
        f"compile_times{label}.json",
        {
            "pair": case.label,
            "xla_flags": os.environ.get("XLA_FLAGS", ""),
            "capacities": str(config.capacities),
            "stages": rows,
            "public_program_run_ms": run_ms,
            "public_program_cold_traces": traces,
        },
    )


def warm_median(run, repeats: int = 5) -> float:
    """Median seconds of `repeats` calls after a first one."""
    times = []
    for _ in range(repeats + 1):
        t0 = time.perf_counter()
        jax.block_until_ready(run())
        times.append(time.perf_counter() - t0)
    return statistics.median(times[1:])


if __name__ == "__main__":
    main()
