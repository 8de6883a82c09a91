"""N5's equivalent motions in the capture benchmark (issue 23): what one view pair can say
about them. For each N5 pair of `capture.make_cases(pairs)` and each motion that N5's half
turns make equivalent to the truth (`CaptureCase.equivalents`), at that exact motion:

- the consistency that `Estimate.ambiguous` compares (`jaxpose._capture.consistency`, the
  fine stage's 3 cm gate, on `RotationSearch.points` points a side);
- how many points it is measured on: the previous points that should be seen after the
  motion and the current points that should have been seen before it (facing the camera and
  not hidden behind nearer surface that the other view saw);
- the half-turn twin that the capture stage would fit there when the truth is its best
  hypothesis (`_capture.symmetric_candidates`): its rotation and translation errors from the
  equivalent nearest it.

The benchmark's own outcome of each pair (status, ambiguous, truth among the hypotheses) is
read from `results/capture_benchmark.json` where that file holds the pair.

    uv run python experiments/capture_symmetry.py [pairs per bin]
        → results/capture_symmetry.{json,md}
"""

from __future__ import annotations

import json
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import RESULTS, write_json

import jaxpose as jp
from jaxpose import _capture
from jaxpose._poses import displacement_from_motion
from jaxpose._problem import build_problem, sized_config
from jaxpose._rotations import rotation, rotation_angle
from jaxpose.evaluation import capture

FEW = 50
"""A consistency measured on fewer points than this, both sides together, is called thin."""


@eqx.filter_jit
def _at_motions(problem, config, ps):
    """Consistency and the counts of points it is measured on, at each p of `ps` (frame n);
    and the half-turn twins of `ps[0]`."""
    so3 = config.so3
    prev = _capture.previous_surface(problem, so3.points)
    curr, grid = _capture.current_surface(problem, so3.points)
    views = _capture.view_maps(problem)
    gate = jnp.asarray(config.fine.inlier, problem.d.dtype)

    def one(p):
        _, seen_prev, _, seen_curr = _capture.expected_in_view(problem, p, prev, curr, views)
        agree = _capture.consistency(problem, p, prev, curr, grid, gate, views)
        return agree, jnp.sum(seen_prev), jnp.sum(seen_curr)

    twins = _capture.symmetric_candidates(ps[0], prev, curr)
    return jax.vmap(one)(ps), twins


def _twin_errors(twins, equivalents) -> list[tuple[float, float]]:
    """Each twin's (rotation error °, translation error cm) from the equivalent nearest it."""
    out = []
    for x in np.asarray(twins):
        G = rotation(*x[:3])
        errs = [
            (float(np.degrees(rotation_angle(G, rotation(*e[:3])))), float(100 * np.linalg.norm(x[3:] - e[3:])))
            for e in np.asarray(equivalents[1:])
        ]
        out.append(min(errs))
    return out


def _benchmark_rows() -> dict:
    path = RESULTS / "capture_benchmark.json"
    if not path.exists():
        return {}
    rows = json.loads(path.read_text())["rows"]
    return {(r["sigma_cm"], r["pair"]): r for r in rows if r["method"] == "jaxpose" and r["target"] == "n5"}


def main(pairs: int = 3) -> None:
    cases, _ = capture.make_cases(pairs)
    config = jp.Config.capture()
    outcome = _benchmark_rows()
    rows = []
    for case in (c for c in cases if c.target == "n5"):
        sized = sized_config(case.prev, case.curr, config)
        problem = build_problem(case.prev, case.curr, sized)
        ps = jnp.stack(
            [
                displacement_from_motion(
                    problem.frame.origin,
                    problem.frame.axes,
                    jnp.asarray(R, problem.d.dtype),
                    jnp.asarray(t, problem.d.dtype),
                )
                for R, t in case.equivalents()
            ]
        )
        (agree, n_prev, n_curr), twins = _at_motions(problem, sized, ps)
        bench = outcome.get((case.sigma_cm, case.index), {})
        row = {
            "pair": case.index,
            "sigma_cm": case.sigma_cm,
            "bin": f"{case.bin[0]:g}–{case.bin[1]:g}",
            "motion_deg": case.motion_deg,
            "consistency": [float(x) for x in agree],
            "seen_prev": [int(x) for x in n_prev],
            "seen_curr": [int(x) for x in n_curr],
            "twin_errors": _twin_errors(twins, ps),
            "status": bench.get("status"),
            "ambiguous": bench.get("ambiguous"),
            "among": bench.get("among"),
        }
        rows.append(row)
        print(row, flush=True)
    write_json(
        "capture_symmetry.json", {"command": f"uv run python experiments/capture_symmetry.py {pairs}", "rows": rows}
    )
    (RESULTS / "capture_symmetry.md").write_text(markdown(rows))


def markdown(rows: list[dict]) -> str:
    head = (
        "| σ cm | pair | turn ° | consistency: truth / equivalents | points seen (prev + curr): truth / equivalents "
        "| twins from the truth: error °, cm | benchmark: status, ambiguous |\n|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        cons = " / ".join(f"{c:.2f}" for c in r["consistency"])
        seen = " / ".join(str(a + b) for a, b in zip(r["seen_prev"], r["seen_curr"], strict=True))
        twins = "; ".join(f"{d:.1f}, {cm:.1f}" for d, cm in r["twin_errors"])
        bench = f"{r['status']}, {r['ambiguous']}" if r["status"] is not None else "–"
        lines.append(
            f"| {r['sigma_cm']:g} | {r['pair']} | {r['motion_deg']:.0f} | {cons} | {seen} | {twins} | {bench} |"
        )
    counts = [
        (r["consistency"][1:], [a + b for a, b in zip(r["seen_prev"][1:], r["seen_curr"][1:], strict=True)])
        for r in rows
    ]
    thin = sum(n < FEW for _, ns in counts for n in ns)
    total = sum(len(ns) for _, ns in counts)
    tail = (
        f"\n{thin} of {total} equivalent motions are measured on fewer than {FEW} points "
        "(both sides together): a half turn that carries the seen side out of view leaves the "
        "views almost nothing to compare there.\n"
    )
    return head + "\n".join(lines) + "\n" + tail


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:2]))
