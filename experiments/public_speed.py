"""Speed of the public call on the realistic benchmark's clouds, GICP in the same run (issue 22).

- **Warm per pair:** `jp.estimate(prev, curr, key=...)` with the default config, after a first
  call per pair (which compiles when the pair opens a new capacity bucket; that time is
  reported apart), median of `repeats` calls; small_gicp's GICP (1 thread, as in the
  realistic benchmark) median of `repeats` calls on the same clouds. N5, the satellite and
  the upper stage at σ = 0 and 1 cm.
- **Cold start:** a fresh process with the default settings and an empty cache folder
  (`$JAXPOSE_CACHE`): the import, the first result on one pair (from the call), and the time to
  make the estimate program alone (`compile_s`: tracing, lowering and compiling it, or loading
  it from its file); then a second fresh process with that folder warm (the program files
  jaxpose keeps by default), and, in a folder of their own, two processes with JAX's
  compilation cache alone (`jp.enable_compile_cache`, then `jp.disable_compile_cache`), the
  second's figures reported (the program traced and lowered again to find it).
- **CLI end to end:** `jaxpose estimate a.ply b.ply` as a subprocess, cold and warm cache.
- **Batched:** `batch` pairs of one bucket, pairs per second: `jax.vmap` of `estimate` (the
  jit path, a config sized for the camera), `jp.estimate_batch` (`lax.map`), and one public
  call per pair.

    uv run --extra peers python experiments/public_speed.py [pairs] [repeats] [batch]
        → results/public_speed.{json,md}
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose._estimate import _estimate_pair
from jaxpose._problem import sized_config
from jaxpose.evaluation import realistic
from jaxpose.evaluation.realistic import _bucket

TARGETS = ("n5", "satellite", "upper_stage")
LEVELS = (0.0, 1.0)

COLD = """
import json, sys, time
t0 = time.perf_counter()
import jax
import jaxpose as jp
if sys.argv[2] == "xla-only":
    jp.enable_compile_cache(sys.argv[1])
    jp.disable_compile_cache()
from jaxpose.evaluation import realistic
from jaxpose._estimate import _estimate_pair
t_import = time.perf_counter()
case = realistic.make_cases(1, names=("n5",), levels=(1.0,))[0]
t1 = time.perf_counter()
est = jp.estimate(case.prev, case.curr, key=jax.random.key(0))
est.params.block_until_ready()
t2 = time.perf_counter()
print(json.dumps({"import_s": t_import - t0, "simulate_s": t1 - t_import, "first_result_s": t2 - t1,
                  "compile_s": _estimate_pair.last_compile_s,
                  "status": int(est.status)}))
