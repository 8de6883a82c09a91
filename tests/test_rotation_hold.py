"""How firmly a fit's matched surfaces hold its rotation and translation
(`jaxpose._fine.face_holds`) and the status they set (`Thresholds.min_rotation_lever`,
`Thresholds.min_translation_grip`)."""

import math

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

import jaxpose as jp
from jaxpose import _fine
from jaxpose._rotations import rotation_angle


def _view(R, t=(0.0, 0.0, 5.0)):
    """Noise-free N1 seen by the CamCube 2 at pose (R, t), camera frame, metres."""
    return jp.simulate(jp.Camera.camcube2(), jp.targets.n1(), jnp.asarray(R), jnp.asarray(t))


def _turn(axis, degrees):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return _exp(np.radians(degrees) * axis)


def _exp(rotvec):
    return np.asarray(jaxlie.SO3.exp(jnp.asarray(rotvec, jnp.float64)).as_matrix(), float)


CORNER = _turn([1.0, 1.0, 0.0], 50.0) @ _turn([0.0, 0.0, 1.0], 30.0)
"""A pose of N1 that shows three of its faces."""

EDGE = _turn([0.0, 1.0, 0.0], 45.0)
"""A pose of N1 that shows two of its faces, their common edge along the camera's y axis."""


def _problem_at_truth(R0, dR):
    """The problem of the pair (R0, dR R0) at its true displacement (frame n)."""
    config = jp.Config()
    t = jnp.array([0.0, 0.0, 5.0])
    prev, curr = _view(R0), _view(dR @ R0)
    problem = jp.Problem.build(prev, curr, config)
    p = jp.true_displacement(problem.frame, jnp.asarray(R0), t, jnp.asarray(dR @ R0), t)
    return problem, config, p


def _face_matches(problem, config, p):
    """The fit's current points matched to faces (frame ν, `(3, F)`) and their planes' normals
    (`(3, F)`): the raw current side, the fit's inliers among the most planar matches."""
    b, live = _fine.select_current(problem, config, p, smooth=False)
    matched, weight, _ = _fine._correspond(p, b, live, problem.fine, config.fine.inlier)
    keep = np.asarray(weight & matched.planar)
    return np.asarray(_fine._moved(p, b), float)[:, keep], np.asarray(matched.normals, float)[:, keep]


def _direct_lever(problem, config, p, axis, turn=1e-3):
    """An independent reference: the residuals of the fit's matched face planes after a small
    turn about `axis` (frame n) and the translation that best undoes it (least squares),
    root mean square per radian of turn. Sets of points, planes and matches are the fit's own."""
    q, n = _face_matches(problem, config, p)
    q = q - q.mean(axis=1, keepdims=True)
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    R = _exp(turn * axis)
    change = np.sum(n * (R @ q - q), axis=0)  # each residual's change, the planes held fixed
    tau, *_ = np.linalg.lstsq(n.T, -change, rcond=None)
    return np.sqrt(np.mean((change + n.T @ tau) ** 2)) / turn


def _direct_grip(problem, config, p, direction):
    """An independent reference: the residuals' change per metre of a translation along
    `direction` (frame n) over the fit's matched face planes, root mean square."""
    _, n = _face_matches(problem, config, p)
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    return np.sqrt(np.mean((direction @ n) ** 2))


def _assert_the_least(direct, value, vector, rtol):
    """`value` is what the direct reference gives along `vector`, and no random vector (12
    draws) gives less, within `rtol`."""
    np.testing.assert_allclose(direct(np.asarray(vector)), value, rtol=rtol)
    for other in np.random.default_rng(0).normal(size=(12, 3)):
        assert direct(other) >= value * (1 - rtol)


def test_a_face_seen_head_on_holds_no_turn_about_its_normal():
    """N1 with one face towards the camera, turned 4° about the optical axis: the face's planes
    say nothing about that turn (lever ≈ 0), and its axis is the face's normal, the camera's
    z axis."""
    problem, config, p = _problem_at_truth(np.eye(3), _turn([0, 0, 1], 4.0))
    hold = _fine.face_holds(problem, config, p)[0]
    assert float(hold.lever) < 1e-3
    axis_c = np.asarray(problem.frame.axes @ hold.axis)
    assert abs(axis_c[2]) > np.cos(np.radians(1.0))


