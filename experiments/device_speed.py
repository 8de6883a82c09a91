"""The public call, batches and capture on whatever backend JAX runs on (issues 22 and 23's
GPU figures), GICP in the same run on that machine's CPU, under one time budget.

Sections, in the order the last argument names them (by default the order below), each
skipped when less than its share of the budget is left, each written to the JSON file as
soon as it ends (so that a run stopped at its limit keeps what it did):

- **warm:** `public_speed.warm_pairs` (the default config through `jp.estimate`, median of
  `repeats` warm calls; small_gicp's GICP, 1 thread, on the same clouds): N5, the satellite
  and the upper stage at σ = 0 and 1 cm, `pairs` pairs each.
- **capture:** `Config.capture()` on `capture.make_cases(capture_pairs)` (N5, the satellite and
  the fragment, turned 0–180° in five bins, σ = 0 and 1 cm), sized once for all the pairs
  (`sized_batch_config`: one compile, as a jit user would size it), GICP on the same pairs,
  and the coarse problem's scoring throughput (poses/s) for the capture grid's batch.
- **batched:** `jp.estimate_batch` (one program, its default chunk: the whole batch vmapped
  on an accelerator, one pair after another on a CPU) and `jax.vmap` of `jp.estimate` (a
  config sized for the camera) over `batch` N5 pairs at σ = 1 cm: pairs per second, the
  first call (compile and one run) apart.
- **cold:** a fresh process with an empty compilation cache: its first result on an N5 pair
  at σ = 1 cm, from the call (`public_speed.fresh_process`).

    uv run --extra peers python experiments/device_speed.py \
        [budget_s] [pairs] [repeats] [batch] [capture_pairs] [sections]
        → results/device_speed_<backend>.json (or $DEVICE_SPEED_OUT)
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
import traceback
from pathlib import Path

import jax
from _common import write_json
from capture_benchmark import scoring_throughput
from public_speed import fresh_process, median_time, n5_batch, warm_pairs

import jaxpose as jp
from jaxpose._estimate_batch import default_chunk
from jaxpose._problem import sized_batch_config
from jaxpose.evaluation import capture, realistic
from jaxpose.evaluation.peers import available_peers

SHARE = {"warm": 0.0, "capture": 0.45, "batched": 0.15, "cold": 0.06}
"""The fraction of the whole budget that must still be left for a section to start."""


def batched(batch: int, repeats: int) -> dict:
    """Pairs per second for `batch` N5 pairs at σ = 1 cm: `jp.estimate_batch` and `jax.vmap`
    of `jp.estimate` with one config sized for the camera; the first call apart."""
    cases, prev, curr, keys, vmapped = n5_batch(batch)
    runs = {
        "estimate_batch": lambda: jp.estimate_batch(prev, curr, key=keys),
        "vmap": lambda: vmapped(prev, curr, keys),
    }
    out = {"batch": batch, "estimate_batch_chunk": default_chunk(batch)}
    for name, run in runs.items():
        t0 = time.perf_counter()
        est = jax.block_until_ready(run())
        first = time.perf_counter() - t0
        seconds = median_time(run, repeats)
        found = [realistic.errors(c, est.rotation[i], est.translation[i])["found"] for i, c in enumerate(cases)]
        out[name] = {
            "first_call_s": first,
            "median_s": seconds,
            "pairs_per_s": batch / seconds,
            "found": int(sum(found)),
        }
        print(name, out[name], flush=True)
    return out


def capture_section(pairs: int) -> dict:
    cases, rejected = capture.make_cases(pairs)
    config = sized_batch_config([(c.prev, c.curr) for c in cases], jp.Config.capture())
    rows, first_calls = capture.run_jaxpose(cases, config)
    peers, missing = available_peers()
    if "small_gicp GICP" in peers:
        rows += capture.run_peer("small_gicp GICP", peers["small_gicp GICP"], cases)
    return {
        "pairs": len(cases),
        "rejected_draws": rejected,
        "first_calls_s": first_calls,
        "scoring_poses_per_s": scoring_throughput(cases[0], config),
        "totals": capture.totals(rows),
        "summary": capture.summarise(rows),
        "rows": rows,
    }


def cold_start() -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        return fresh_process(str(Path(tmp) / "cache"))


def main(
    budget_s: float = 480,
    pairs: int = 1,
    repeats: int = 5,
    batch: int = 64,
    capture_pairs: int = 1,
    sections: str = "warm,capture,batched,cold",
) -> None:
    start = time.perf_counter()
    name = os.environ.get("DEVICE_SPEED_OUT", f"device_speed_{jax.default_backend()}.json")
    runs = {
        "warm": lambda: warm_pairs(pairs, repeats),
        "capture": lambda: capture_section(capture_pairs),
        "batched": lambda: batched(batch, repeats),
        "cold": cold_start,
    }
    report: dict = {"command": " ".join(["experiments/device_speed.py", *sys.argv[1:]]), "skipped": []}
    for section in sections.split(","):
        run = runs[section]
        left = budget_s - (time.perf_counter() - start)
        if left < SHARE[section] * budget_s:
            report["skipped"].append(section)
            continue
        t0 = time.perf_counter()
        try:
            report[section] = run()
        except Exception:  # a failed section is reported, and the next still runs
            report[section] = {"error": traceback.format_exc()}
            print(report[section]["error"], flush=True)
        report[f"{section}_seconds"] = time.perf_counter() - t0
        print(f"{section}: {report[f'{section}_seconds']:.0f} s", flush=True)
        path = write_json(name, report)
        if "OUT" in os.environ:
            (Path(os.environ["OUT"]) / name).write_text(path.read_text())


if __name__ == "__main__":
    types = (float, int, int, int, int, str)
    main(*(kind(a) for kind, a in zip(types, sys.argv[1:], strict=False)))
