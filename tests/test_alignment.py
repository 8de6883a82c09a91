"""The correlated translation (`jaxpose._alignment`): the shift found against a brute-force
overlap count of its own occupancy grids, and the translation of two partial views of a box
within a cell of the truth where the centroids' shift is not."""

import itertools

import jax.numpy as jnp
import numpy as np
from box_views import box_views

from jaxpose import _alignment as alignment


def _box_views():
    """The previous and current points of `box_views`' cube that face the camera, and the
    motion (G, xyz) between them."""
    v = box_views(600)
    return v.P[:, v.seen_prev], v.B[:, v.seen_curr], v.G, v.xyz


def _occupied(points, origin, cell, n):
    idx = np.floor((points - origin[:, None]) / cell).astype(int)
    inside = np.all((idx >= 0) & (idx < n), axis=0)
    return {tuple(i) for i in idx[:, inside].T}


def test_the_correlation_peak_is_the_shift_of_largest_overlap():
    """Against an independent count: the occupied cells of both grids as sets, and for every
    shift within ±9 cells the number of cells occupied in both once the turned previous grid is
    shifted. The correlation's shift reaches the largest count."""
    prev, curr, G, _ = _box_views()
    valid_p, valid_c = np.ones(prev.shape[1], bool), np.ones(curr.shape[1], bool)
    extent = max(np.ptp(prev, axis=1).max(), np.ptp(curr, axis=1).max())
    target = alignment.correlation_target(jnp.asarray(curr), jnp.asarray(valid_c), jnp.asarray(extent))
    t = alignment.correlation_translation(jnp.asarray(G), jnp.asarray(prev), jnp.asarray(valid_p), target)
    n = alignment.CORRELATION_CELLS
    cell = alignment.CORRELATION_SPAN * extent / n
    c_prev, c_curr = prev.mean(axis=1), curr.mean(axis=1)
    origin = c_curr - cell * n / 2
    a = _occupied(G @ (prev - c_prev[:, None]) + c_curr[:, None], origin, cell, n)
    b = _occupied(curr, origin, cell, n)
    shift = np.rint((np.asarray(t) - (c_curr - G @ c_prev)) / cell).astype(int)

    def overlap(s):
        return sum(((i + s[0]) % n, (j + s[1]) % n, (k + s[2]) % n) in b for i, j, k in a)

    best = max(overlap(s) for s in itertools.product(range(-9, 10), repeat=3))
    assert np.all(np.abs(shift) <= 9)
    assert overlap(shift) == best


def test_the_correlated_translation_of_two_partial_views_lies_within_a_cell():
    """The views share only part of the cube, so the centroids' shift lies far from the true
    translation; the correlated one lies within a cell (along each axis) of it."""
    prev, curr, G, xyz = _box_views()
    valid_p, valid_c = np.ones(prev.shape[1], bool), np.ones(curr.shape[1], bool)
    extent = alignment.cloud_extent(jnp.asarray(curr), jnp.asarray(valid_c))
    target = alignment.correlation_target(jnp.asarray(curr), jnp.asarray(valid_c), extent)
    t = alignment.correlation_translation(jnp.asarray(G), jnp.asarray(prev), jnp.asarray(valid_p), target)
    cell = alignment.CORRELATION_SPAN * float(extent) / alignment.CORRELATION_CELLS
    centroid_shift = curr.mean(axis=1) - G @ prev.mean(axis=1)
    assert np.linalg.norm(centroid_shift - xyz) > 3 * cell
    assert np.all(np.abs(np.asarray(t) - xyz) <= cell)


def test_cloud_extent_is_the_largest_side_of_the_valid_points():
    points = np.array([[0.0, 2.0, 1.0, 50.0], [0.0, -1.0, 0.5, 0.0], [0.0, 0.0, 3.0, 0.0]])
    valid = np.array([True, True, True, False])
    assert float(alignment.cloud_extent(jnp.asarray(points), jnp.asarray(valid))) == 3.0
    assert float(alignment.cloud_extent(jnp.asarray(points), jnp.zeros(4, bool))) == 0.0
