"""jaxpose and peer registration methods on the same cloud pairs, measured in one run.

Errors against the truth of each `jaxpose.sim.Pair`:

- `rotation_error_deg`: angle of R_est R_trueᵀ (camera frame c), degrees;
- `angle_error_deg`, `translation_error_cm`: the largest absolute error of (θ, φ, ψ) and of
  (x, y, z) of the displacement p in the previous cloud's plane frame n (the paper's and
  issue 4's measure), degrees and centimetres;
- `seconds`: wall time of one pair (jaxpose: after its compilation, which is reported
  separately; peers: including their preprocessing).

A pair counts as found when its rotation error is < 1°. jaxpose also reports its status, so
a *false success* (status success but ≥ 1° off) is counted.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable

import jax
import numpy as np

from .._config import Config
from .._estimate import STATUS_NAME, estimate_problem
from .._frame import plane_frame
from .._poses import displacement_from_motion
from .._problem import Problem, sized_batch_config
from .._rotations import rotation_angle
from ..sim._scenarios import Pair

FOUND_DEG = 1.0
"""A result within this rotation error (degrees) counts as found."""


def pair_errors(pair: Pair, R, t, frame=None) -> dict:
    """Errors of an estimated camera-frame motion (R, t) for `pair` (see the module docstring)."""
    frame = plane_frame(pair.prev) if frame is None else frame
    R_true, t_true = pair.motion
    p_true = np.asarray(displacement_from_motion(frame.origin, frame.axes, R_true, t_true), float)
    p_est = np.asarray(displacement_from_motion(frame.origin, frame.axes, np.asarray(R), np.asarray(t)), float)
    err = np.abs(p_est - p_true)
    return {
        "rotation_error_deg": math.degrees(float(rotation_angle(np.asarray(R), R_true))),
        "angle_error_deg": float(np.degrees(err[:3]).max()),
        "translation_error_cm": float(100 * err[3:].max()),
    }


def run_jaxpose(
    pairs: list[Pair], config: Config, seed: int = 0, progress: Callable[[], None] | None = None, repeats: int = 1
):
    """`estimate` on each pair (key = (seed, i)); returns the rows and the compile time (s).
    A pair's time is the median of `repeats` runs. Capacities the config leaves at None are
    sized once from all the pairs, so that one compiled program serves them all and no timed
    call compiles."""
    config = sized_batch_config([(pair.prev, pair.curr) for pair in pairs], config)
    rows, compile_s = [], None
    for i, pair in enumerate(pairs):
        key = jax.random.fold_in(jax.random.key(seed), i)
        try:
            problem = Problem.build(pair.prev, pair.curr, config)
        except ValueError as err:
            rows.append({"pair": pair.label, "method": "jaxpose", "unusable": str(err)})
            continue
        if compile_s is None:
            t0 = time.perf_counter()
            jax.block_until_ready(estimate_problem(problem, config, key))
            compile_s = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            est = jax.block_until_ready(estimate_problem(problem, config, key))
            times.append(time.perf_counter() - t0)
        seconds = statistics.median(times)
        errors = pair_errors(pair, est.rotation, est.translation, problem.frame)
        rows.append(
            {
                "pair": pair.label,
                "method": "jaxpose",
                **errors,
                "seconds": seconds,
                "status": STATUS_NAME[int(est.status)],
                "hard": float(est.hard),
                "restarts": int(est.search.restarts),
                "inliers": float(est.fine.inliers) if est.fine is not None else math.nan,
                "fine_rms_mm": 1000 * float(est.fine.rms) if est.fine is not None else math.nan,
            }
        )
        if progress is not None:
            progress()
    return rows, compile_s


def run_peer(name: str, align, pairs: list[Pair], progress: Callable[[], None] | None = None) -> list[dict]:
    """One peer aligner on each pair (previous → current, starting from the identity)."""
    rows = []
    for pair in pairs:
        prev, curr = np.asarray(pair.prev.compact(), float), np.asarray(pair.curr.compact(), float)
        t0 = time.perf_counter()
        R, t = align(prev, curr)
        seconds = time.perf_counter() - t0
        rows.append({"pair": pair.label, "method": name, **pair_errors(pair, R, t), "seconds": seconds})
        if progress is not None:
            progress()
    return rows


def outcome_counts(found, success) -> dict[str, int]:
    """Counts over pairs from per-pair flags: `found` (the answer lies within the found
    threshold, e.g. < 1°) and `success` (jaxpose reported status success): how many were
    found, how many were found and reported success, and how many were false successes
    (reported success but not found)."""
    found, success = np.asarray(found, bool), np.asarray(success, bool)
    return {
        "found": int(found.sum()),
        "success": int((found & success).sum()),
        "false_success": int((~found & success).sum()),
    }


def summarise(rows: list[dict], angles_deg: dict[str, float] | None = None, bins=None) -> dict:
    """Per method: pairs, found (< 1°), false successes (jaxpose), median and max errors,
    median time; with `angles_deg` (pair → rotation magnitude) and `bins`, found per bin."""
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method and "unusable" not in r]
        found = [r for r in mine if r["rotation_error_deg"] < FOUND_DEG]
        summary = {
            "pairs": len(mine),
            "unusable": sum(1 for r in rows if r["method"] == method and "unusable" in r),
            "found": len(found),
            "median_rotation_error_deg": statistics.median(r["rotation_error_deg"] for r in mine),
            "max_angle_error_deg": max(r["angle_error_deg"] for r in mine),
            "max_translation_error_cm": max(r["translation_error_cm"] for r in mine),
            "median_seconds": statistics.median(r["seconds"] for r in mine),
        }
        if "status" in mine[0]:
            counts = outcome_counts(
                [r["rotation_error_deg"] < FOUND_DEG for r in mine], [r["status"] == "success" for r in mine]
            )
            summary["false_success"], summary["success"] = counts["false_success"], counts["success"]
        if angles_deg and bins:
            summary["found_by_angle"] = {
                f"{lo:g}-{hi:g} deg": (
                    sum(1 for r in found if lo <= angles_deg[r["pair"]] < hi),
                    sum(1 for r in mine if lo <= angles_deg[r["pair"]] < hi),
                )
                for lo, hi in bins
            }
        out[method] = summary
    return out


def markdown_summary(summary: dict, compile_s: float | None) -> str:
    """One row per method: found, false successes, errors and median time per pair."""
    lines = [
        "| method | found (< 1°) | false success | median rot. error, ° | max abs Δ angle, ° "
        "| max abs Δ x,y,z, cm | median time per pair |",
        "|---|---|---|---|---|---|---|",
    ]
    for method, s in summary.items():
        bins = s.get("found_by_angle")
        by = f" ({', '.join(f'{k}: {a}/{b}' for k, a, b in ((k, *v) for k, v in bins.items()))})" if bins else ""
        lines.append(
            f"| {method} | {s['found']}/{s['pairs']}{by} | {s.get('false_success', '–')} | "
            f"{s['median_rotation_error_deg']:.4f} | {s['max_angle_error_deg']:.4f} | "
            f"{s['max_translation_error_cm']:.4f} | {s['median_seconds'] * 1e3:.1f} ms |"
        )
    if compile_s is not None:
        lines += ["", f"jaxpose compile (first call, not in the times above): {compile_s:.1f} s."]
    return "\n".join(lines)


__all__ = ["FOUND_DEG", "markdown_summary", "pair_errors", "run_jaxpose", "run_peer", "summarise"]
