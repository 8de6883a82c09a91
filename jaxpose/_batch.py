"""Scoring many candidate displacements against one problem.

`jax.vmap` of the objectives turns their scatters and gathers into batched scatters, which
XLA on CPU runs several times slower than the same work under `lax.map` (measured in
experiments/bench_scoring.py: 1.8k vs 30k hard poses/s for the paper's N5 pair). So a batch
is scored by `lax.map` over chunks of `chunk` candidates, each chunk vmapped.
"""

from __future__ import annotations

from typing import Literal

import jax
from jaxtyping import Array, Float

from ._objective import hard_score, soft_score
from ._problem import Problem

OBJECTIVES = {"hard": hard_score, "soft": soft_score}


def score_batch(
    ps: Float[Array, "B 6"],
    problem: Problem,
    objective: Literal["hard", "soft"] = "hard",
    chunk: int = 16,
) -> Float[Array, " B"]:
    """f(p) for each row of `ps` (displacements in frame n, radians and metres).

    Pure and jittable; `objective` and `chunk` are static. Same values as
    `jax.vmap(hard_score, (0, None))(ps, problem)`, computed faster on CPU.
    """
    fn = OBJECTIVES[objective]
    return jax.lax.map(lambda p: fn(p, problem), ps, batch_size=min(chunk, ps.shape[0]))
