"""Running one computation over a batch: candidate displacements against one problem
(`score_batch`), and any per-item function (`map_batch`).

On a CPU, `jax.vmap` of the objectives turns their scatters and gathers into batched
scatters, which XLA runs several times slower than the same work under `lax.map` (measured
in experiments/bench_scoring.py: 1.8k vs 30k hard poses/s for the paper's N5 pair), and a
vmapped loop runs until the batch's slowest item is done. So on a CPU a batch runs under
`lax.map`, over chunks of a few vmapped items. On an accelerator (GPU, TPU) each step of
a sequential map is a handful of small kernels that leave the device nearly idle, so there a
batch runs under `vmap`, whole or in large chunks (experiments/device_speed.py). Which of the
two is decided when the function is traced, from `jax.default_backend()`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import jax
from jaxtyping import Array, Float

from ._objective import hard_score, soft_score
from ._problem import Problem

OBJECTIVES = {"hard": hard_score, "soft": soft_score}

ACCELERATOR_CHUNK = 1024
"""Candidates `score_batch` vmaps together on an accelerator: the capture grid's batch of
about 8 200 in 8 steps, with each step's working set a few hundred megabytes at most."""


def on_accelerator() -> bool:
    """Whether JAX's default backend is an accelerator (anything but the CPU), read when a
    function that asks is traced."""
    return jax.default_backend() != "cpu"


def map_batch(fn: Callable, xs, cpu_chunk: int = 1):
    """`fn` over the leading axis of the pytree `xs`, stacked like `jax.vmap(fn)(xs)`: on a CPU
    under `lax.map` with `cpu_chunk` items vmapped at a time (module docstring), on an
    accelerator under `vmap` over all items. Pure and jittable; the same values either way
    up to floating-point rounding."""
    if on_accelerator():
        return jax.vmap(fn)(xs)
    return jax.lax.map(fn, xs, batch_size=cpu_chunk if cpu_chunk > 1 else None)


def score_batch(
    ps: Float[Array, "B 6"],
    problem: Problem,
    objective: Literal["hard", "soft"] = "hard",
    chunk: int = 16,
) -> Float[Array, " B"]:
    """f(p) for each row of `ps` (displacements in frame n, radians and metres).

    Pure and jittable; `objective` and `chunk` are static. Same values as
    `jax.vmap(hard_score, (0, None))(ps, problem)`, computed faster: `lax.map` over chunks of
    `chunk` vmapped candidates on a CPU, of `ACCELERATOR_CHUNK` on an accelerator.
    """
    fn = OBJECTIVES[objective]
    chunk = max(chunk, ACCELERATOR_CHUNK) if on_accelerator() else chunk
    return jax.lax.map(lambda p: fn(p, problem), ps, batch_size=min(chunk, ps.shape[0]))
