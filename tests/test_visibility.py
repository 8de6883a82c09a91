"""Range maps built from a cloud (`jaxpose._visibility`), checked against scenes whose
visibility is known in closed form: a plate seen head-on and a plate hiding a part of a
second one behind it."""

import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import _visibility as visibility

CAMERA = np.zeros(3)


def _plate(z, half, spacing, rng=None, dropout=0.0, centre=(0.0, 0.0)):
    """Points (3, N) on the square plate |x − cx|, |y − cy| ≤ half at depth z (metres), one
    per pixel-like grid step, a share `dropout` dropped at random."""
    g = np.arange(-half, half + 1e-9, spacing)
    x, y = np.meshgrid(g + centre[0], g + centre[1])
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    if dropout:
        points = points[:, rng.random(points.shape[1]) >= dropout]
    return points


def _map(points):
    p = jnp.asarray(points)
    valid = jnp.ones(p.shape[1], bool)
    basis = visibility.view_basis(p, valid, jnp.asarray(CAMERA))
    return visibility.range_map(p, valid, jnp.asarray(CAMERA), basis)


def test_view_basis_is_orthonormal_and_looks_at_the_cloud():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(3, 200)) * 0.3 + np.array([[1.0], [-2.0], [4.0]])
    B = np.asarray(visibility.view_basis(jnp.asarray(points), jnp.ones(200, bool), jnp.asarray(CAMERA)))
    np.testing.assert_allclose(B @ B.T, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(B), 1.0, atol=1e-6)
    mean_direction = (points / np.linalg.norm(points, axis=0)).mean(axis=1)
    np.testing.assert_allclose(B[2], mean_direction / np.linalg.norm(mean_direction), atol=1e-6)


@pytest.mark.parametrize("dropout", [0.0, 0.3])
def test_a_plate_hides_what_lies_behind_it_and_nothing_else(dropout):
    """A 1 m plate 5 m ahead, 1 cm between points, 30 % of them dropped or none. Behind it by
    more than the margin: hidden; in front of it, or behind by less than the margin: not;
    beside it (outside its directions), at any depth: not. The nearest range in every cell
    is the plate's range along some ray of that cell (no cell inside the plate is empty)."""
    rng = np.random.default_rng(1)
    rmap = _map(_plate(5.0, 0.5, 0.01, rng, dropout))
    probe = np.array([[0.1, -0.2, 5.2], [0.1, -0.2, 4.8], [0.3, 0.3, 5.03], [1.5, 0.0, 9.0], [0.0, 0.0, 1.0]]).T
    got = np.asarray(visibility.hidden(rmap, jnp.asarray(probe), 0.05))
    assert got.tolist() == [True, False, False, False, False]
    inside = np.asarray(rmap.nearest)[np.isfinite(np.asarray(rmap.nearest))]
    # Every range on the plate lies in [5, √(5² + 0.5² + 0.5²)].
    assert inside.min() >= 5.0 - 1e-5 and inside.max() <= np.sqrt(25.5) + 1e-5
    span = np.asarray(rmap.hi - rmap.lo) / float(rmap.cell)
    full = int(np.floor(span.min())) - 1  # cells lying wholly inside the plate's directions
    assert np.isfinite(np.asarray(rmap.nearest)[:full, :full]).all()


def test_a_near_plate_hides_only_the_part_of_a_far_plate_behind_it():
    """A 0.4 m plate at 4 m in front of the left part of a 1 m plate at 6 m: the far plate's
    points behind the near one are hidden, those beside it are not, by the independent
    geometric test (the ray from the camera through the point crosses the near plate)."""
    near = _plate(4.0, 0.2, 0.008, centre=(-0.3, 0.0))
    far = _plate(6.0, 0.5, 0.012)
    # The camera sees the near plate and the part of the far plate not behind it.
    at_near_depth = far[:2] * 4.0 / 6.0
    behind = (np.abs(at_near_depth[0] + 0.3) <= 0.2) & (np.abs(at_near_depth[1]) <= 0.2)
    rmap = _map(np.concatenate([near, far[:, ~behind]], axis=1))
    got = np.asarray(visibility.hidden(rmap, jnp.asarray(far), 0.05))
    # Cells straddle the near plate's outline: judge the points a cell or more from it.
    x, y = at_near_depth
    dx, dy = np.abs(x + 0.3) - 0.2, np.abs(y) - 0.2
    outline = np.where(behind, -np.maximum(dx, dy), np.hypot(np.maximum(dx, 0), np.maximum(dy, 0)))
    clear = outline / 4.0 > 2.0 * float(rmap.cell)  # in tangent-plane units
    assert clear.sum() > 0.8 * far.shape[1] and (clear & behind).sum() > 0.5 * behind.sum()
    np.testing.assert_array_equal(got[clear], behind[clear])


@pytest.mark.parametrize("dropout", [0.0, 0.3])
def test_a_plate_is_seen_through_only_in_front_of_it_and_where_nothing_was_seen(dropout):
    """`in_front`, the complement of `hidden` within the view: in front of the plate by more
    than the margin, or in a direction inside the view's box where nothing was seen, a point
    contradicts the view; on or behind the plate, or outside the view's directions, it does
    not. A 1 m plate 5 m ahead with a 0.3 m square hole (nothing seen through it)."""
    rng = np.random.default_rng(2)
    plate = _plate(5.0, 0.5, 0.01, rng, dropout)
    hole = (np.abs(plate[0] - 0.25) <= 0.15) & (np.abs(plate[1] - 0.25) <= 0.15)
    rmap = _map(plate[:, ~hole])
    probe = np.array(
        [
            [-0.2, -0.2, 4.8],  # 20 cm in front of the plate: seen through
            [-0.2, -0.2, 4.99],  # on the plate, within the margin
            [-0.2, -0.2, 5.5],  # behind it
            [0.25, 0.25, 5.0],  # in the hole's middle, at the plate's depth: nothing was seen there
            [1.5, 0.0, 4.0],  # beside the view
        ]
    ).T
    got = np.asarray(visibility.in_front(rmap, jnp.asarray(probe), 0.02))
    assert got.tolist() == [True, False, False, True, False]
    hidden = np.asarray(visibility.hidden(rmap, jnp.asarray(probe), 0.02))
    assert not np.any(got & hidden)
