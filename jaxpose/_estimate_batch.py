"""`estimate_batch`: many pairs in one compiled call, one pair after another.

`jax.vmap(estimate)` runs a batch in lockstep: a `lax.cond` whose condition differs between
pairs runs both branches for every pair (the turned fine runs, the noise-free polish), and a
loop runs until the batch's slowest pair is done. On a CPU that costs more than it saves
(docs/performance.md, "Batches"). `estimate_batch` sizes one config from all the pairs,
then runs them under `lax.map` in one compiled program per capacity bucket, so each pair
takes only its own branches and loop counts and the batch pays one dispatch. `chunk` > 1
vmaps that many pairs at a time inside the map. On an accelerator the default vmaps the
whole batch: there a sequential map leaves the device nearly idle, and lockstep costs less
than it saves (on one H200, 64 N5 pairs ran 18 pairs/s one after another and 180 pairs/s
vmapped; experiments/device_speed.py, docs/performance.md).
"""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import Array, Key

from ._batch import on_accelerator
from ._cloud import Cloud, _check_arrays
from ._config import Config
from ._estimate import Estimate, _estimate_pair
from ._problem import check_reach, raise_for_codes, run_growing, sized_stacked_config
from ._programs import BoundedJit


def _keys(key: Key[Array, ""] | Key[Array, " B"], count: int) -> Key[Array, " B"]:
    """One key per pair: `key` split `count` ways when it is a single key, else as given."""
    if key.shape == ():
        return jax.random.split(key, count)
    if key.shape != (count,):
        raise ValueError(f"key: one key or {count} keys (one per pair), got shape {key.shape}.")
    return key


def default_chunk(count: int) -> int:
    """`estimate_batch`'s pairs per vmapped step when none is given: 1 on a CPU (each pair
    takes only its own branches and loop counts), all `count` on an accelerator (module
    docstring)."""
    return count if on_accelerator() else 1


def _map_pairs(prev: Cloud, curr: Cloud, config: Config, keys: Key[Array, " B"], chunk: int):
    def one(args):
        p, c, k = args
        # The single pair's program, nested (a vmapped build inlined into the caller's program
        # crashed XLA:CPU's compiler, see `BoundedJit`).
        return _estimate_pair(Cloud(*p), Cloud(*c), config, k)

    xs = ((prev.points, prev.valid), (curr.points, curr.valid), keys)
    return jax.lax.map(one, xs, batch_size=chunk if chunk > 1 else None)


_estimate_pairs = BoundedJit(_map_pairs)
"""One compiled program per capacity bucket, batch size and `chunk` (see `jaxpose._programs`)."""


def estimate_batch(
    prev: Cloud,
    curr: Cloud,
    config: Config | None = None,
    *,
    key: Key[Array, ""] | Key[Array, " B"],
    chunk: int | None = None,
) -> Estimate:
    """[`estimate`][jaxpose.estimate] for B pairs in one compiled call.

    **Arguments:**

    - `prev`, `curr`: [`jaxpose.Cloud`][]s with a leading batch axis (points `(B, N, 3)` and
      `(B, M, 3)`, camera frame, metres; `valid` `(B, N)` and `(B, M)`): pair i is
      `(prev[i], curr[i])`.
    - `config`: a [`jaxpose.Config`][] (default `Config()`); capacities left at None are
      sized from all the pairs, as `estimate` sizes them from one.
    - `key`: one PRNG key, split into one per pair, or B keys. Pair i with key k gives what
      `estimate(prev[i], curr[i], config, key=k)` gives with the batch's capacities.
    - `chunk`: pairs run together under `vmap` inside the sequential map. None (the
      default): 1 on a CPU, where that is fastest, and the whole batch on an accelerator
      (`jaxpose._estimate_batch.default_chunk`).

    **Returns:**

    An [`Estimate`][jaxpose.Estimate] whose fields have a leading axis B. Python boundary
    only (under `jax.jit`, call `estimate` under `jax.lax.map` or `jax.vmap`). A pair that
    `estimate` would refuse raises a ValueError that names the pair's index.
    """
    config = Config() if config is None else config
    if prev.points.ndim != 3 or curr.points.ndim != 3 or prev.points.shape[0] != curr.points.shape[0]:
        raise ValueError(
            "estimate_batch: prev and curr need a leading batch axis of the same length "
            f"(points (B, N, 3)), got {prev.points.shape} and {curr.points.shape}."
        )
    count = prev.points.shape[0]
    chunk = default_chunk(count) if chunk is None else chunk
    if chunk < 1:
        raise ValueError(f"estimate_batch: chunk must be ≥ 1, got {chunk}.")
    # Checked on host copies, pair by pair: no device op or transfer per pair.
    host = [(side, np.asarray(c.points), np.asarray(c.valid)) for side, c in (("previous", prev), ("current", curr))]
    for i in range(count):
        for side, points, valid in host:
            _check_arrays(points[i], valid[i], f"pair {i}: {side} cloud")
            check_reach(f"pair {i}: {side} cloud", points[i], valid[i], config)
    keys = _keys(key, count)
    prev, curr = prev.floating(), curr.floating()
    config = sized_stacked_config(prev, curr, config)
    est, status, frame_status = run_growing(lambda grown: _estimate_pairs(prev, curr, grown, keys, chunk), config)
    for i, (code, frame_code) in enumerate(zip(np.asarray(status), np.asarray(frame_status), strict=True)):
        try:
            raise_for_codes(int(code), int(frame_code))
        except ValueError as err:
            raise ValueError(f"pair {i}: {err}") from None
    return est


__all__ = ["estimate_batch"]
