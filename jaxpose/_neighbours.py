"""Even subsets of masked points, and neighbour search on a sorted voxel grid (static shapes, jittable, vmappable).

The points are binned into cubic voxels of edge h; their voxel keys (x, y, z bits, z least
significant) are sorted once. A query reads the 27 voxels around its own as 9 columns
along z, each three voxels consecutive in key order: one `searchsorted` per column, then at
most `slots` points of it, so a query costs 9·`slots` distances instead of one per point.
The sorted points are kept as rows (x, y, z) (`VoxelGrid.rows`), so that a column's window
is one contiguous block of memory.
Every point within h of the query lies in those voxels, so the search is exact within h as
long as no column holds more than `slots` points (h is sized from [`voxel_spacing`][]);
farther points may be missed, which the fine stage treats as no match.

Points are structure of arrays, `(3, N)`, metres, any frame.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

BITS = 10
"""Bits of each voxel coordinate in a key: a grid spans 1024 voxels per axis."""

EMPTY = jnp.iinfo(jnp.int32).max
"""The key of an invalid point: sorts last, matches no voxel."""


class VoxelGrid(eqx.Module):
    """Points binned in voxels: `keys` sorted, `order` the point index of each sorted key,
    `rows` `(N, 3)` the points in that sorted order, one row (x, y, z) each (so that a column
    of voxels is one contiguous block), `lo` the grid's corner (metres) and `size` the voxel
    edge h (metres)."""

    keys: Int[Array, " N"]
    order: Int[Array, " N"]
    rows: Float[Array, "N 3"]
    lo: Float[Array, "3"]
    size: Float[Array, ""]


def _coords(x: Float[Array, "3 S"], lo, size) -> Int[Array, "3 S"]:
    return jnp.floor((x - lo[:, None]) / size).astype(jnp.int32)


def _key(c: Int[Array, "3 ..."]) -> Int[Array, "..."]:
    inside = jnp.all((c >= 0) & (c < 2**BITS), axis=0)
    return jnp.where(inside, (c[0] << (2 * BITS)) | (c[1] << BITS) | c[2], EMPTY - 1)


def voxel_grid(points: Float[Array, "3 N"], valid: Bool[Array, " N"], size) -> VoxelGrid:
    """Bin the valid points in voxels of edge `size` (metres). The grid's corner is one voxel
    below the points' smallest coordinates; points beyond 1022 voxels from it are left out."""
    size = jnp.asarray(size, points.dtype)
    lo = jnp.min(jnp.where(valid[None], points, jnp.inf), axis=1) - size
    lo = jnp.where(jnp.isfinite(lo), lo, 0.0)
    keys = jnp.where(valid, _key(_coords(points, lo, size)), EMPTY)
    order = jnp.argsort(keys)
    return VoxelGrid(keys[order], order.astype(jnp.int32), points[:, order].T, lo, size)


class Candidates(NamedTuple):
    """The points read for each query, `(S, 9·slots)` each: their position in the grid's
    sorted order, whether they are real (in one of the query's 27 voxels), and their squared
    distance to the query (metres², inf where not real)."""

    sorted_index: Int[Array, "S C"]
    real: Bool[Array, "S C"]
    distance2: Float[Array, "S C"]


class Windows(NamedTuple):
    """Where each query's 9 columns of voxels lie in the grid's sorted order, `(S, 9)` each:
    the keys of the column's lowest and highest voxels (`first`, `last`; EMPTY and -1 for a
    column outside the grid) and the sorted position its window of `slots` points starts at."""

    first: Int[Array, "S 9"]
    last: Int[Array, "S 9"]
    start: Int[Array, "S 9"]


def windows(grid: VoxelGrid, queries: Float[Array, "3 S"], slots: int) -> Windows:
    """The windows of the 3 × 3 columns of voxels (x ± 1, y ± 1) around each query, each
    column's three voxels along z consecutive in key order (one `searchsorted` each)."""
    c = _coords(queries, grid.lo, grid.size)
    top = 2**BITS - 1
    columns = jnp.asarray([(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)], jnp.int32).T  # (2, 9)
    xy = c[:2, :, None] + columns[:, None, :]  # (2, S, 9)
    z = jnp.broadcast_to(c[2][:, None], xy.shape[1:])
    inside = jnp.all((xy >= 0) & (xy <= top), axis=0) & (z >= -1) & (z <= top + 1)
    column = (xy[0] << (2 * BITS)) | (xy[1] << BITS)
    first = jnp.where(inside, column | jnp.clip(z - 1, 0, top), EMPTY)
    last = jnp.where(inside, column | jnp.clip(z + 1, 0, top), -1)
    n = grid.keys.shape[0]
    # The barriers keep XLA:CPU from fusing the key arithmetic into the search loop and the
    # search into the window reads, which made the lookup several times slower.
    first, last = jax.lax.optimization_barrier((first, last))
    start = jnp.searchsorted(grid.keys, first.ravel(), method="scan_unrolled")
    # A window that would run past the end is moved back to end there: it still holds every
    # point from `start` on, and the key test of `candidates` drops the ones before it.
    start = jax.lax.optimization_barrier(jnp.minimum(start, n - min(slots, n)).astype(jnp.int32))
    return Windows(first, last, start.reshape(first.shape))


