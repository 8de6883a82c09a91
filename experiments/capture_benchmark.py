"""Capture at any rotation (issue 23): `Config.capture()` on pairs turned 0–180°, in bins of
0–30, 30–60, 60–90, 90–135 and 135–180°, N5 (exactly symmetric) and two asymmetric targets
(the satellite and the fragment), noise-free and at σ = 1 cm, with small_gicp GICP and
Open3D FGR / RANSAC (where Open3D imports) on the same clouds in the same run. See
`jaxpose.evaluation.capture` for the pairs, the overlap rule and the scores. Also the coarse
problem's scoring throughput (poses/s) for the capture grid's batches.

    uv run --extra peers python experiments/capture_benchmark.py [pairs per bin]
        → results/capture_benchmark.{json,md}
"""

from __future__ import annotations

import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose._batch import score_batch
from jaxpose._problem import build_problem, sized_config
from jaxpose._rotations import angles, super_fibonacci
from jaxpose.evaluation import capture
from jaxpose.evaluation.peers import available_peers

PEER_NAMES = ("small_gicp GICP", "Open3D FGR (FPFH)", "Open3D RANSAC (FPFH)")


def scoring_throughput(case, config, repeats: int = 5) -> dict:
    """Poses per second of the capture grid's batch (`RotationSearch.rotations` poses) on the
    coarse problem of one pair, hard and soft objectives; median of `repeats` warm calls."""
    config = sized_config(case.prev, case.curr, config)
    problem = build_problem(case.prev, case.curr, config)
    G = super_fibonacci(config.so3.rotations)
    ps = jnp.concatenate([angles(G), jnp.zeros((G.shape[0], 3))], axis=1).astype(problem.d.dtype)
    out = {}
    for objective in ("hard", "soft"):
        run = eqx.filter_jit(lambda pb, ps, o=objective: score_batch(ps, pb.search_problem, o, chunk=64))
        jax.block_until_ready(run(problem, ps))
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            jax.block_until_ready(run(problem, ps))
            times.append(time.perf_counter() - t0)
        times.sort()
        out[objective] = ps.shape[0] / times[len(times) // 2]
    return out


def main(pairs: int = 3) -> None:
    t0 = time.perf_counter()
    cases, rejected = capture.make_cases(pairs)
    print(f"{len(cases)} pairs ({rejected} draws rejected for < {capture.MIN_OVERLAP:.0%} shared surface)", flush=True)
    config = jp.Config.capture()
    rows, first_calls = capture.run_jaxpose(cases, config)
    peers, missing = available_peers()
    for name in PEER_NAMES:
        if name in peers:
            rows += capture.run_peer(name, peers[name], cases)
    summary = capture.summarise(rows)
    totals = capture.totals(rows)
    throughput = scoring_throughput(cases[0], config)
    report = {
        "command": "uv run --extra peers python experiments/capture_benchmark.py " + str(pairs),
        "pairs": len(cases),
        "rejected_draws": rejected,
        "first_calls_s": first_calls,
        "missing_peers": {k: v for k, v in missing.items() if k in PEER_NAMES},
        "scoring_poses_per_s": throughput,
        "totals": totals,
        "summary": summary,
        "rows": rows,
        "seconds": time.perf_counter() - t0,
    }
    write_json("capture_benchmark.json", report)
    lines = [
        capture.markdown(summary),
        "",
        "| method | bin ° | found | truth among | false succ. | median ms |",
        "|---|---|---|---|---|---|",
    ]
    for s in totals:
        lines.append(
            f"| {s['method']} | {s['bin']} | {s['found']}/{s['pairs']} | {s['among']} "
            f"| {s['false_success']} | {s['median_ms']:.0f} |"
        )
    (RESULTS / "capture_benchmark.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"scoring: {throughput}; first calls {[round(s, 1) for s in first_calls]} s; missing {list(missing)}")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:]))
