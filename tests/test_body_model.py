"""`body_model`: the registered clouds fused into one voxelised model of the target.

The reference is the target's own surface: N5 is a union of boxes, whose exact signed
distance (`box_distance`) does not depend on the fusion."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.evaluation.model_fit import box_distance
from jaxpose.sim import Tumble, simulate_sequence
from jaxpose.tracking._model import fuse_clouds, voxel_means


def test_voxel_means_average_each_cell_and_count_its_points():
    points = jnp.array([[0.01, 0.01, 0.01], [0.03, 0.03, 0.03], [0.15, 0.0, 0.0], [9.0, 9.0, 9.0], [-0.01, 0.0, 0.0]])
    valid = jnp.array([True, True, True, False, True])
    means, counts = voxel_means(points, valid, 0.1)
    occupied = np.asarray(counts) > 0
    assert occupied.sum() == 3 and np.all(occupied[:3])  # the invalid point makes no voxel
    pairs = zip(np.asarray(means)[occupied], np.asarray(counts)[occupied], strict=True)
    found = {tuple(np.round(m, 6)): int(c) for m, c in pairs}
    assert found == {(0.02, 0.02, 0.02): 2, (0.15, 0.0, 0.0): 1, (-0.01, 0.0, 0.0): 1}


@pytest.fixture(scope="module")
def tumble_clouds():
    """2 s of N5 tumbling at 20 °/s, 5 Hz, noise-free: 11 views from different sides."""
    return simulate_sequence(jp.Camera.camcube2(), jp.targets.n5(), Tumble.n5(20.0), 2.0, 5.0)


def test_exact_motions_fuse_onto_the_target_surface(tumble_clouds):
    seq = tumble_clouds
    G, p = seq.rotations, seq.positions
    R = jnp.einsum("tij,kj->tik", G, G[0])
    t = p - jnp.einsum("tij,j->ti", R, p[0])
    # Model frame = the target frame t: P = G_0, c = O_t at the first frame.
    model = fuse_clouds(seq.clouds.points, seq.clouds.valid, R, t, G[0], p[0], voxel=0.02)
    distance = np.abs(np.asarray(box_distance(model.points, jp.targets.n5())))
    assert model.points.shape[0] > 2000
    assert np.median(distance) < 1e-3 and np.percentile(distance, 99) < 0.02
    # More of the surface than the first view alone.
    first = fuse_clouds(seq.clouds.points[:1], seq.clouds.valid[:1], R[:1], t[:1], G[0], p[0], voxel=0.02)
    assert model.points.shape[0] > 1.5 * first.points.shape[0]


def test_wrong_motions_blur_the_model(tumble_clouds):
    """The same fusion with each frame's rotation 2° off: the model leaves the surface."""
    seq = tumble_clouds
    G, p = seq.rotations, seq.positions
    turn = jaxlie.SO3.exp(jnp.radians(2.0) * jnp.array([1.0, 0.0, 0.0])).as_matrix()
    R = jnp.einsum("tij,kj->tik", G, G[0])
    R_bad = jnp.concatenate([R[:1], jnp.einsum("ij,tjk->tik", turn, R[1:])])
    t = p - jnp.einsum("tij,j->ti", R, p[0])
    model = fuse_clouds(seq.clouds.points, seq.clouds.valid, R_bad, t, G[0], p[0], voxel=0.02)
    distance = np.abs(np.asarray(box_distance(model.points, jp.targets.n5())))
    assert np.percentile(distance, 90) > 0.01


def exact_track(seq) -> jp.Track:
    """A `Track` holding the exact motions, every frame registered against frame 0."""
    G, p = seq.rotations, seq.positions
    T = G.shape[0]
    R = jnp.einsum("tij,kj->tik", G, G[0])
    return jp.Track.of_measurements(R, p, jnp.zeros(T, jnp.int32), jnp.broadcast_to(jnp.eye(6), (T, 6, 6)))


def test_body_model_of_a_track_is_the_fusion_of_its_frames(tumble_clouds):
    seq = tumble_clouds
    track = exact_track(seq)
    T = seq.rotations.shape[0]
    model = jp.body_model(seq.clouds, track, voxel=0.02, frames=jnp.arange(T))
    R, p = track.rotations, seq.positions
    t = p - jnp.einsum("tij,j->ti", R, p[0])
    expected = fuse_clouds(seq.clouds.points, seq.clouds.valid, R, t, jnp.eye(3), jnp.zeros(3), voxel=0.02)
    np.testing.assert_allclose(model.points, expected.points, atol=1e-6)
    # Default frames: the keyframes, here frame 0 alone.
    assert jp.body_model(seq.clouds, track, voxel=0.02).points.shape[0] < model.points.shape[0]


def test_body_model_checks_its_input(tumble_clouds):
    seq = tumble_clouds
    track = exact_track(seq)
    with pytest.raises(ValueError, match="time axis"):
        jp.body_model(jp.Cloud(seq.clouds.points[:3], seq.clouds.valid[:3]), track)
    with pytest.raises(ValueError, match="voxel"):
        jp.body_model(seq.clouds, track, voxel=0.0)
