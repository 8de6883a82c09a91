"""The translation of a given rotation, found without a start: a translation search over a
whole grid at once, by one FFT cross-correlation of the two clouds' occupancy grids (the
capture stage's hypothesis starts, `jaxpose._capture`).

On the capture benchmark's 60 asymmetric pairs, at the true rotation, it lay a median 4.3 cm
(at most 15.8 cm) from the true translation, where `_capture.settled_translation`, which lines
up the centroids of the surface each view should see of the other, lay 8.6 cm (at most 71 cm)
off (`experiments/capture_cues.py`).

Frames: everything is in the previous cloud's plane frame n (metres, radians).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

CORRELATION_CELLS = 64
"""Cells along each axis of the occupancy grids of [`correlation_translation`][]."""

CORRELATION_SPAN = 2.0
"""The grids' span, in units of the clouds' largest extent: the moved previous cloud may lie up
to about one extent from the current one before the circular correlation wraps."""


def _occupancy(points: Float[Array, "3 N"], valid: Bool[Array, " N"], origin, cell) -> Float[Array, "C C C"]:
    """Which cells of a `CORRELATION_CELLS`³ grid (corner `origin`, cell size `cell`, metres)
    hold a valid point (1) or none (0)."""
    n = CORRELATION_CELLS
    idx = jnp.floor((points - origin[:, None]) / cell).astype(jnp.int32)
    inside = valid & jnp.all((idx >= 0) & (idx < n), axis=0)
    flat = jnp.where(inside, (idx[0] * n + idx[1]) * n + idx[2], n**3)
    counts = jnp.zeros(n**3 + 1, points.dtype).at[flat].add(1.0)[:-1]
    return jnp.minimum(counts, 1.0).reshape(n, n, n)


def correlation_translation(
    G: Float[Array, "3 3"],
    prev_points: Float[Array, "3 K"],
    prev_valid: Bool[Array, " K"],
    curr_points: Float[Array, "3 M"],
    curr_valid: Bool[Array, " M"],
    extent: Float[Array, ""],
) -> Float[Array, "3"]:
    """The translation x (frame n, metres) for which the previous points turned by G, a ↦ G a + x,
    overlap the current points most: the peak of the circular cross-correlation of their
    occupancy grids (`CORRELATION_CELLS`³ cells spanning `CORRELATION_SPAN` × `extent`,
    centred on the current centroid), after the turned previous centroid is put on the current
    one. Accurate to about a cell (`extent` / 32 by default): a start for a surface fit."""
    dtype = prev_points.dtype
    n = CORRELATION_CELLS
    count = lambda valid: jnp.maximum(jnp.sum(valid), 1)  # noqa: E731
    c_prev = jnp.sum(jnp.where(prev_valid[None], prev_points, 0.0), axis=1) / count(prev_valid)
    c_curr = jnp.sum(jnp.where(curr_valid[None], curr_points, 0.0), axis=1) / count(curr_valid)
    cell = CORRELATION_SPAN * jnp.maximum(extent, jnp.finfo(dtype).eps) / n
    origin = c_curr - cell * n / 2
    moved = G @ (prev_points - c_prev[:, None]) + c_curr[:, None]
    a = _occupancy(moved, prev_valid, origin, cell)
    b = _occupancy(curr_points, curr_valid, origin, cell)
    corr = jnp.fft.irfftn(jnp.conj(jnp.fft.rfftn(a)) * jnp.fft.rfftn(b), s=a.shape)
    shift = jnp.stack(jnp.unravel_index(jnp.argmax(corr), a.shape)).astype(dtype)
    shift = jnp.where(shift > n // 2, shift - n, shift)  # circular shifts as signed offsets
    return c_curr - G @ c_prev + cell * shift


def cloud_extent(points: Float[Array, "3 K"], valid: Bool[Array, " K"]) -> Float[Array, ""]:
    """The largest extent of the valid points along an axis of their frame (metres); 0 for
    none."""
    high = jnp.max(jnp.where(valid[None], points, -jnp.inf), axis=1)
    low = jnp.min(jnp.where(valid[None], points, jnp.inf), axis=1)
    size = jnp.max(high - low)
    return jnp.where(jnp.isfinite(size), size, 0.0)


__all__ = ["cloud_extent", "correlation_translation"]
