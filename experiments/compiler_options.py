"""The public program compiled with XLA's default options, with XLA:CPU's elemental loop
emitters, and with jaxpose's options, on the same pairs.

For each realistic-benchmark pair (`make_cases(1)`: N5, the satellite, the upper stage and the
fragment at σ = 0 and 1 cm), the public program (`_build_and_estimate`, the default config
sized from the pair) is traced and lowered once, then compiled three times: with XLA's default
options, with `ELEMENTAL` (`{"xla_cpu_use_fusion_emitters": False}`, XLA:CPU's older emitters
for its loop fusions) and with `jaxpose._programs.compiler_options()` (`CPU_COMPILER_OPTIONS`).
The programs are called in turn, `repeats` + 1 times each, so that all meet the same state of
the machine; the first call of each is dropped. Per pair: the compile time of each, the median
warm call, the largest difference of each estimate's p from the XLA defaults' (frame n;
radians and metres) and the statuses.

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
ELEMENTAL = {"xla_cpu_use_fusion_emitters": False}
"""XLA:CPU's elemental emitters for loop fusions instead of its fusion emitters: a variant that
the comparison keeps beside XLA's defaults and jaxpose's options."""


def compare_pair(case, repeats: int) -> dict:
    """Compile times, warm medians and estimates of the two programs on one pair."""
    config = sized_config(case.prev, case.curr, jp.Config())
    dynamic, static = eqx.partition((case.prev, case.curr, config, jax.random.key(0)), eqx.is_array)
    lowered = jax.jit(lambda d: _build_and_estimate(*eqx.combine(d, static))).lower(dynamic)
    variants = {"xla_default": {}, "elemental": ELEMENTAL, "jaxpose": _programs.compiler_options()}
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
    reference = np.asarray(estimates["xla_default"].params)
    return {
        "pair": case.label,
        "compile_s": compile_s,
        "warm_ms": warm_ms,
        "ratio": {name: warm_ms[name] / warm_ms["xla_default"] for name in variants},
        "max_param_difference": {
            name: float(np.max(np.abs(np.asarray(e.params) - reference))) for name, e in estimates.items()
        },
        "status": {name: STATUS_NAME[int(e.status)] for name, e in estimates.items()},
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| pair | compile s: XLA default / elemental / jaxpose | warm ms: XLA default / elemental / jaxpose "
        "| ratio to XLA default: elemental / jaxpose | max Δp: elemental / jaxpose | status |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        c, w, q, d, s = r["compile_s"], r["warm_ms"], r["ratio"], r["max_param_difference"], r["status"]
        status = " / ".join(dict.fromkeys(s.values()))
        lines.append(
            f"| {r['pair']} | {c['xla_default']:.1f} / {c['elemental']:.1f} / {c['jaxpose']:.1f} | "
            f"{w['xla_default']:.1f} / {w['elemental']:.1f} / {w['jaxpose']:.1f} | "
            f"{q['elemental']:.2f} / {q['jaxpose']:.2f} | {d['elemental']:.1e} / {d['jaxpose']:.1e} | {status} |"
        )
    for name in ("elemental", "jaxpose"):
        ratios = [r["ratio"][name] for r in rows]
        lines.append(
            f"\nWarm ratio {name} / XLA default: median {statistics.median(ratios):.2f}, "
            f"range {min(ratios):.2f}–{max(ratios):.2f}."
        )
    lines.append(f"\njaxpose's options: {_programs.compiler_options()}; elemental: {ELEMENTAL}.")
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