"""


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def warm_pairs(pairs: int, repeats: int) -> list[dict]:
    rows = []
    for case in realistic.make_cases(pairs, names=TARGETS, levels=LEVELS):
        key = jax.random.key(case.index)
        _estimate_pair.last_compile_s = 0.0
        t0 = time.perf_counter()
        est = jax.block_until_ready(jp.estimate(case.prev, case.curr, key=key))
        first = time.perf_counter() - t0
        ms = 1e3 * median_time(lambda c=case, k=key: jp.estimate(c.prev, c.curr, key=k), repeats)
        a, b = case.prev.compact(), case.curr.compact()
        gicp_ms = 1e3 * median_time(lambda a=a, b=b: realistic.gicp(a, b), repeats)
        R, t = realistic.gicp(a, b)
        row = {
            "target": case.target,
            "sigma_cm": case.sigma_cm,
            "pair": case.index,
            "jaxpose_ms": ms,
            "gicp_ms": gicp_ms,
            "first_call_s": first,
            "compile_s": _estimate_pair.last_compile_s,
            "status": int(est.status),
            "jaxpose": realistic.errors(case, est.rotation, est.translation),
            "gicp": realistic.errors(case, R, t),
        }
        rows.append(row)
        print(f"{case.label}: {ms:.0f} ms (GICP {gicp_ms:.0f} ms), compile {row['compile_s']:.1f} s", flush=True)
    return rows


def fresh_process(cache: str, files: str = "default") -> dict:
    """A new Python process's start-up figures with the cache folder `cache`; `files`:
    "default" (`$JAXPOSE_CACHE` set to it, nothing called: jaxpose's program files) or
    "xla-only" (JAX's compilation cache alone)."""
    env = {**os.environ, "JAXPOSE_CACHE": cache}
    out = subprocess.run(
        [sys.executable, "-c", COLD, cache, files], capture_output=True, text=True, check=True, env=env
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def cli_end_to_end(folder: Path, cache: str) -> float:
    case = realistic.make_cases(1, names=("n5",), levels=(1.0,))[0]
    a, b = folder / "a.ply", folder / "b.ply"
    jp.save_cloud(a, case.prev)
    jp.save_cloud(b, case.curr)
    env = {**os.environ, "JAXPOSE_CACHE": cache}
    t0 = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "jaxpose._cli", "estimate", str(a), str(b)], env=env, capture_output=True, check=True
    )
    return time.perf_counter() - t0


def n5_batch(batch: int):
    """`batch` N5 pairs at σ = 1 cm (`realistic.make_cases`) stacked for one batched call, a
    key per pair, and `jax.jit(jax.vmap(jp.estimate))` with one config sized for the camera:
    (cases, prev, curr, keys, vmapped)."""
    cases = realistic.make_cases(batch, names=("n5",), levels=(1.0,))
    config = jp.Config().sized_for(jp.Camera.camcube2(), 1.9)
    stack = lambda xs: jax.tree.map(lambda *x: np.stack(x), *xs)  # noqa: E731
    prev, curr = stack([c.prev for c in cases]), stack([c.curr for c in cases])
    keys = jax.random.split(jax.random.key(0), batch)
    vmapped = jax.jit(jax.vmap(lambda p, c, k: jp.estimate(p, c, config, key=k)))
    return cases, prev, curr, keys, vmapped


def batched(batch: int, repeats: int) -> dict:
    """Pairs per second for `batch` N5 pairs at σ = 1 cm: `jax.vmap` of `estimate` (one config
    sized for the camera), `jp.estimate_batch` (one `lax.map` program, sized from the pairs)
    and one public call per pair (one compiled program per capacity bucket kept); compile
    (with the first run) apart, and how many buckets the pairs fall into."""
    cases, prev, curr, keys, vmapped = n5_batch(batch)
    runs = {
        "vmap": lambda: vmapped(prev, curr, keys),
        "estimate_batch": lambda: jp.estimate_batch(prev, curr, key=keys),
        "one call per pair": lambda: [jp.estimate(c.prev, c.curr, key=k) for c, k in zip(cases, keys, strict=True)],
    }
    out = {"batch": batch, "buckets": len({_bucket(sized_config(c.prev, c.curr, jp.Config())) for c in cases})}
    kept = _estimate_pair.size
    # The pairs fall into more capacity buckets than the public path keeps compiled programs
    # (`jaxpose._programs.PROGRAMS`); looping over them would recompile on every call. Keep
    # one program per bucket here, so that the row measures the calls, not the compiles.
    _estimate_pair.size = max(kept, batch)
    for name, run in runs.items():
        t0 = time.perf_counter()
        jax.block_until_ready(run())
        compile_s = time.perf_counter() - t0
        seconds = median_time(run, repeats)
        out[name] = {"compile_s": compile_s, "median_s": seconds, "pairs_per_s": batch / seconds}
    _estimate_pair.size = kept
    return out


def markdown(rows: list[dict]) -> str:
    lines = ["| target | σ, cm | pairs | jaxpose median ms | GICP median ms | ratio |", "|---|---|---|---|---|---|"]
    for target in TARGETS:
        for sigma in LEVELS:
            group = [r for r in rows if r["target"] == target and r["sigma_cm"] == sigma]
            mine = statistics.median(r["jaxpose_ms"] for r in group)
            theirs = statistics.median(r["gicp_ms"] for r in group)
            lines.append(f"| {target} | {sigma:g} | {len(group)} | {mine:.0f} | {theirs:.0f} | {mine / theirs:.1f}× |")
    return "\n".join(lines) + "\n"


def main(pairs: int = 4, repeats: int = 5, batch: int = 8) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cache, xla_only = str(Path(tmp) / "cache"), str(Path(tmp) / "xla-only")
        cold = fresh_process(cache)
        warm_cache = fresh_process(cache)
        fresh_process(xla_only, "xla-only")  # fills XLA's cache for the direct program
        warm_xla_only = fresh_process(xla_only, "xla-only")
        cli_cache = str(Path(tmp) / "cli")
        cli = {"cold_s": cli_end_to_end(Path(tmp), cli_cache), "warm_cache_s": cli_end_to_end(Path(tmp), cli_cache)}
        print("cold", cold, "warm cache", warm_cache, "XLA's cache alone", warm_xla_only, "cli", cli, flush=True)
        # This process's programs go to a folder of the run's own (the default keeps them in
        # ~/.cache/jaxpose), so that its first calls compile whatever the user's cache holds.
        jp.enable_compile_cache(Path(tmp) / "this-process")
        rows = warm_pairs(pairs, repeats)
        vmapped = batched(batch, repeats)
    print("batched", json.dumps(vmapped), flush=True)
    table = markdown(rows)
    print(table)
    payload = {
        "cold_process": cold,
        "warm_cache_process": warm_cache,
        "warm_xla_cache_only_process": warm_xla_only,
        "cli": cli,
        "batched": vmapped,
        "rows": rows,
    }
    write_json("public_speed.json", payload)
    (RESULTS / "public_speed.md").write_text(table)


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
