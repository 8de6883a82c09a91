"""Where a warm public call spends its time, by compiled operation (XLA:CPU thunks).

For one realistic-benchmark pair (`make_cases(1)`, a target and a noise level), three warm
calls of `jp.estimate(prev, curr, key=...)`, then `repeats` more under `jax.profiler.trace`
with a Perfetto trace. The trace's complete events are summed by name over the traced calls
and divided by `repeats`: milliseconds and executions per call of each thunk (a fusion, a
while loop, a custom call; a while loop's time includes the thunks inside it) and of the
traced Python frames. Operation names are those of the call's optimised HLO module (dump it
with `XLA_FLAGS=--xla_dump_to=<dir> --xla_dump_hlo_as_text` to read what a fusion computes
and which source line it came from).

    uv run python experiments/call_profile.py [target] [sigma_cm] [repeats] [top]
        → results/call_profile_<target>_<sigma>.json (default: n5 1.0 5 40)
"""

from __future__ import annotations

import collections
import gzip
import json
import sys
import tempfile
from pathlib import Path

import jax
from _common import RESULTS, machine, write_json

import jaxpose as jp
from jaxpose.evaluation import realistic


def thunk_times(trace_dir: Path, repeats: int) -> list[dict]:
    """Per-call milliseconds and executions of each complete event in the Perfetto trace."""
    (path,) = trace_dir.rglob("perfetto_trace.json.gz")
    events = json.load(gzip.open(path))
    events = events["traceEvents"] if isinstance(events, dict) else events
    total, count = collections.Counter(), collections.Counter()
    for e in events:
        if e.get("ph") == "X":
            total[e["name"]] += e.get("dur", 0.0)
            count[e["name"]] += 1
    return [
        {"name": name, "ms_per_call": us / 1e3 / repeats, "per_call": count[name] / repeats}
        for name, us in total.most_common()
    ]


def main(target: str = "n5", sigma_cm: float = 1.0, repeats: int = 5, top: int = 40) -> None:
    (case,) = realistic.make_cases(1, names=(target,), levels=(sigma_cm,))
    key = jax.random.key(case.index)
    for _ in range(3):
        jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(repeats):
                jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key).params)
        rows = thunk_times(Path(tmp), repeats)[:top]
    for r in rows:
        print(f"{r['ms_per_call']:8.2f} ms/call  ×{r['per_call']:6.0f}  {r['name'][:100]}")
    name = f"call_profile_{target}_{sigma_cm:g}.json"
    write_json(name, {"machine": machine(), "case": case.label, "repeats": repeats, "rows": rows})
    print("wrote", RESULTS / name)


if __name__ == "__main__":
    args = sys.argv[1:]
    main(*args[:1], *(float(a) for a in args[1:2]), *(int(a) for a in args[2:4]))
