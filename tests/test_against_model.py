"""`track_against_model`: every frame registered against the growing body-frame model.

The reference is the simulator's true motion. The chain given to it is built from the truth
with a known drift (each keyframe switch adds a 1° turn, as a chain's registration errors
add up), so the test knows what the chain got wrong and checks that the model takes it out."""

import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

import jaxpose as jp
from jaxpose._estimate import LOW_SCORE, NOT_CONVERGED, SUCCESS, UNCERTAIN
from jaxpose._problem import sized_sequence_config
from jaxpose.sim import Tumble, simulate_sequence
from jaxpose.tracking._against_model import (
    FrameRegistration,
    agrees_with_chain,
    model_config,
    model_side,
    register_frame,
)

KEYFRAMES = (0, 3, 6, 9)
DRIFT_DEG = 1.0
LOST = 5
"""A frame whose cloud is moved 1 m away: no model surface near it, so it must not register."""


def rotation_error_deg(R, R_true):
    return np.array(
        [np.degrees(np.linalg.norm(jaxlie.SO3.from_matrix(a @ b.T).log())) for a, b in zip(R, R_true, strict=True)]
    )


def drifted_chain(seq) -> jp.Track:
    """A `Track` of the true motions, registered against `KEYFRAMES`, with `DRIFT_DEG` more
    turn about a fixed axis after each keyframe switch (frame k's keyframe is the last one
    before it)."""
    G, p = seq.rotations, seq.positions
    T = G.shape[0]
    R_true = jnp.einsum("tij,kj->tik", G, G[0])
    keyframes = np.array([max(j for j in KEYFRAMES if j < k) if k else 0 for k in range(T)])
    switches = np.array([sum(1 for j in KEYFRAMES[1:] if j <= k) for k in range(T)])
    turn = jnp.stack(
        [jaxlie.SO3.exp(jnp.radians(DRIFT_DEG) * m * jnp.array([0.6, 0.0, 0.8])).as_matrix() for m in switches]
    )
    R = jnp.einsum("tij,tjk->tik", turn, R_true)
    points = jnp.einsum("tij,j->ti", R, p[0]) + (p - jnp.einsum("tij,j->ti", R_true, p[0]))
    return jp.Track.of_measurements(
        R, points, jnp.asarray(keyframes, jnp.int32), jnp.broadcast_to(jnp.eye(6) * 1e-6, (T, 6, 6))
    )


@pytest.fixture(scope="module")
def sequence():
    """2 s of N5 tumbling at 20 °/s, 5 Hz, noise-free (11 frames, 40° in all), one frame lost,
    and the drifted chain over it."""
    seq = simulate_sequence(jp.Camera.camcube2(), jp.targets.n5(), Tumble.n5(20.0), 2.0, 5.0)
    points = seq.clouds.points.at[LOST].add(jnp.array([1.0, 0.0, 0.0]))
    return seq, jp.Cloud(points, seq.clouds.valid), drifted_chain(seq)


@pytest.fixture(scope="module")
def tumble(sequence):
    """The sequence registered against the model (compiles the registration: ≈ 50 s on 2 cores,
    hence `slow`: an option off the default path)."""
    seq, clouds, chain = sequence
    return seq, clouds, chain, jp.track_against_model(clouds, chain, 0.2)


@pytest.mark.slow
def test_the_model_takes_out_the_chains_drift(tumble):
    seq, _, chain, model = tumble
    G = seq.rotations
    R_true = jnp.einsum("tij,kj->tik", G, G[0])
    kept = np.arange(G.shape[0]) != LOST
    chain_error = rotation_error_deg(chain.rotations, R_true)
    model_error = rotation_error_deg(model.rotations, R_true)
    assert chain_error[-1] > 2.5 * DRIFT_DEG  # three switches
    assert np.all(model_error[kept] < 0.02), model_error
    p_true = seq.positions - jnp.einsum("tij,j->ti", R_true, seq.positions[0])
    t_model = model.motions()[0]
    assert np.all(np.linalg.norm(np.asarray(t_model - p_true), axis=1)[kept] < 2e-4)
    # Every frame is a measurement against the model, anchored at frame 0; every kept frame is
    # a success, so none needed the chain's agreement.
    assert np.all(np.asarray(model.keyframes) == 0)
    assert not np.any(np.asarray(model.continuity))
    assert np.all(np.isfinite(np.asarray(model.attitude))) and np.all(np.isfinite(np.asarray(model.rate)))


