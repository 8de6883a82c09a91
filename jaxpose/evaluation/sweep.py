"""Monte Carlo sweeps: error and success rate of `estimate` against one condition at a time.

Base case: N5 at 5.5 m in the paper's previous attitude, rotated by 10° about a random axis
through O_t, noise-free, no dropout. Each sweep varies one condition over the values of
[`AXES`][] and keeps the others at the base; trial j of value v uses key (seed, axis, v, j),
so a sweep is reproducible and a value's trials do not depend on the value list. The trials
of one value run as one batch through `jaxpose._scale.estimate_sharded`, so a sweep spreads over every JAX device
(and every host after `jax.distributed.initialize()`).

A trial is *found* when the rotation error is < 1°; *success* when it is also reported as a
success; a *false success* is reported as a success but ≥ 1° off.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from .._config import Config
from .._estimate import SUCCESS
from .._problem import Problem, sized_batch_config
from .._scale import estimate_sharded
from ..sim._camera import Camera
from ..sim._scenarios import paper_pose, rotated_pair
from .comparison import FOUND_DEG, outcome_counts, pair_errors

AXES = {
    "rotation": ("rotation angle, °", (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 30.0, 45.0, 60.0)),
    "noise": ("range noise σ, cm", (0.0, 0.25, 0.5, 1.0, 1.5, 2.0)),
    "distance": ("distance to O_t, m", (1.0, 2.0, 3.0, 4.0, 5.5, 7.0)),
    "dropout": ("pixel dropout probability", (0.0, 0.1, 0.2, 0.4, 0.6)),
}
"""Sweep name → (axis label, values) at the report boundary (degrees, centimetres, metres)."""
BASE = {"rotation": 10.0, "noise": 0.0, "distance": 5.5, "dropout": 0.0}


def _pair(axis: str, value: float, key):
    cond = {**BASE, axis: value}
    camera = Camera.camcube2(noise_sigma=cond["noise"] / 100, dropout=cond["dropout"])
    return rotated_pair(
        key,
        math.radians(cond["rotation"]),
        attitude=paper_pose("previous")[0],
        distance=cond["distance"],
        camera=camera,
    )


def sweep_value(axis: str, value: float, trials: int, config: Config, seed: int = 0) -> dict:
    """`trials` random pairs at one condition → found/success rates and error statistics."""
    # Keys from the axis and the value itself (in thousandths), not its place in the list.
    base = jax.random.fold_in(jax.random.fold_in(jax.random.key(seed), list(AXES).index(axis)), round(1000 * value))
    pairs = [_pair(axis, value, jax.random.fold_in(base, j)) for j in range(trials)]
    # One program for the batch: capacities sized from all its pairs.
    config = sized_batch_config([(p.prev, p.curr) for p in pairs], config)
    usable, problems, unusable = [], [], []
    for p in pairs:
        try:
            problems.append(Problem.build(p.prev, p.curr, config))
            usable.append(p)
        except ValueError as err:
            unusable.append(str(err))
    row = {"value": value, "trials": trials, "unusable": len(unusable), "unusable_reasons": sorted(set(unusable))}
    if not usable:
        return {**row, "found": 0, "success": 0, "false_success": 0}
    batch = jax.tree.map(lambda *xs: np.stack(xs), *problems)
    search_keys = jax.random.split(jax.random.fold_in(base, 10**6), len(usable))
    est = estimate_sharded(batch, config, search_keys)
    errors = [pair_errors(p, est.rotation[i], est.translation[i], problems[i].frame) for i, p in enumerate(usable)]
    rot = np.array([e["rotation_error_deg"] for e in errors])
    ok = np.asarray(est.status) == SUCCESS
    return {
        **row,
        **outcome_counts(rot < FOUND_DEG, ok),
        "median_rotation_error_deg": float(np.median(rot)),
        "median_translation_error_cm": statistics.median(e["translation_error_cm"] for e in errors),
        "rotation_errors_deg": rot.round(4).tolist(),
    }


def run_sweep(
    axes: list[str], trials: int, config: Config, seed: int = 0, progress: Callable[[], None] | None = None
) -> dict[str, list[dict]]:
    """[`sweep_value`][] over every value of each named axis."""
    out = {}
    for axis in axes:
        out[axis] = []
        for value in AXES[axis][1]:
            out[axis].append(sweep_value(axis, value, trials, config, seed))
            if progress is not None:
                progress()
    return out


def plot_sweep(results: dict[str, list[dict]], path: Path, title: str = "") -> None:
    """One panel per axis: found and success rates (%, left) and median rotation error (°, right, log)."""
    import matplotlib.pyplot as plt

    from .figures import save_figure  # also selects the Agg backend

    fig, axs = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.6), squeeze=False)
    for ax, (axis, rows) in zip(axs[0], results.items(), strict=True):
        x = [r["value"] for r in rows]
        n = [max(r["trials"], 1) for r in rows]
        ax.plot(x, [100 * r["found"] / k for r, k in zip(rows, n, strict=True)], "o-", label="found (< 1°)")
        ax.plot(x, [100 * r["success"] / k for r, k in zip(rows, n, strict=True)], "s--", label="success")
        ax.plot(x, [100 * r["false_success"] / k for r, k in zip(rows, n, strict=True)], "x:", label="false success")
        ax.set(
            xlabel=AXES[axis][0], ylabel="% of trials", ylim=(-5, 105), xscale="log" if axis == "rotation" else "linear"
        )
        err = ax.twinx()
        err.semilogy(x, [r.get("median_rotation_error_deg", np.nan) for r in rows], "k^-", ms=4, lw=0.8)
        err.set_ylabel("median rotation error, °")
        ax.legend(fontsize=7, loc="center left")
    save_figure(fig, path, dpi=110, title=title)


__all__ = ["AXES", "BASE", "plot_sweep", "run_sweep", "sweep_value"]
