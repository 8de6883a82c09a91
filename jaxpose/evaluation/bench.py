"""Benchmarks: simulator, scoring throughput, estimate time and compile times (seconds).

Every timing is the median of `repeats` calls after a first call whose time is reported
separately as the compile time (it includes one run). Used by `jaxpose bench` and the
scripts in `experiments/`. No test asserts a time.
"""

from __future__ import annotations

import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp

from .._batch import score_batch
from .._config import Capacities, Config
from .._estimate import estimate, estimate_problem
from .._problem import Problem
from .._programs import cpu_model
from ..sim._camera import Camera
from ..sim._scenarios import paper_pair, paper_pose
from ..sim._simulate import simulate
from ..sim.targets import n5


def machine() -> dict:
    """What the numbers were measured on."""
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "device_kind": jax.devices()[0].device_kind,
        "x64": bool(jax.config.jax_enable_x64),
    }


def block(x):
    """Wait for every array in a pytree (JAX dispatch is asynchronous)."""
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


def run_bench(repeats: int = 10, candidates: int = 4096, batch: int = 8, presets=("default", "fast")) -> dict:
    """The headline numbers on the paper's N5 variant-2 pair (204 × 204 CamCube 2.0 frames).

    **Returns:** a dict with `simulate` (one frame), `score_hard`/`score_soft` (`candidates`
    random displacements within ±2°/±2 cm; poses/s), `estimate_public` (the public call
    `estimate(prev, curr, key=…)` with the default config, capacities sized from the clouds),
    and per preset `estimate` (one prepared problem) and `estimate_vmap` (a vmapped batch of
    `batch` pairs; pairs/s); each with its compile time.
    """
    camera, target = Camera.camcube2(), n5()
    R, t = paper_pose("previous")
    sim = jax.jit(lambda R, t: simulate(camera, target, R, t))
    out = {"simulate": time_call(sim, R, t, repeats=repeats)}
    pair = paper_pair("N5", "variant 2")
    key = jax.random.key(0)
    scale = jnp.array([0.035] * 3 + [0.02] * 3)
    ps = jax.random.uniform(key, (candidates, 6), minval=-1.0, maxval=1.0) * scale
    problem = Problem.build(pair.prev, pair.curr, Config(capacities=Capacities(max_points=5120)))
    for objective in ("hard", "soft"):
        fn = jax.jit(lambda ps, pb, o=objective: score_batch(ps, pb, o))
        res = time_call(fn, ps, problem, repeats=max(3, repeats // 2))
        out[f"score_{objective}"] = {**res, "candidates": candidates, "poses_per_s": candidates / res["median_s"]}
    public = time_call(lambda prev, curr: estimate(prev, curr, key=key), pair.prev, pair.curr, repeats=repeats)
    out["estimate_public"] = {**public, "ms_per_pair": 1e3 * public["median_s"]}
    for name in presets:
        preset = Config if name == "default" else getattr(Config, name)
        config = preset(capacities=Capacities(max_points=5120))
        problem = Problem.build(pair.prev, pair.curr, config)
        res = time_call(estimate_problem, problem, config, key, repeats=repeats)
        out[f"estimate_{name}"] = {**res, "ms_per_pair": 1e3 * res["median_s"]}
        problems = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *jnp.shape(x))), problem)
        keys = jax.random.split(key, batch)
        fn = jax.jit(jax.vmap(lambda pb, k, c=config: estimate_problem(pb, c, k)))
        res = time_call(fn, problems, keys, repeats=max(2, repeats // 4))
        out[f"estimate_{name}_vmap{batch}"] = {**res, "pairs_per_s": batch / res["median_s"]}
    return {"machine": machine(), "repeats": repeats, **out}


__all__ = ["block", "machine", "run_bench", "time_call"]