def test_the_holds_are_the_least_that_any_turn_or_translation_moves_the_matched_faces():
    """On a corner view (three faces): the lever and its axis, and the grip and its direction,
    against the direct references, and every other axis or direction moves the faces at least
    as much."""
    problem, config, p = _problem_at_truth(CORNER, _turn([0.3, -1.0, 0.5], 5.0))
    hold, slide = _fine.face_holds(problem, config, p)
    assert float(hold.lever) > 0.05  # three faces hold every turn
    _assert_the_least(lambda axis: _direct_lever(problem, config, p, axis), float(hold.lever), hold.axis, 2e-2)
    assert float(slide.grip) > 0.1  # and every translation
    _assert_the_least(lambda d: _direct_grip(problem, config, p, d), float(slide.grip), slide.direction, 1e-3)


def test_a_face_seen_head_on_is_uncertain_and_names_the_free_turn():
    """The whole call on the head-on pair: never a success, whatever the search's key, and
    `Estimate.hold.axis` (camera frame) is the optical axis. With the check off
    (`min_rotation_lever=0`) the same result is reported by the other statuses alone."""
    prev, curr = _view(np.eye(3)), _view(_turn([0, 0, 1], 4.0))
    for seed in range(2):
        est = jp.estimate(prev, curr, key=jax.random.key(seed))
        assert int(est.status) != jp._estimate.SUCCESS
        assert int(est.status) == jp._estimate.UNCERTAIN or bool(est.ambiguous)
        assert float(est.hold.lever) < jp.Config().thresholds.min_rotation_lever
        assert abs(float(est.hold.axis[2])) > np.cos(np.radians(1.0))


def test_a_corner_view_is_held_and_found():
    """Three faces: the lever clears the threshold and the motion comes out right, a success."""
    dR = _turn([0.3, -1.0, 0.5], 5.0)
    est = jp.estimate(_view(CORNER), _view(dR @ CORNER), key=jax.random.key(0))
    assert float(est.hold.lever) > 2 * jp.Config().thresholds.min_rotation_lever
    assert int(est.status) == jp._estimate.SUCCESS
    assert np.degrees(float(rotation_angle(est.rotation, jnp.asarray(dR)))) < 0.01


def test_two_faces_hold_no_slide_along_their_common_edge():
    """N1 turned 45° about the camera's y axis shows two faces: their planes say nothing about a
    translation along the edge where they meet (grip ≈ 0), and its direction is that edge,
    the camera's y axis; they hold every turn."""
    problem, config, p = _problem_at_truth(EDGE, _turn([0.2, 1.0, -0.3], 4.0))
    hold, slide = _fine.face_holds(problem, config, p)
    assert float(slide.grip) < 1e-3
    direction_c = np.asarray(problem.frame.axes @ slide.direction)
    assert abs(direction_c[1]) > np.cos(np.radians(3.0))
    assert float(hold.lever) > 2 * config.thresholds.min_rotation_lever


def test_two_faces_are_uncertain_and_name_the_free_slide():
    """The whole call on the two-face pair: never a success, whatever the search's key, and
    `Estimate.slide.direction` (camera frame) is the common edge, the camera's y axis."""
    dR = _turn([0.2, 1.0, -0.3], 4.0)
    prev, curr = _view(EDGE), _view(dR @ EDGE)
    for seed in range(2):
        est = jp.estimate(prev, curr, key=jax.random.key(seed))
        assert int(est.status) != jp._estimate.SUCCESS
        assert float(est.slide.grip) < jp.Config().thresholds.min_translation_grip
        assert abs(float(est.slide.direction[1])) > np.cos(np.radians(3.0))


@pytest.mark.parametrize("value", [-0.01, float("nan")])
def test_the_threshold_is_checked(value):
    with pytest.raises(ValueError, match="min_rotation_lever"):
        jp.Thresholds(min_rotation_lever=value)


@pytest.mark.parametrize("value", [-0.01, 1.5, float("nan")])
def test_the_grip_threshold_is_checked(value):
    with pytest.raises(ValueError, match="min_translation_grip"):
        jp.Thresholds(min_translation_grip=value)


def test_the_tracker_registers_without_the_hold_checks():
    """`chain_estimates` judges an unheld turn or translation by motion continuity: its
    registrations' config has both checks off, the covariance scale its filter was tuned with,
    and is otherwise the caller's."""
    import dataclasses

    from jaxpose.tracking._track import TRACKING_COVARIANCE_SCALE, registration_config

    config = jp.Config(thresholds=jp.Thresholds(min_score=0.6))
    inner = registration_config(config)
    assert inner.thresholds.min_rotation_lever == 0.0
    assert inner.thresholds.min_translation_grip == 0.0
    assert inner.thresholds.min_score == 0.6
    assert inner.fine.covariance_scale == TRACKING_COVARIANCE_SCALE != config.fine.covariance_scale
    assert inner.fine == dataclasses.replace(
        config.fine, covariance_scale=TRACKING_COVARIANCE_SCALE, covariance_noise=math.inf
    )
