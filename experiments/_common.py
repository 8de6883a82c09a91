"""Helpers shared by the experiment scripts: the paper's setting, timing, machine info."""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxpose as jp
from jaxpose.scenarios import PAPER_T, paper_pose

RESULTS = Path(__file__).resolve().parent.parent / "results"
T_PAPER = jnp.asarray(PAPER_T)


def paper_rotation(pose: str):
    """Target attitude of a paper pose: "previous", "variant 1" or "variant 2"."""
    return paper_pose(pose)[0]


def paper_cloud(shape: str, pose: str, camera=None) -> jp.Cloud:
    camera = jp.Camera.camcube2() if camera is None else camera
    return jp.simulate(camera, getattr(jp.targets, shape)(), paper_rotation(pose), T_PAPER)


def machine() -> dict:
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.jax_enable_x64),
    }


def block(x):
    return jax.tree.map(lambda a: a.block_until_ready() if hasattr(a, "block_until_ready") else a, x)


def time_call(fn, *args, repeats: int = 20) -> dict:
    """Compile time (first call) and the median of `repeats` later calls, in seconds."""
    t0 = time.perf_counter()
    block(fn(*args))
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        block(fn(*args))
        times.append(time.perf_counter() - t0)
    return {"compile_s": compile_s, "median_s": statistics.median(times), "repeats": repeats}


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