def candidates(grid: VoxelGrid, queries: Float[Array, "3 S"], slots: int, found: Windows | None = None) -> Candidates:
    """The points in the 27 voxels around each query ([`windows`][]), each column read as one
    contiguous window of `slots` sorted points (a slice of rows, not a gather per point: about 3×
    faster on the 2-core CPU than gathering each candidate through `order`, and rows (x, y, z)
    read faster than the three coordinates' windows of a `(3, N)` array). `found`: the
    queries' windows where the caller has them already."""
    first, last, start = windows(grid, queries, slots) if found is None else found
    slots = min(slots, grid.keys.shape[0])
    S = queries.shape[1]
    rows = jax.vmap(lambda i: jax.lax.dynamic_slice(grid.rows, (i, jnp.int32(0)), (slots, 3)))(start.ravel())
    rows = rows.reshape(S, 9, slots, 3)  # (S, column, slot, x y z)
    keys = jax.vmap(lambda i: jax.lax.dynamic_slice(grid.keys, (i,), (slots,)))(start.ravel()).reshape(S, 9, slots)
    real = (keys >= first[..., None]) & (keys <= last[..., None])
    d2 = sum((rows[..., k] - queries[k][:, None, None]) ** 2 for k in range(3))
    sorted_index = start[..., None] + jnp.arange(slots)[None, None]
    return Candidates(sorted_index.reshape(S, -1), real.reshape(S, -1), jnp.where(real, d2, jnp.inf).reshape(S, -1))


def exact_radius(grid: VoxelGrid, queries: Float[Array, "3 S"], found: Windows, slots: int) -> Float[Array, " S"]:
    """The radius (metres) around each query within which [`candidates`][] reads every grid
    point: the distance from the query to the faces of its 27 voxels (between h and 1.5 h),
    or 0 where one of its columns holds more than `slots` points, some of which were not
    read (the key just past that column's window still belongs to the column). `found`: the
    queries' [`windows`][]."""
    _, last, start = found
    n = grid.keys.shape[0]
    after = start + min(slots, n)
    overflow = (after < n) & (grid.keys[jnp.minimum(after, n - 1)] <= last)
    offset = (queries - grid.lo[:, None]) / grid.size  # in voxels; the box is [c − 1, c + 2)
    inner = offset - jnp.floor(offset)
    to_faces = grid.size * (1 + jnp.min(jnp.minimum(inner, 1 - inner), axis=0))
    return jnp.where(jnp.any(overflow, axis=1), 0.0, to_faces)


def nearest(grid: VoxelGrid, queries: Float[Array, "3 S"], slots: int) -> tuple[Int[Array, " S"], Float[Array, " S"]]:
    """The nearest grid point of each query (index into the points the grid was built from)
    and its distance (metres; inf where the 27 voxels hold none)."""
    cand = candidates(grid, queries, slots)
    best, d2 = first_minimum(cand.distance2)
    pick = jnp.take_along_axis(cand.sorted_index, best[:, None], 1)[:, 0]
    return grid.order[pick], jnp.sqrt(d2)


def first_minimum(values: Float[Array, "S C"]) -> tuple[Int[Array, " S"], Float[Array, " S"]]:
    """`jnp.argmin(values, axis=1)` (the first index of each row's minimum) and that minimum,
    by two plain reductions: XLA:CPU vectorises a min and an integer min, not the paired
    value-and-index reduction of `argmin`, which took as long as computing the 144 distances
    of each query. A row of inf gives index 0, as `argmin` does; a row holding NaN gives a
    NaN minimum (its index is then of no use, and the callers' `dist < reach` tests fail)."""
    low = jnp.min(values, axis=1)
    column = jax.lax.broadcasted_iota(jnp.int32, values.shape, 1)
    first = jnp.min(jnp.where(values == low[:, None], column, values.shape[1] - 1), axis=1)
    return first, low


def k_nearest(
    grid: VoxelGrid, queries: Float[Array, "3 S"], k: int, slots: int, found: Windows | None = None
) -> tuple[Int[Array, "S k"], Float[Array, "S k"]]:
    """The k nearest grid points of each query among its 27 voxels (indices into the points
    the grid was built from, and squared distances, inf for missing ones), nearest first.
    `found`: the queries' [`windows`][] where the caller has them already."""
    cand = candidates(grid, queries, slots, found)
    neg, pos = jax.lax.top_k(-cand.distance2, k)
    return grid.order[jnp.take_along_axis(cand.sorted_index, pos, 1)], -neg