@pytest.mark.slow
def test_float32_clouds_register_against_the_model_in_the_sessions_precision(tumble):
    """Under `jax_enable_x64` (the tests' setting) a float32 sequence registers against the
    model with a float64 track as the float64 one does: it traces, and every registered frame
    is as close to the truth."""
    seq, clouds, chain, _ = tumble
    single = jp.Cloud(jnp.asarray(clouds.points, jnp.float32), clouds.valid)
    model = jp.track_against_model(single, chain, 0.2)
    assert model.rate.dtype == jnp.float64
    assert np.all(np.isfinite(np.asarray(model.attitude))) and np.all(np.isfinite(np.asarray(model.rate)))
    R_true = jnp.einsum("tij,kj->tik", seq.rotations, seq.rotations[0])
    kept = np.arange(R_true.shape[0]) != LOST
    assert np.all(rotation_error_deg(model.rotations, R_true)[kept] < 0.02)


@pytest.mark.slow
def test_a_frame_away_from_the_model_is_not_a_registration(tumble):
    _, _, chain, model = tumble
    status = np.asarray(model.status)
    assert status[LOST] == LOW_SCORE
    assert not bool(model.registered()[LOST])
    assert np.all(status[np.arange(status.size) != LOST] == SUCCESS)
    assert int(model.filter_status[LOST]) == jp.tracking.FILTER_NO_ESTIMATE


@pytest.mark.slow
def test_register_frame_shapes_and_a_start_at_the_truth(tumble):
    """One registration from the true motion stays there, with the shapes its annotations name."""
    seq, clouds, _, _ = tumble
    G, p = seq.rotations, seq.positions
    config = model_config(sized_sequence_config(clouds, jp.Config()))
    side = model_side(clouds.points[0], clouds.valid[0], config)
    R = G[2] @ G[0].T
    reg = register_frame(side, jp.Cloud(clouds.points[2], clouds.valid[2]), R, p[2] - R @ p[0], config)
    assert isinstance(reg, FrameRegistration)
    assert reg.rotation.shape == (3, 3) and reg.translation.shape == (3,) and reg.covariance.shape == (6, 6)
    assert int(reg.status) == SUCCESS and float(reg.inliers) > 0.9
    assert rotation_error_deg(reg.rotation[None], R[None])[0] < 0.01


def test_track_against_model_checks_its_input(sequence):
    _, clouds, chain = sequence
    # Not a Track: a ValueError, or the run-time type check's TypeError where it is on (tests).
    with pytest.raises((ValueError, TypeError), match="Track"):
        jp.track_against_model(clouds, chain.rotations, 0.2)
    with pytest.raises(ValueError, match="time axis"):
        jp.track_against_model(jp.Cloud(clouds.points[:3], clouds.valid[:3]), chain, 0.2)
    with pytest.raises(ValueError, match="voxel"):
        jp.track_against_model(clouds, chain, 0.2, voxel=-1.0)
    with pytest.raises(ValueError, match="fine stage"):
        jp.track_against_model(clouds, chain, 0.2, config=jp.Config(fine=None))


def _registration(angle_deg: float, status: int, cov_scale: float = 1e-6) -> FrameRegistration:
    """A registration turned `angle_deg` about (0.6, 0, 0.8) from the identity."""
    R = jaxlie.SO3.exp(jnp.radians(angle_deg) * jnp.array([0.6, 0.0, 0.8])).as_matrix()
    return FrameRegistration(R, jnp.zeros(3), jnp.asarray(status, jnp.int32), jnp.eye(6) * cov_scale, jnp.asarray(0.9))


def test_a_weak_registration_is_accepted_only_where_it_agrees_with_the_chain():
    """Within `WEAK_FRACTION` × `ambiguous_deg` (1°) of the chain's registration of the frame, a
    not-converged or uncertain fit against the model counts; beyond it, with a covariance that
    cannot be fused, a low score or as a success (taken by its own status) it does not."""
    config = jp.Config()
    chain = np.eye(3)
    assert agrees_with_chain(_registration(0.5, NOT_CONVERGED), chain, config)
    assert agrees_with_chain(_registration(0.9, UNCERTAIN), chain, config)
    assert not agrees_with_chain(_registration(1.1, NOT_CONVERGED), chain, config)
    assert not agrees_with_chain(_registration(0.1, LOW_SCORE), chain, config)
    assert not agrees_with_chain(_registration(0.1, SUCCESS), chain, config)
    assert not agrees_with_chain(_registration(0.1, UNCERTAIN, cov_scale=np.nan), chain, config)
    # The gate follows the config's ambiguity angle.
    wide = jp.Config(thresholds=jp.Thresholds(ambiguous_deg=2.0))
    assert agrees_with_chain(_registration(1.5, NOT_CONVERGED), chain, wide)
