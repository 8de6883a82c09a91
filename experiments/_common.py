"""Helpers shared by the experiment scripts: the paper's setting, timing, machine info."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxpose as jp
from jaxpose.evaluation.bench import block, machine, time_call  # noqa: F401  (re-exported for the scripts)
from jaxpose.sim import PAPER_T, paper_pose

RESULTS = Path(__file__).resolve().parent.parent / "results"
T_PAPER = jnp.asarray(PAPER_T)


NEAR_PLANE_FINE = jp.FineStage(prev_slab=3.0, curr_slab=2.0, points=2048, anchor="point", guard=1.0, tol=1e-6)
"""The fine stage near the cutting planes: 2048 points a side, slabs of 3d / 2d, planes
through the points, no guard, tolerance 1e-6."""


def full_search(points: int | None = None, **changes) -> jp.Config:
    """The search on the full patterns (CMA-ES 32 × 40, up to 100 BFGS steps, as in
    `Config.tracking()`) with `NEAR_PLANE_FINE`: the setting several committed experiments
    measured. `points`: a fixed current-point capacity (one compile for every pair).
    `changes`: sections to replace."""
    if points is not None:
        changes.setdefault("capacities", jp.Capacities(max_points=points))
    return jp.Config.tracking(**{"fine": NEAR_PLANE_FINE, **changes})


def paper_rotation(pose: str):
    """Target attitude of a paper pose: "previous", "variant 1" or "variant 2"."""
    return paper_pose(pose)[0]


def paper_cloud(shape: str, pose: str, camera=None) -> jp.Cloud:
    camera = jp.Camera.camcube2() if camera is None else camera
    return jp.simulate(camera, getattr(jp.targets, shape)(), paper_rotation(pose), T_PAPER)


def run_child(code: str, *args: str) -> dict:
    """Run `code` in a fresh Python process (own JAX settings, own peak memory) and return
    the JSON object on the last line it prints."""
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def write_json(name: str, payload: dict) -> Path:
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / name
    path.write_text(json.dumps({"machine": machine(), **payload}, indent=2))
    print(f"wrote {path}")
    return path


def stacked(clouds: list[jp.Cloud]) -> jp.Cloud:
    """Clouds of one camera (one row count) stacked along a new leading axis, for
    `jp.estimate_batch`."""
    return jax.tree.map(lambda *x: jnp.stack(x), *clouds)
