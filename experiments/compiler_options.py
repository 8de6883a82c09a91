"""The public program compiled with XLA's default options and with jaxpose's, on the same pairs.

For each realistic-benchmark pair (`make_cases(1)`: N5, the satellite, the upper stage and the
fragment at σ = 0 and 1 cm), the public program (`_build_and_estimate`, the default config
sized from the pair) is traced and lowered once, then compiled twice: with XLA's default
options and with `jaxpose._programs.compiler_options()` (`CPU_COMPILER_OPTIONS`). The two
programs are called in turn, `repeats` + 1 times each, so that both meet the same state of
the machine; the first call of each is dropped. Per pair: the compile time of each, the median
warm call, the largest difference of the estimates' p (frame n; radians and metres) and both
statuses.

    uv run python experiments/compiler_options.py [repeats] → results/compiler_options.{json,md}
"""

from __future__ import annotations

import statistics
import sys
import time

import equinox as eqx
import jax
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose import _programs
from jaxpose._estimate import STATUS_NAME, _build_and_estimate
from jaxpose._problem import sized_config
from jaxpose.evaluation import realistic

TARGETS = ("n5", "satellite", "upper_stage", "fragment")
LEVELS = (0.0, 1.0)


def compare_pair(case, repeats: int) -> dict:
    """Compile times, warm medians and estimates of the two programs on one pair."""
    config = sized_config(case.prev, case.curr, jp.Config())
    dynamic, static = eqx.partition((case.prev, case.curr, config, jax.random.key(0)), eqx.is_array)
    lowered = jax.jit(lambda d: _build_and_estimate(*eqx.combine(d, static))).lower(dynamic)
    variants = {"xla_default": {}, "jaxpose": _programs.compiler_options()}
    programs, compile_s = {}, {}
    for name, options in variants.items():
        start = time.perf_counter()
        programs[name] = _programs.compile_lowered(lowered, options)
        compile_s[name] = time.perf_counter() - start
    times = {name: [] for name in variants}
    estimates = {}
    for _ in range(repeats + 1):
        for name, program in programs.items():
            start = time.perf_counter()
            estimates[name] = jax.block_until_ready(program(dynamic))[0]
            times[name].append(time.perf_counter() - start)
    warm_ms = {name: 1e3 * statistics.median(ts[1:]) for name, ts in times.items()}
    a, b = (np.asarray(estimates[name].params) for name in variants)
    return {
        "pair": case.label,
        "compile_s": compile_s,
        "warm_ms": warm_ms,
        "ratio": warm_ms["jaxpose"] / warm_ms["xla_default"],
        "max_param_difference": float(np.max(np.abs(a - b))),
        "status": {name: STATUS_NAME[int(e.status)] for name, e in estimates.items()},
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| pair | compile s: XLA default / jaxpose | warm ms: XLA default / jaxpose | ratio | max Δp | status |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        c, w, s = r["compile_s"], r["warm_ms"], r["status"]
        status = s["xla_default"] if s["xla_default"] == s["jaxpose"] else f"{s['xla_default']} / {s['jaxpose']}"
        lines.append(
            f"| {r['pair']} | {c['xla_default']:.1f} / {c['jaxpose']:.1f} | {w['xla_default']:.1f} / "
            f"{w['jaxpose']:.1f} | {r['ratio']:.2f} | {r['max_param_difference']:.1e} | {status} |"
        )
    ratios = [r["ratio"] for r in rows]
    lines.append(f"\nWarm ratio jaxpose / XLA default: median {statistics.median(ratios):.2f}, ")
    lines[-1] += f"range {min(ratios):.2f}–{max(ratios):.2f}; options {_programs.compiler_options()}."
    return "\n".join(lines) + "\n"


def main() -> None:
    repeats = int(sys.argv[1]) if len(sys.argv) > 1 else 6
    rows = []
    for case in realistic.make_cases(1, names=TARGETS, levels=LEVELS):
        rows.append(compare_pair(case, repeats))
        print(rows[-1], flush=True)
    write_json("compiler_options.json", {"options": _programs.compiler_options(), "repeats": repeats, "rows": rows})
    (RESULTS / "compiler_options.md").write_text(table(rows))
    print(table(rows))


if __name__ == "__main__":
    main()
