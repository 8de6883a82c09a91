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

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Complex, Float

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


class CorrelationTarget(eqx.Module):
    """The current cloud's side of [`correlation_translation`][], built once for every
    rotation tried (`correlation_target`): its centroid, the grid's corner and cell size
    (frame n, metres) and the grid's occupancy spectrum (`rfftn`)."""

    centroid: Float[Array, "3"]
    origin: Float[Array, "3"]
    cell: Float[Array, ""]
    spectrum: Complex[Array, "C C H"]


def valid_centroid(points: Float[Array, "3 N"], valid: Bool[Array, " N"]) -> Float[Array, "3"]:
    """The centroid of the valid points (metres, their frame); the origin for none."""
    return jnp.sum(jnp.where(valid[None], points, 0.0), axis=1) / jnp.maximum(jnp.sum(valid), 1)


def correlation_target(
    curr_points: Float[Array, "3 M"], curr_valid: Bool[Array, " M"], extent: Float[Array, ""]
) -> CorrelationTarget:
    """The [`CorrelationTarget`][] of the current points: a `CORRELATION_CELLS`³ grid spanning
    `CORRELATION_SPAN` × `extent` (metres), centred on their centroid."""
    n = CORRELATION_CELLS
    centroid = valid_centroid(curr_points, curr_valid)
    cell = CORRELATION_SPAN * jnp.maximum(extent, jnp.finfo(curr_points.dtype).eps) / n
    origin = centroid - cell * n / 2
    spectrum = jnp.fft.rfftn(_occupancy(curr_points, curr_valid, origin, cell))
    return CorrelationTarget(centroid, origin, cell, spectrum)


def correlation_translation(
    G: Float[Array, "3 3"], prev_points: Float[Array, "3 K"], prev_valid: Bool[Array, " K"], target: CorrelationTarget
) -> Float[Array, "3"]:
    """The translation x (frame n, metres) for which the previous points turned by G, a ↦ G a + x,
    overlap the current points of `target` most: the peak of the circular cross-correlation of
    their occupancy grids, after the turned previous centroid is put on the current one.
    Accurate to about a cell (`extent` / 32 by default): a start for a surface fit."""
    n = CORRELATION_CELLS
    c_prev = valid_centroid(prev_points, prev_valid)
    moved = G @ (prev_points - c_prev[:, None]) + target.centroid[:, None]
    a = _occupancy(moved, prev_valid, target.origin, target.cell)
    corr = jnp.fft.irfftn(jnp.conj(jnp.fft.rfftn(a)) * target.spectrum, s=a.shape)
    shift = jnp.stack(jnp.unravel_index(jnp.argmax(corr), a.shape)).astype(prev_points.dtype)
    shift = jnp.where(shift > n // 2, shift - n, shift)  # circular shifts as signed offsets
    return target.centroid - G @ c_prev + target.cell * shift


def cloud_extent(points: Float[Array, "3 K"], valid: Bool[Array, " K"]) -> Float[Array, ""]:
    """The largest extent of the valid points along an axis of their frame (metres); 0 for
    none."""
    high = jnp.max(jnp.where(valid[None], points, -jnp.inf), axis=1)
    low = jnp.min(jnp.where(valid[None], points, jnp.inf), axis=1)
    size = jnp.max(high - low)
    return jnp.where(jnp.isfinite(size), size, 0.0)


__all__ = ["CorrelationTarget", "cloud_extent", "correlation_target", "correlation_translation", "valid_centroid"]
