"""What a view saw along each direction from the camera: a range map built from the cloud itself.

A time-of-flight camera sees, along each of its rays, the nearest surface. A cloud's
`RangeMap` bins its points by direction from the camera centre (cells of a tangent plane
about the cloud's mean direction) and keeps the nearest range in each cell. A point more
than a margin behind that range in its cell was hidden from the view by nearer surface
([`hidden`][]): the capture stage's consistency does not expect such a point to have been
seen (`jaxpose._capture.consistency`). A point more than a margin in front of it, or where
the view saw nothing, contradicts the view ([`in_front`][]): the fine stage's choice between
fits far apart counts such points (`jaxpose._estimate.free_space_conflict`).

No camera model is needed (no intrinsics, no pixel order): the cells are sized from the
points' own angular spacing, a few points a cell, so that a dropped pixel leaves no hole.
Only directions inside the cloud's angular bounding box are judged; outside it the view
says nothing (the target may have left the field of view there).

Frames: any frame, as long as the points and the camera centre are in the same one
(the capture stage uses the plane frame n); metres.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

RANGE_CELLS = 96
"""Cells of a range map along each tangent-plane axis at most (static)."""

POINTS_PER_CELL_SIDE = 2.5
"""A cell's side is at least this many times the mean spacing of the cloud's directions, so
that each cell inside the silhouette holds several points and random dropout leaves none
empty."""


class RangeMap(eqx.Module):
    """The nearest range (metres) seen in each direction cell of one view.

    - `camera`: the camera centre (3,); `basis`: rows e1, e2, a, with a the view's mean
      direction and e1, e2 the tangent-plane axes.
    - `lo`, `hi`: the view's bounding box in tangent-plane coordinates (u, v) = (d·e1,
      d·e2) / d·a of each direction d; `cell`: a cell's side in those coordinates.
    - `nearest`: (RANGE_CELLS, RANGE_CELLS) the least range in each cell, +inf where the view
      saw nothing.
    """

    camera: Float[Array, "3"]
    basis: Float[Array, "3 3"]
    lo: Float[Array, "2"]
    hi: Float[Array, "2"]
    cell: Float[Array, ""]
    nearest: Float[Array, "C C"]


def view_basis(points: Float[Array, "3 N"], valid: Bool[Array, " N"], camera: Float[Array, "3"]) -> Float[Array, "3 3"]:
    """Rows e1, e2, a: a the mean direction from `camera` to the valid points, e1 and e2
    completing a right-handed orthonormal basis."""
    d = points - camera[:, None]
    d = d / jnp.maximum(jnp.linalg.norm(d, axis=0, keepdims=True), jnp.finfo(points.dtype).tiny)
    a = jnp.sum(jnp.where(valid[None], d, 0.0), axis=1)
    a = a / jnp.maximum(jnp.linalg.norm(a), jnp.finfo(points.dtype).tiny)
    reference = jnp.eye(3, dtype=points.dtype)[jnp.argmin(jnp.abs(a))]
    e1 = jnp.cross(a, reference)
    e1 = e1 / jnp.linalg.norm(e1)
    return jnp.stack([e1, jnp.cross(a, e1), a])


def _directions(basis, camera, points) -> tuple[Float[Array, " N"], Float[Array, " N"], Float[Array, " N"]]:
    """Tangent-plane coordinates (u, v) and range of each point seen from `camera`. A point
    behind the camera (d·a ≤ 0) gets u = v = +inf (outside every map)."""
    d = basis @ (points - camera[:, None])
    ahead = d[2] > 0
    depth = jnp.where(ahead, d[2], 1.0)
    u = jnp.where(ahead, d[0] / depth, jnp.inf)
    v = jnp.where(ahead, d[1] / depth, jnp.inf)
    return u, v, jnp.linalg.norm(points - camera[:, None], axis=0)


def _cells(lo, cell, u, v):
    """The cell (i, j) of tangent-plane coordinates (u, v) in a map whose bounding box starts
    at `lo` with cells of side `cell`, clamped to the map (callers judge `inside` apart)."""
    i = jnp.clip(jnp.floor((u - lo[0]) / cell), 0, RANGE_CELLS - 1).astype(jnp.int32)
    j = jnp.clip(jnp.floor((v - lo[1]) / cell), 0, RANGE_CELLS - 1).astype(jnp.int32)
    return i, j


def range_map(
    points: Float[Array, "3 N"], valid: Bool[Array, " N"], camera: Float[Array, "3"], basis: Float[Array, "3 3"]
) -> RangeMap:
    """The [`RangeMap`][] of the valid `points` seen from `camera`, in the tangent plane of
    `basis` ([`view_basis`][])."""
    u, v, r = _directions(basis, camera, points)
    valid = valid & jnp.isfinite(u)
    lo = jnp.stack([jnp.min(jnp.where(valid, u, jnp.inf)), jnp.min(jnp.where(valid, v, jnp.inf))])
    hi = jnp.stack([jnp.max(jnp.where(valid, u, -jnp.inf)), jnp.max(jnp.where(valid, v, -jnp.inf))])
    count = jnp.maximum(jnp.sum(valid), 1)
    span = jnp.maximum(hi - lo, jnp.finfo(points.dtype).eps)
    spacing = jnp.sqrt(span[0] * span[1] / count)
    cell = jnp.maximum(jnp.max(span) / RANGE_CELLS, POINTS_PER_CELL_SIDE * spacing)
    i, j = _cells(lo, cell, u, v)
    nearest = jnp.full((RANGE_CELLS, RANGE_CELLS), jnp.inf, points.dtype)
    nearest = nearest.at[i, j].min(jnp.where(valid, r, jnp.inf))
    return RangeMap(camera, basis, lo, hi, cell, nearest)


def _seen_along(rmap: RangeMap, points: Float[Array, "3 S"]):
    """For each point: whether its direction lies inside the view's bounding box, its range
    from the camera, and the nearest range the view saw in its cell (+inf where it saw
    nothing), metres."""
    u, v, r = _directions(rmap.basis, rmap.camera, points)
    inside = (u >= rmap.lo[0]) & (u <= rmap.hi[0]) & (v >= rmap.lo[1]) & (v <= rmap.hi[1])
    i, j = _cells(rmap.lo, rmap.cell, u, v)
    return inside, r, rmap.nearest[i, j]


def hidden(rmap: RangeMap, points: Float[Array, "3 S"], margin) -> Bool[Array, " S"]:
    """Which `points` the view of `rmap` could not have seen: inside its bounding box of
    directions and more than `margin` metres behind the nearest range it saw in their cell."""
    inside, r, nearest = _seen_along(rmap, points)
    return inside & (r > nearest + margin)


def in_front(rmap: RangeMap, points: Float[Array, "3 S"], margin) -> Bool[Array, " S"]:
    """Which `points` the view of `rmap` would have seen had they been there: inside its
    bounding box of directions and more than `margin` metres in front of the nearest range it
    saw in their cell, or in a cell where it saw nothing. Such a point contradicts the view:
    the view saw through it to farther surface, or to empty space."""
    inside, r, nearest = _seen_along(rmap, points)
    return inside & (r < nearest - margin)


__all__ = ["RangeMap", "hidden", "in_front", "range_map", "view_basis"]
