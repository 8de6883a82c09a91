"""Sequences of a tumbling target and the tracking filter (issue 7)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

import jaxpose as jp
from jaxpose._estimate import AMBIGUOUS, DEGENERATE, LOW_SCORE, NON_FINITE, NOT_CONVERGED, SUCCESS
from jaxpose.sim import Tumble, paper_pose, simulate_sequence, tumble_poses
from jaxpose.tracking._track import (
    ANCHOR_WEIGHT,
    FILTER_BAD_MEASUREMENT,
    FILTER_BAD_UPDATE,
    FILTER_NO_ESTIMATE,
    FILTER_UPDATED,
    Chain,
    TrackFilter,
    _guarded_update,
    _row,
    _skew,
    anchor_weight,
    anchored_motion,
    continuity_choice,
    covariance_usable,
    filter_chain,
    filter_keyframes,
    keyframe_switch,
    measurement_usable,
    motion_reached,
    nearest_semidefinite,
    predicted_motion,
    prediction_spread,
    track,
)


def test_tumble_poses_start_at_the_initial_state_and_turn_at_the_set_rate():
    tumble = Tumble.n5(4.5)
    times = jnp.arange(26) / 25.0
    R, positions, rates = tumble_poses(tumble, times)
    np.testing.assert_allclose(np.asarray(R[0]), np.asarray(tumble.attitude), atol=1e-12)
    np.testing.assert_allclose(np.asarray(positions), np.broadcast_to(np.asarray(tumble.position), (26, 3)), atol=1e-9)
    for k in range(25):
        np.testing.assert_allclose(np.asarray(R[k] @ R[k].T), np.eye(3), atol=1e-12)
    # Apparent rate in the camera frame: body rate 4.5°/s minus at most the orbit rate (0.064°/s).
    step = np.degrees(float(jp.rotation_angle(R[25], R[0])))
    assert abs(step - 4.5) < 0.07 and abs(np.degrees(float(jnp.linalg.norm(rates[0]))) - 4.5) < 1e-9


def test_tumble_poses_count_time_from_the_initial_state_not_the_first_time_asked():
    tumble = Tumble.chibis_m()
    # Same shape of `times` in both calls: one compile.
    R_late, p_late, w_late = tumble_poses(tumble, jnp.array([300.0, 301.0, 302.0]))
    R_all, p_all, w_all = tumble_poses(tumble, jnp.array([0.0, 300.0, 301.0]))
    np.testing.assert_allclose(np.asarray(p_late[:2]), np.asarray(p_all[1:]), atol=1e-9)
    np.testing.assert_allclose(np.asarray(R_late[:2]), np.asarray(R_all[1:]), atol=1e-9)
    np.testing.assert_allclose(np.asarray(w_late[:2]), np.asarray(w_all[1:]), atol=1e-12)
    assert abs(float(jnp.linalg.norm(p_late[0])) - 3.0) > 2.0  # 300 s at 1 cm/s: moved ≈ 3 m


def test_filter_recovers_the_rate_from_exact_poses():
    rate = jnp.array([0.02, -0.05, 0.06])  # rad/s in frame c
    filt = TrackFilter.start(jnp.zeros(3))
    for k in range(1, 51):
        filt = filt.predict(0.04, 1e-4, 1e-4)
        A = jaxlie.SO3.exp(rate * 0.04 * k).as_matrix()
        filt = filt.update(A, jnp.array([0.0, 0.0, 0.01 * 0.04 * k]), jnp.eye(6) * 1e-8)
    np.testing.assert_allclose(np.asarray(filt.rate), np.asarray(rate), atol=1e-4)
    np.testing.assert_allclose(np.asarray(filt.velocity), [0.0, 0.0, 0.01], atol=1e-4)


def _drifting_chain(rate0, spin_accel, dt=0.04, frames=251):
    """Exact chained poses of a rotation about a fixed axis whose rate grows linearly."""
    t = jnp.arange(frames) * dt
    angle = rate0 * t + 0.5 * spin_accel * t**2
    axis = jnp.array([0.6, 0.0, 0.8])
    R = jax.vmap(lambda a: jaxlie.SO3.exp(axis * a).as_matrix())(angle)
    # The tracked point (on the rotation axis, as a centroid is) starts 5.5 m ahead and moves at
    # 1 cm/s along z. Keyframe every 25 frames; the relative measurements keyframe → k.
    origin = jnp.array([0.2, -0.1, 5.5])
    points = origin[None] + jnp.outer(t, jnp.array([0.0, 0.0, 0.01]))
    translations = points - jax.vmap(lambda Rk: Rk @ origin)(R)
    k = jnp.arange(frames)
    key = jnp.where(k % 25 == 0, k - 25, (k // 25) * 25).clip(0)  # measured from the last keyframe
    R_rel = jax.vmap(lambda a, b: a @ b.T)(R, R[key])
    t_rel = points - jax.vmap(lambda M, p: M @ p)(R_rel, points[key])
    cov = jnp.broadcast_to(jnp.eye(6) * 1e-8, (frames, 6, 6))
    status = jnp.zeros(frames, jnp.int32)
    chain = Chain(R, translations, points, status, origin, R_rel, t_rel, cov, k % 25 == 0)
    return chain, (rate0 + spin_accel * t)[:, None] * axis[None], points


def test_filter_follows_a_drifting_rate_that_the_constant_rate_model_lags():
    # 0.08 rad/s growing by 1e-3 rad/s² (N5's tumble drifts by ≈ 1e-3 rad/s², see the module
    # docstring); exact measurements at 25 Hz for 10 s.
    chain, true_rate, _ = _drifting_chain(0.08, 1e-3)
    with_accel = filter_chain(chain, 0.04, rotation_sigma=1e-4, point_sigma=1e-4)
    constant = filter_chain(chain, 0.04, 1e-4, 1e-4, spin_accel_noise=0.0, spin_accel_sigma=0.0)
    err_accel = float(jnp.linalg.norm(with_accel.rate[-1] - true_rate[-1]))
    err_const = float(jnp.linalg.norm(constant.rate[-1] - true_rate[-1]))
    assert err_accel < 1e-4, err_accel
    assert err_const > 10 * err_accel, (err_const, err_accel)
    np.testing.assert_allclose(
        np.asarray(with_accel.spin_accel[-1]), np.asarray(1e-3 * jnp.array([0.6, 0.0, 0.8])), atol=1e-4
    )


def test_keyframe_filter_on_exact_relative_measurements_matches_the_motion():
    chain, true_rate, points = _drifting_chain(0.08, 1e-3)
    result = filter_keyframes(chain, 0.04)
    assert float(jnp.linalg.norm(result.rate[-1] - true_rate[-1])) < 1e-4
    np.testing.assert_allclose(np.asarray(result.position[-1]), np.asarray(points[-1]), atol=1e-5)
    np.testing.assert_allclose(np.asarray(result.velocity[-1]), [0.0, 0.0, 0.01], atol=1e-4)
    angle = float(jp.rotation_angle(result.attitude[-1], chain.rotations[-1]))
    assert angle < 1e-5, angle


def test_keyframe_filter_carries_an_error_shared_by_a_segment_in_the_clone():
    # Every registration against one keyframe is off by the same rotation (σ 1e-3 rad per axis,
    # about the tracked point, as a registration error is), drawn anew for each keyframe. A
    # filter that takes the errors as independent reads each switch's jump as motion; one
    # that carries them in the clone (shared_fraction) reads the rate off each segment.
    chain, true_rate, points = _drifting_chain(0.08, 1e-3)
    errors = np.random.default_rng(0).normal(0.0, 1e-3, (11, 3))
    segment = np.maximum(np.arange(len(points)) - 1, 0) // 25  # frames 1–25 → keyframe 0, …
    E = jax.vmap(lambda e: jaxlie.SO3.exp(e).as_matrix())(jnp.asarray(errors[segment]))
    R_rel = E @ chain.relative_rotations
    t_rel = jnp.einsum("kij,kj->ki", E, chain.relative_translations - points) + points

    def cov(point, t):  # the covariance of such an error: rotation vector, then translation
        G = jnp.concatenate([jnp.eye(3), _skew(point - t)])
        return 1e-6 * G @ G.T + 1e-10 * jnp.eye(6)

    covs = jax.vmap(cov)(points, chain.relative_translations)
    chain = eqx.tree_at(
        lambda c: (c.relative_rotations, c.relative_translations, c.relative_cov), chain, (R_rel, t_rel, covs)
    )
    late = {}
    for fraction in (0.0, 0.99):
        rate = filter_keyframes(chain, 0.04, shared_fraction=fraction).rate
        late[fraction] = np.degrees(float(jnp.linalg.norm(rate - true_rate, axis=1)[-75:].max()))
    assert late[0.99] < 0.03, late  # °/s over the last 3 s (measured 0.013)
    assert late[0.0] > 3 * late[0.99], late


@pytest.mark.slow
def test_tracking_a_simulated_tumble_converges():
    # 2 s at 12.5 Hz, noise-free; keyframes every 0.4 s. The fast config keeps it short; its
    # estimates are ≈ 0.5° off, so after 2 s the rate is known to about 1°/s (the accurate
    # and tracking configs over 10 s: 0.03–0.08°/s, experiments/tumble_tracking.py).
    dt = 0.08
    seq = simulate_sequence(jp.Camera.camcube2(), jp.targets.n5(), Tumble.n5(4.5), 2.0, 1 / dt)
    result = jax.jit(
        lambda c: track(c, dt, jp.Config.fast(capacities=jp.Capacities(max_points=5120)), jax.random.key(0), 5)
    )(seq.clouds)
    R = np.asarray(seq.rotations)
    true_rate = np.asarray(jaxlie.SO3.from_matrix(R[-1] @ R[-2].T).log()) / dt
    error = np.degrees(np.linalg.norm(np.asarray(result.rate) - true_rate, axis=1))
    assert np.mean(np.asarray(result.status) == 0) > 0.8
    assert error[0] > 4.0 and error[-1] < 1.5 and error[-5:].max() < 1.5, error  # from "unknown" (zero)
    # The chained attitude drifts by each keyframe switch's pair error: 5 switches here, each
    # within the fast config's ≈ 0.5° (test_estimate), so at most ≈ 2.5° (measured: 2.2°).
    attitude = np.degrees(float(jp.rotation_angle(result.attitude[-1], R[-1] @ R[0].T)))
    assert attitude < 2.5 and math.isfinite(attitude)


FILTERED = ("attitude", "rate", "spin_accel", "position", "velocity", "rate_std")


def _all_finite(result) -> bool:
    """Every filtered output is finite (the measurements are passed through as they came)."""
    return all(bool(jnp.all(jnp.isfinite(getattr(result, name)))) for name in FILTERED)


GOOD_COV = jnp.eye(6) * 1e-6


@pytest.mark.parametrize(
    "change, usable",
    [
        (lambda R, t, c: (R, t, c), True),
        (lambda R, t, c: (R.at[0, 0].set(jnp.nan), t, c), False),
        (lambda R, t, c: (R, t.at[1].set(jnp.inf), c), False),
        (lambda R, t, c: (R, t, c.at[5, 5].set(jnp.nan)), False),
        (lambda R, t, c: (R, t, c.at[5, 5].set(jnp.inf)), False),
        (lambda R, t, c: (R, t, c.at[0, 1].set(5e-7)), False),  # not symmetric
        (lambda R, t, c: (R, t, c.at[2, 2].set(-1e-6)), False),  # indefinite
        (lambda R, t, c: (R, t, c.at[2, 2].set(0.0)), True),  # singular: one direction exact
        (lambda R, t, c: (R, t, c.at[2, 2].set(1.5)), True),  # one direction free (condition 1e6)
        (lambda R, t, c: (R, t, jnp.zeros((6, 6))), False),
        (lambda R, t, c: (R, t, c.at[0, 1].set(5e-7).at[1, 0].set(5e-7)), True),  # correlated, still PD
    ],
)
def test_a_measurement_is_usable_only_when_finite_with_a_symmetric_semidefinite_covariance(change, usable):
    R, t, cov = change(jnp.eye(3), jnp.array([0.1, 0.2, 5.0]), GOOD_COV)
    assert bool(measurement_usable(R, t, cov)) == usable
    assert bool(jax.jit(measurement_usable)(R, t, cov)) == usable


@pytest.mark.parametrize("bad", ["nan_cov", "indefinite_cov", "nan_rotation", "failed_estimate"])
def test_the_keyframe_filter_skips_and_flags_an_unusable_measurement_and_stays_finite(bad):
    chain, true_rate, _ = _drifting_chain(0.08, 1e-3, frames=76)
    frames = jnp.array([7, 25, 40])  # 25 is a keyframe switch
    if bad == "nan_cov":
        chain = eqx.tree_at(lambda c: c.relative_cov, chain, chain.relative_cov.at[frames].set(jnp.nan))
    elif bad == "indefinite_cov":
        chain = eqx.tree_at(lambda c: c.relative_cov, chain, chain.relative_cov.at[frames, 0, 0].set(-1.0))
    elif bad == "nan_rotation":
        chain = eqx.tree_at(lambda c: c.relative_rotations, chain, chain.relative_rotations.at[frames].set(jnp.nan))
    else:
        chain = eqx.tree_at(lambda c: c.status, chain, chain.status.at[frames].set(1))
    result = jax.jit(filter_keyframes, static_argnums=1)(chain, 0.04)
    assert _all_finite(result)
    expected = FILTER_NO_ESTIMATE if bad == "failed_estimate" else FILTER_BAD_MEASUREMENT
    status = np.asarray(result.filter_status)
    assert set(np.flatnonzero(status != FILTER_UPDATED)) == set(np.asarray(frames).tolist())
    assert np.all(status[np.asarray(frames)] == expected)
    # The other frames still carry the filter to the motion (exact measurements).
    assert float(jnp.linalg.norm(result.rate[-1] - true_rate[-1])) < 1e-3


def test_the_chained_filter_skips_and_flags_a_non_finite_pose():
    chain, true_rate, _ = _drifting_chain(0.08, 1e-3, frames=51)
    chain = eqx.tree_at(lambda c: c.points, chain, chain.points.at[10].set(jnp.nan))
    result = filter_chain(chain, 0.04, rotation_sigma=1e-4, point_sigma=1e-4)
    assert _all_finite(result)
    assert np.flatnonzero(np.asarray(result.filter_status) != FILTER_UPDATED).tolist() == [10]
    assert float(jnp.linalg.norm(result.rate[-1] - true_rate[-1])) < 1e-3


def test_track_needs_a_key_and_checks_its_inputs():
    cloud = jp.simulate(jp.Camera.camcube2(), jp.targets.n5(), *paper_pose("previous"))
    clouds = jax.tree.map(lambda x: jnp.stack([x, x]), cloud)
    with pytest.raises(ValueError, match="PRNG key"):
        track(clouds, 0.04)
    with pytest.raises(ValueError, match="dt"):
        track(clouds, -0.04, key=jax.random.key(0))
    with pytest.raises(ValueError, match=r"\(T ≥ 2, N, 3\)"):
        track(cloud, 0.04, key=jax.random.key(0))
    bad = eqx.tree_at(lambda c: c.points, clouds, clouds.points.at[1, 0].set(jnp.nan))
    bad = eqx.tree_at(lambda c: c.valid, bad, bad.valid.at[1, 0].set(True))
    with pytest.raises(ValueError, match="frame 1"):
        track(bad, 0.04, key=jax.random.key(0))


@pytest.mark.slow  # tracking; the default run checks the estimate's float32 path (tests/test_estimate.py)
def test_track_runs_float32_clouds_in_the_sessions_precision():
    """Under `jax_enable_x64` (the tests' setting) a float32 sequence goes through `track`'s
    Python boundary as float64 (`Cloud.floating`): it traces, and every output is finite."""
    cloud = jp.simulate(jp.Camera.camcube2(), jp.targets.n5(), *paper_pose("previous"))
    clouds = jax.tree.map(lambda x: jnp.stack([x, x]), cloud)
    single = jp.Cloud(jnp.asarray(clouds.points, jnp.float32), clouds.valid)
    result = track(single, 0.04, jp.Config.fast(), key=jax.random.key(0))
    assert result.rate.dtype == jnp.float64
    assert _all_finite(result)


def _tumble_errors(seq, result, dt):
    R = np.asarray(seq.rotations)
    attitude = np.degrees(float(jp.rotation_angle(result.attitude[-1], R[-1] @ R[0].T)))
    true_rate = np.asarray(jaxlie.SO3.from_matrix(R[-1] @ R[-2].T).log()) / dt
    rate = np.degrees(np.linalg.norm(np.asarray(result.rate[-1]) - true_rate))
    return attitude, rate


def test_random_tumbles_are_rigid_bodies_with_rates_in_range():
    for seed in range(20):
        tumble = Tumble.random(jax.random.key(seed), rates_deg_s=(0.5, 10.0))
        moments = np.sort(np.diag(np.asarray(tumble.inertia)))
        assert moments[0] + moments[1] >= moments[2] * (1 - 1e-6) and moments[0] > 0
        assert 0.5 - 1e-6 <= np.degrees(np.linalg.norm(np.asarray(tumble.rate))) <= 10.0 + 1e-6
        np.testing.assert_allclose(np.asarray(tumble.attitude @ tumble.attitude.T), np.eye(3), atol=1e-6)


@pytest.mark.parametrize(
    ("seed", "guided"),
    [(0, False), pytest.param(1, False, marks=pytest.mark.slow), pytest.param(0, True, marks=pytest.mark.slow)],
)
def test_track_with_the_default_config_on_random_tumbles_is_finite_and_near_the_truth(seed, guided):
    # Property test, short: 6 frames at 12.5 Hz of N5 (1.6 m) on a random tumble with 0–2 cm
    # range noise, through the public call with no config, plain and guided by the predicted
    # motion. Longer ones: the slow test below.
    rng = np.random.default_rng([25, seed])
    dt = 0.08
    tumble = Tumble.random(jax.random.key(100 + seed), 5.5, orbital_camera=bool(seed % 2))
    camera = jp.Camera.camcube2(noise_sigma=rng.uniform(0.0, 0.02))
    seq = simulate_sequence(camera, jp.targets.n5(), tumble, 5 * dt, 1 / dt, key=jax.random.key(seed))
    result = track(seq.clouds, dt, key=jax.random.key(seed), guided=guided)
    assert _all_finite(result)
    assert result.filter_status.shape == (6,)
    # Frames whose estimate is no success are predicted only (at 2 cm noise some registrations
    # end "not converged"); the filter must still have fused most of them.
    assert np.mean(np.asarray(result.filter_status) == FILTER_UPDATED) >= 0.5
    attitude, rate = _tumble_errors(seq, result, dt)
    # The chained attitude after 5 registrations of ≈ 0.1–0.3° each; the rate after 0.4 s is
    # known to roughly the attitude noise over the span (≈ 0.3° / 0.4 s).
    assert attitude < 0.5, attitude
    assert rate < 1.5, rate


KNOWN_TRACKING_FAILURES = {
    2: "upper stage: a registration reported as a success 6° off (near-axisymmetric target, issue 21 item 6)",
}


@pytest.mark.slow
@pytest.mark.parametrize(
    "seed",
    [
        pytest.param(seed, marks=pytest.mark.xfail(strict=True, reason=KNOWN_TRACKING_FAILURES[seed]))
        if seed in KNOWN_TRACKING_FAILURES
        else seed
        for seed in range(4)
    ],
)
def test_track_on_longer_random_tumbles_of_benchmark_targets(seed):
    names = ("n5", "satellite", "upper_stage", "fragment")
    rng = np.random.default_rng([26, seed])
    dt = 0.08
    target = getattr(jp.targets, names[seed % len(names)])()
    tumble = Tumble.random(jax.random.key(200 + seed), 6.0, orbital_camera=bool(seed % 2))
    camera = jp.Camera.camcube2(noise_sigma=rng.uniform(0.0, 0.02))
    seq = simulate_sequence(camera, target, tumble, 2.0, 1 / dt, key=jax.random.key(seed))
    result = track(seq.clouds, dt, key=jax.random.key(seed), keyframe_every=5)
    assert _all_finite(result)
    attitude, rate = _tumble_errors(seq, result, dt)
    # After 2 s the rate is known to a few tenths of a °/s (registrations of 0.1–0.5° each,
    # keyframes 0.4 s apart); the bound asks that the filter's error stay within 4 of its own
    # standard deviations (a consistent filter is within 3 almost always) and the attitude
    # within 1°.
    std = np.degrees(np.linalg.norm(np.asarray(result.rate_std[-1])))
    assert attitude < 1.0 and rate < 4 * std, (attitude, rate, std)


def _screw_pose(k, axis, centre, angle_step, advance):
    """Frame 0 → k of a constant screw motion (numpy, Rodrigues): a turn of `angle_step` per
    frame about `axis` through `centre` and an advance of `advance` m per frame along it."""
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = angle_step * k
    R = np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K
    return R, centre - R @ centre + advance * k * a


def test_predicted_motion_extrapolates_a_constant_screw_motion_exactly():
    """The last two registered frames (2 and 5, three frames apart) of a constant screw motion
    predict frame 9 against keyframe 3 exactly, as an independent Rodrigues construction gives it."""
    axis, centre = np.array([0.3, -1.0, 0.5]), np.array([0.2, 0.1, 5.5])
    pose = lambda k: _screw_pose(k, axis, centre, math.radians(0.7), 0.004)  # noqa: E731
    (R0, t0), (R1, t1), (Rk, tk), (R9, t9) = pose(2), pose(5), pose(3), pose(9)
    R, t = predicted_motion((R0, t0, jnp.asarray(2)), (R1, t1, jnp.asarray(5)), (Rk, tk), jnp.asarray(9))
    R_true = R9 @ Rk.T
    np.testing.assert_allclose(np.asarray(R), R_true, atol=1e-9)
    np.testing.assert_allclose(np.asarray(t), t9 - R_true @ tk, atol=1e-9)
    # With nothing registered but frame 0 (base and last both frame 0) it predicts rest.
    eye, zero = np.eye(3), np.zeros(3)
    R, t = predicted_motion((eye, zero, jnp.asarray(0)), (eye, zero, jnp.asarray(0)), (eye, zero), jnp.asarray(4))
    np.testing.assert_allclose(np.asarray(R), eye, atol=1e-12)
    np.testing.assert_allclose(np.asarray(t), zero, atol=1e-12)


def _hypotheses_at(degrees, distinct):
    about_z = jnp.stack([jaxlie.SO3.from_z_radians(math.radians(d)).as_matrix() for d in degrees])
    k = len(degrees)
    return jp.Hypotheses(jnp.zeros((k, 6)), about_z, jnp.zeros((k, 3)), jnp.ones(k), jnp.asarray(distinct))


@pytest.mark.parametrize(
    ("predicted_deg", "status", "distinct", "chosen", "resolved"),
    [
        (2.9, AMBIGUOUS, [True, True], 1, True),  # the alternative, 0.1° from the prediction
        (0.2, AMBIGUOUS, [True, True], 0, True),
        (1.4, AMBIGUOUS, [True, True], 0, False),  # nearest more than 0.5° away: unresolved
        (2.9, AMBIGUOUS, [True, False], 0, False),  # a repeat is never chosen
        (2.9, SUCCESS, [True, True], 0, False),  # a success needs no continuity
        (0.9, LOW_SCORE, [True, True], 0, True),  # a weak estimate within 1° of the prediction
        (1.1, NOT_CONVERGED, [True, False], 0, False),  # … and not beyond
        (0.9, NOT_CONVERGED, [True, False], 0, True),
        (2.9, LOW_SCORE, [True, True], 0, False),  # never its alternative
        (0.0, DEGENERATE, [True, False], 0, False),  # nor a degenerate or non-finite one
        (0.0, NON_FINITE, [True, False], 0, False),
    ],
)
def test_continuity_chooses_the_hypothesis_nearest_the_prediction(predicted_deg, status, distinct, chosen, resolved):
    hypotheses = _hypotheses_at([0.0, 3.0], distinct)
    R_pred = jaxlie.SO3.from_z_radians(math.radians(predicted_deg)).as_matrix()
    j, ok = continuity_choice(hypotheses, jnp.asarray(status), R_pred, jp.Config())
    assert int(j) == chosen and bool(ok) == resolved


@pytest.mark.parametrize(
    ("predicted_deg", "spread_deg", "resolved"),
    [
        (1.5, 0.6, True),  # within 3 standard deviations of the extrapolation error
        (1.5, 0.4, False),  # … and not beyond
        (0.9, 0.1, True),  # the 1° gate is the narrowest
        (2.9, 1.0, True),
        (3.5, 5.0, False),  # never beyond WEAK_MAX_DEG
    ],
)
def test_a_weak_estimate_is_accepted_within_the_extrapolation_error(predicted_deg, spread_deg, resolved):
    hypotheses = _hypotheses_at([0.0, 3.0], [True, True])
    R_pred = jaxlie.SO3.from_z_radians(math.radians(predicted_deg)).as_matrix()
    _, ok = continuity_choice(hypotheses, jnp.asarray(LOW_SCORE), R_pred, jp.Config(), math.radians(spread_deg))
    assert bool(ok) == resolved


@pytest.mark.parametrize(
    ("fits_deg", "predicted_deg", "spread_deg", "chosen", "resolved"),
    [
        ([0.0, 15.0], 1.5, 0.6, 0, True),  # within 3 standard deviations, the other fit 9× as far
        ([0.0, 15.0], 1.5, 0.4, 0, False),  # beyond them
        ([0.0, 15.0], 13.5, 5.0, 1, True),  # the alternative; the gate stops at WEAK_MAX_DEG
        ([0.0, 15.0], 11.0, 5.0, 1, False),  # 4° from the nearest: beyond WEAK_MAX_DEG
        ([0.0, 3.0], 1.2, 1.0, 0, False),  # the other fit only 1.5× as far: no clear choice
        ([0.0, 3.0], 0.4, 1.0, 0, True),  # the fixed 0.5° gate needs no clear choice
    ],
)
def test_an_ambiguous_estimate_is_resolved_within_the_extrapolation_error_when_the_choice_is_clear(
    fits_deg, predicted_deg, spread_deg, chosen, resolved
):
    hypotheses = _hypotheses_at(fits_deg, [True, True])
    R_pred = jaxlie.SO3.from_z_radians(math.radians(predicted_deg)).as_matrix()
    j, ok = continuity_choice(hypotheses, jnp.asarray(AMBIGUOUS), R_pred, jp.Config(), math.radians(spread_deg))
    assert bool(ok) == resolved
    if resolved:
        assert int(j) == chosen


def test_the_prediction_spread_grows_with_the_frames_ahead_over_the_baseline():
    """σ √(2a (1 + a)), a = (k − last) / (last − base): one frame ahead of a one-frame
    baseline 2σ, four ahead √40 σ, one ahead of a hundred-frame baseline ≈ 0.14σ; nothing
    registered since frame 0: 0."""
    assert float(prediction_spread(1.0, 2, 1, 0)) == pytest.approx(2.0)
    assert float(prediction_spread(1.0, 5, 1, 0)) == pytest.approx(math.sqrt(40))
    assert float(prediction_spread(1.0, 101, 100, 0)) == pytest.approx(math.sqrt(2 * 0.01 * 1.01))
    assert float(prediction_spread(0.5, 7, 0, 0)) == 0.0


def test_the_anchor_moves_its_weight_of_the_way_along_the_screw_from_the_prediction():
    """Weight 0 keeps the predicted motion, 1 takes the registered one, and 0.25 of the way
    between two frames of a constant screw motion is that motion a quarter of a frame on."""
    axis, centre = np.array([0.3, -1.0, 0.5]), np.array([0.2, 0.1, 5.5])
    pose = lambda k: _screw_pose(k, axis, centre, math.radians(2.0), 0.01)  # noqa: E731
    predicted, registered = pose(4.0), pose(5.0)
    for weight, expected in ((0.0, predicted), (1.0, registered), (0.25, pose(4.25))):
        R, t = anchored_motion(predicted, registered, weight)
        np.testing.assert_allclose(np.asarray(R), expected[0], atol=1e-9)
        np.testing.assert_allclose(np.asarray(t), expected[1], atol=1e-9)


def test_the_anchor_weight_is_a_running_mean_first_and_follows_a_drifted_prediction():
    """1 / count over the first registrations, `ANCHOR_WEIGHT` on a long baseline one frame
    ahead, and the extrapolation's share 2a(1 + a) / (1 + 2a(1 + a)) after missed frames."""
    assert float(anchor_weight(1, 1, 0, 0)) == 1.0
    assert float(anchor_weight(2, 2, 1, 0)) == pytest.approx(0.8)  # a = 1 outweighs 1/2
    assert float(anchor_weight(3, 41, 40, 0)) == pytest.approx(1 / 3)
    assert float(anchor_weight(50, 41, 40, 0)) == pytest.approx(ANCHOR_WEIGHT)
    share = 2 * 0.5 * 1.5 / (1 + 2 * 0.5 * 1.5)  # 20 frames ahead of a 40-frame baseline
    assert float(anchor_weight(50, 60, 40, 0)) == pytest.approx(share)


def test_an_anchor_of_noisy_registrations_is_nearer_the_motion_than_the_last_registration():
    """The anchor recurrence of `chain_estimates` (`predicted_motion` from frame 0 and the
    anchor, `anchored_motion` by `anchor_weight`) on 200 registrations of a constant screw
    motion with independent rotation errors of 0.3° (each axis): its error has the standard
    deviation √(w / (2 − w)) ≈ 0.38 of the registrations' at w = 0.25, and anything above 0.6
    means the anchor does not average."""
    rng = np.random.default_rng(7)
    axis, centre = np.array([0.3, -1.0, 0.5]), np.array([0.2, 0.1, 5.5])
    pose = lambda k: _screw_pose(k, axis, centre, math.radians(0.2), 0.001)  # noqa: E731
    eye, zero = np.eye(3), np.zeros(3)
    base = (jnp.asarray(eye), jnp.asarray(zero), jnp.asarray(0))
    anchor, last_k = (jnp.asarray(eye), jnp.asarray(zero)), 0
    raw_errors, anchor_errors = [], []
    for k in range(1, 201):
        R_true, t_true = pose(k)
        noise = jaxlie.SO3.exp(jnp.asarray(rng.normal(0.0, math.radians(0.3), 3))).as_matrix()
        registered = (noise @ jnp.asarray(R_true), jnp.asarray(t_true))
        predicted = predicted_motion(base, (*anchor, jnp.asarray(last_k)), (eye, zero), jnp.asarray(k))
        anchor = anchored_motion(predicted, registered, anchor_weight(k, k, last_k, 0))
        last_k = k
        if k > 20:
            raw_errors.append(float(jp.rotation_angle(registered[0], jnp.asarray(R_true))))
            anchor_errors.append(float(jp.rotation_angle(anchor[0], jnp.asarray(R_true))))
    ratio = math.sqrt(np.mean(np.square(anchor_errors)) / np.mean(np.square(raw_errors)))
    assert ratio < 0.6, ratio


def test_an_update_whose_covariance_is_not_semidefinite_is_refused():
    """A filter whose updated covariance came out with a negative variance (float32
    round-off) keeps its prediction, flagged as a bad update, so no standard deviation is NaN."""
    predicted = TrackFilter.start(jnp.zeros(3))
    broken = eqx.tree_at(lambda f: f.cov, predicted, predicted.cov.at[4, 4].set(-1e-3))
    ok = jnp.asarray(True)
    kept, code = _guarded_update(predicted, predicted, broken, ok, ok, ok)
    assert int(code) == FILTER_BAD_UPDATE
    np.testing.assert_array_equal(np.asarray(kept.cov), np.asarray(predicted.cov))
    assert not bool(covariance_usable(broken.cov)) and bool(covariance_usable(predicted.cov))


def test_a_keyframe_switch_waits_for_the_first_registered_frame_once_due():
    """Keyframes every 5 frames; frames 5 and 6 are missed, so the switch comes at 7, and the
    next one is due at 12, not at 10."""
    registered = np.ones(16, bool)
    registered[[5, 6]] = False
    key_k, switches = 0, []
    for k in range(1, 16):
        if bool(keyframe_switch(jnp.asarray(k), jnp.asarray(key_k), 5, jnp.asarray(registered[k]))):
            key_k = k
            switches.append(k)
    assert switches == [7, 12]


def test_a_keyframe_switch_is_due_once_the_motion_reaches_its_share_of_the_box():
    """The motion from the keyframe is due a switch once any component of p uses
    `keyframe_reach` of the search box (±20°, ±0.10 m by default); the switch still waits for
    a registered frame, and None or a config without a box search never reaches."""
    config = jp.Config()
    box = np.array([config.search.angle_box] * 3 + [config.search.shift_box] * 3)
    for component in range(6):
        for share, expected in ((0.49, False), (0.51, True)):
            p = np.zeros(6)
            p[component] = -share * box[component]
            assert bool(motion_reached(jnp.asarray(p), config, 0.5)) is expected
    far = jnp.asarray(0.9 * box)
    assert not bool(motion_reached(far, config, None))
    assert not bool(motion_reached(far, jp.Config.capture(), 0.5))
    k, key_k = jnp.asarray(3), jnp.asarray(0)
    assert bool(keyframe_switch(k, key_k, 100, jnp.asarray(True), jnp.asarray(True)))
    assert not bool(keyframe_switch(k, key_k, 100, jnp.asarray(False), jnp.asarray(True)))
    assert not bool(keyframe_switch(k, key_k, 100, jnp.asarray(True), jnp.asarray(False)))


def test_round_off_indefiniteness_is_repaired_and_a_fault_is_not():
    """`nearest_semidefinite` returns a usable covariance bit for bit, lifts an eigenvalue that
    round-off made slightly negative (the result is usable, with a non-negative diagonal and
    within the floor of the original), and leaves a grossly indefinite one for the checks to
    refuse."""
    rng = np.random.default_rng(0)
    basis, _ = np.linalg.qr(rng.normal(size=(21, 21)))
    eig = np.logspace(-12, -1, 21)
    good = (basis * eig) @ basis.T
    np.testing.assert_array_equal(np.asarray(nearest_semidefinite(jnp.asarray(good))), good)
    for negative, repaired in ((-1e-4, True), (-1e-2, False)):
        bad = good + negative * 0.1 * np.outer(basis[:, 0], basis[:, 0]) - 1e-12 * np.outer(basis[:, 0], basis[:, 0])
        assert not bool(covariance_usable(jnp.asarray(bad)))
        fixed = np.asarray(nearest_semidefinite(jnp.asarray(bad)))
        if repaired:
            assert bool(covariance_usable(jnp.asarray(fixed)))
            assert np.all(np.diag(fixed) >= 0)
            np.testing.assert_allclose(fixed, bad, atol=2e-5)
        else:
            np.testing.assert_array_equal(fixed, bad)


def test_a_slightly_indefinite_update_is_repaired_and_fused():
    """An update whose covariance round-off left slightly indefinite is repaired and fused,
    where it used to be refused (and the filter then kept predicting from a covariance that was
    no longer semi-definite)."""
    predicted = TrackFilter.start(jnp.zeros(3))
    eig, vec = np.linalg.eigh(np.asarray(predicted.cov))
    nudged = predicted.cov - 1e-4 * eig[-1] * jnp.asarray(np.outer(vec[:, 0], vec[:, 0]))
    updated = eqx.tree_at(lambda f: f.cov, predicted, nudged)
    assert not bool(covariance_usable(updated.cov))
    ok = jnp.asarray(True)
    kept, code = _guarded_update(predicted, predicted, updated, ok, ok, ok)
    assert int(code) == FILTER_UPDATED
    assert bool(covariance_usable(kept.cov))
    assert np.all(np.isfinite(np.asarray(_row(kept)[-1])))


def _benchmark_tumble_tracked(index, target, sigma, duration):
    """Tumble `index` of `experiments/tracking_benchmark.py` (its `draw_tumble` and
    `simulate_tumble`: key 1000 + index, 6 m, the camera orbital for odd indices, range noise
    `sigma` m at 5 m) seen for `duration` s at 25 Hz and tracked with the default config, in
    float32 as the benchmark runs. Returns (sequence, track)."""
    with jax.enable_x64(False):
        key = jax.random.key(1000 + index)
        tumble = Tumble.random(jax.random.fold_in(key, 0), distance=6.0, orbital_camera=bool(index % 2))
        camera = jp.Camera.camcube2(noise_sigma=sigma, noise_range_ref=5.0)
        seq = simulate_sequence(camera, target, tumble, duration, 25.0, key=jax.random.fold_in(key, 1))
        return seq, track(seq.clouds, 0.04, key=jax.random.fold_in(key, 2))


@pytest.mark.slow
def test_the_noise_free_tumble_whose_covariance_lost_definiteness_stays_finite():
    """The tracking benchmark's tumble 20 (`experiments/tracking_benchmark.py`, second draw):
    N5, noise-free, inertial camera, 10 s at 25 Hz. Before round-off was repaired, 217 of its
    251 updates were refused and `rate_std` was NaN from frame 36 on. In float32, as the
    benchmark runs: the round-off is float32's."""
    _, result = _benchmark_tumble_tracked(20, jp.targets.n5(), 0.0, 10.0)
    assert result.rate_std.dtype == jnp.float32
    assert _all_finite(result)
    assert np.mean(np.asarray(result.filter_status) == FILTER_UPDATED) >= 0.95


@pytest.mark.slow
def test_a_track_whose_registrations_are_all_weak_keeps_registering():
    """The tracking benchmark's tumble 19 (`experiments/tracking_benchmark.py`): the fragment
    at 2 cm of range noise, 6 m from a camera fixed in the orbital frame, 25 Hz, the first
    3 s. Its registrations are all weak (low score). With the 1° continuity gate alone, one
    accepted frame set a constant-rate prediction that refused every later one (2 of 251
    frames registered over 10 s); the extrapolation gate (`prediction_spread`) keeps it. In
    float32, as the benchmark runs."""
    seq, result = _benchmark_tumble_tracked(19, jp.targets.fragment(), 0.02, 3.0)
    registered = np.asarray(result.registered())
    assert _all_finite(result)
    attitude, _ = _tumble_errors(seq, result, 0.04)
    assert registered.mean() > 0.5 and attitude < 2.0, (registered.sum(), attitude)


@pytest.mark.slow
def test_a_track_whose_last_registration_erred_keeps_registering():
    """The tracking benchmark's tumble 54 (`experiments/tracking_benchmark.py`, third draw):
    the fragment at 1 cm of range noise, inertial camera, 25 Hz, the first 4 s. Its frame 39
    registered 1.3° off; with the prediction anchored on the last registration alone, the
    good weak estimates that followed lay 1–2.9° from it and every later frame was refused
    (37 of 251 registered over 10 s, 10.9 °/s at the end). Carried on from the anchor
    (`anchored_motion`) after a refused frame, the prediction keeps the track. In float32, as
    the benchmark runs."""
    seq, result = _benchmark_tumble_tracked(54, jp.targets.fragment(), 0.01, 4.0)
    registered = np.asarray(result.registered())
    assert _all_finite(result)
    attitude, _ = _tumble_errors(seq, result, 0.04)
    assert registered[40:].mean() > 0.8 and attitude < 1.5, (registered.sum(), attitude)