def graph_radius(
    grid: VoxelGrid, queries: Float[Array, "3 S"], d2: Float[Array, "S k"], found: Windows, slots: int
) -> Float[Array, " S"]:
    """The radius (metres) within which the `k_nearest` result `d2` of each query holds every
    grid point: every point left out of a query's k nearest lies at least this far from it.
    The k-th distance where the search was exact that far ([`exact_radius`][]), else the
    exact radius (0 where a column overflowed). `found`: the [`windows`][] the search read.
    [`certified_in_graph`][] rests on it."""
    return jnp.minimum(jnp.sqrt(d2[:, -1]), exact_radius(grid, queries, found, slots))


def _graph_step(points, graph, guess, queries):
    """The nearest of each query among `guess` and `graph[guess]` (index into `points`), its
    distance, and the distance to `guess` itself (metres)."""
    cand = jnp.concatenate([guess[:, None], graph[guess]], axis=1)  # (S, k + 1)
    d2 = sum((points[k][cand] - queries[k][:, None]) ** 2 for k in range(3))
    best, low = first_minimum(d2)
    return jnp.take_along_axis(cand, best[:, None], 1)[:, 0], jnp.sqrt(low), jnp.sqrt(d2[:, 0])


def nearest_in_graph(
    points: Float[Array, "3 N"], graph: Int[Array, "N k"], guess: Int[Array, " S"], queries: Float[Array, "3 S"]
) -> tuple[Int[Array, " S"], Float[Array, " S"]]:
    """The nearest of each query among its `guess` point and that point's graph neighbours
    (`graph[guess]`, indices into `points`), and its distance (metres).

    One step of descent on a k-nearest-neighbour graph: where a query moved little since
    `guess` was its nearest point, its new nearest is among guess's neighbours, and k + 1
    distances replace the voxel search's 9·`slots`. Not exact in general (a query that moved
    farther than the neighbourhood's radius gets a near point, not the nearest); the caller
    decides when a step is small enough (`jaxpose._fine.GRAPH_SHIFT`)."""
    index, dist, _ = _graph_step(points, graph, guess, queries)
    return index, dist


def certified_in_graph(
    points: Float[Array, "3 N"],
    graph: Int[Array, "N k"],
    radius: Float[Array, " N"],
    guess: Int[Array, " S"],
    queries: Float[Array, "3 S"],
) -> tuple[Int[Array, " S"], Float[Array, " S"], Bool[Array, " S"], Float[Array, " S"]]:
    """[`nearest_in_graph`][], with whether its answer is certainly the nearest of all the
    points, and a lower bound of the nearest distance (metres).

    Every point outside guess's neighbourhood lies at least r = `radius[guess]`
    ([`graph_radius`][]) from guess, so at least r − |q − guess| from the query q. Where that
    exceeds the distance d found among the neighbourhood, the answer is exact; in any case
    the nearest of all lies at least min(d, r − |q − guess|) away."""
    index, dist, to_guess = _graph_step(points, graph, guess, queries)
    outside = radius[guess] - to_guess
    return index, dist, dist < outside, jnp.minimum(dist, outside)


def spread_subset(mask: Bool[Array, " N"], size: int) -> tuple[Int[Array, " size"], Bool[Array, " size"]]:
    """Indices of at most `size` true entries of `mask`, evenly spread over them (all of them
    when there are at most `size`), and the mask of the live slots. Static shapes."""
    count = jnp.sum(mask)
    rank = jnp.cumsum(mask) - 1  # rank of each true entry among the true entries
    # Keep the entry of rank r when ⌊r·size/count⌋ steps up there: `size` evenly spaced ranks.
    step = jnp.floor(rank * size / jnp.maximum(count, 1)) != jnp.floor((rank - 1) * size / jnp.maximum(count, 1))
    keep = mask & jnp.where(count > size, step, True)
    (idx,) = jnp.nonzero(keep, size=size, fill_value=0)
    return idx, jnp.arange(size) < jnp.minimum(count, size)


def voxel_spacing(points: Float[Array, "3 N"], valid: Bool[Array, " N"], samples: int = 256) -> Float[Array, ""]:
    """The median distance from a point to its nearest neighbour (metres), measured exactly on
    `samples` points spread evenly over the valid ones: the cloud's sampling step. 1 m
    where no valid point has a distinct neighbour (fewer than two distinct points: there is
    nothing to search, and the voxels only need a finite size)."""
    idx, live = spread_subset(valid, samples)
    q = points[:, idx]
    d2 = sum((q[k][:, None] - points[k][None, :]) ** 2 for k in range(3))
    d2 = jnp.where(valid[None, :] & (d2 > 0), d2, jnp.inf)
    nn = jnp.sqrt(jnp.min(d2, axis=1))
    nn = jnp.where(live & jnp.isfinite(nn), nn, jnp.nan)
    step = jnp.nanmedian(nn)
    return jnp.where(jnp.isfinite(step), step, 1.0)


__all__ = [
    "Candidates",
    "VoxelGrid",
    "Windows",
    "candidates",
    "certified_in_graph",
    "exact_radius",
    "first_minimum",
    "graph_radius",
    "k_nearest",
    "nearest",
    "nearest_in_graph",
    "spread_subset",
    "voxel_grid",
    "voxel_spacing",
    "windows",
]
