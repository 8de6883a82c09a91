"""`identify`: Euler's equations fitted to a tracked motion (torque-free, inertial camera).

Exact measurements come from the simulator's own integration of the tumble (`tumble_poses`,
diffrax Dopri8 on the full inertia tensor), independent of the identification's model
(Tsit5 in principal axes)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import optimistix as optx
import pytest

import jaxpose as jp
from jaxpose.sim import Tumble
from jaxpose.sim._sequence import C_FROM_O, tumble_poses
from jaxpose.tracking._identify import (
    CENTRE_FREE_STD,
    START_MIXES,
    body_rates,
    decorrelated,
    identify_motion,
    inertia_candidates,
    linear_start,
    shared_variance_ratio,
)
from jaxpose.tracking._track import Track, keyframe_indices

DT, SECONDS, KEYFRAME_EVERY = 0.1, 30.0, 10


def tumble(seed: int, spin_axis=None) -> Tumble:
    """A random torque-free tumble (3–8 °/s), the centre drifting at a few cm/s."""
    base = Tumble.random(jax.random.key(seed), rates_deg_s=(3.0, 8.0))
    base = eqx.tree_at(lambda t: t.velocity, base, jnp.array([0.01, -0.02, 0.005]))
    if spin_axis is not None:  # a spin about one principal axis: nothing excites the inertia
        base = eqx.tree_at(lambda t: t.rate, base, jnp.radians(5.0) * jnp.asarray(spin_axis, float))
    return base


def truth(target: Tumble, times):
    """The motions from the first frame (R_k, t_k), and the dynamics in frame c at t = 0."""
    G, positions, rates = tumble_poses(target, times)
    R = jnp.einsum("tij,kj->tik", G, G[0])
    t = positions - jnp.einsum("tij,j->ti", R, positions[0])
    moments = jnp.diag(target.inertia)
    order = jnp.argsort(moments)
    return R, t, G[0][:, order], moments[order] / moments[order][2], positions[0], G[0] @ rates[0]


def measurements(target: Tumble):
    times = jnp.arange(int(round(SECONDS / DT)) + 1) * DT
    R, t, *expected = truth(target, times)
    switched = jnp.arange(times.shape[0]) % KEYFRAME_EVERY == 0
    return times, R, t, keyframe_indices(switched), expected


def axis_angles(found, expected):
    """Angle (rad) between each found principal axis and the true one (sign-free)."""
    cosines = jnp.abs(jnp.sum(found * expected, axis=0))
    return np.arccos(np.clip(np.asarray(cosines), -1.0, 1.0))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exact_measurements_recover_the_dynamics(seed):
    target = tumble(seed)
    times, R, t, references, (axes, moments, centre, omega) = measurements(target)
    valid = jnp.ones(times.shape[0], bool)
    d = identify_motion(times, R, t, valid, references, None, 5)
    np.testing.assert_allclose(d.inertia_ratios, moments[:2], rtol=1e-4)
    assert axis_angles(d.principal_axes, axes).max() < 1e-4
    np.testing.assert_allclose(d.omega, omega, atol=1e-7)
    np.testing.assert_allclose(d.centre, centre, atol=1e-6)
    np.testing.assert_allclose(d.velocity, target.velocity, atol=1e-7)
    assert bool(d.observable) and float(d.excitation) > np.radians(2)
    assert np.isclose(float(jnp.linalg.det(d.principal_axes)), 1.0)
    assert bool(jnp.all(jnp.isfinite(d.covariance)))


def test_the_linear_start_is_the_candidate_of_least_cost():
    target = tumble(1)
    times, R, _, _, (axes, moments, _, _) = measurements(target)
    valid = jnp.ones(times.shape[0], bool)
    rates, ok = body_rates(times, R, valid, 5)
    candidate_axes, candidate_moments = inertia_candidates(R, rates, ok)
    assert candidate_axes.shape == (START_MIXES, 3, 3) and candidate_moments.shape == (START_MIXES, 3)
    goal = candidate_moments[7]
    cost = lambda a, m, w: jnp.where(jnp.allclose(m, candidate_moments[3]), jnp.nan, jnp.sum((m - goal) ** 2))  # noqa: E731
    start_axes, start_moments, start_omega = linear_start(times, R, valid, 5, cost)
    np.testing.assert_allclose(start_moments, goal)
    np.testing.assert_allclose(start_axes, candidate_axes[7])
    # A non-finite cost is never the least.
    nan_first = lambda a, m, w: jnp.where(jnp.allclose(m, candidate_moments[0]), jnp.nan, 1.0)  # noqa: E731
    assert not np.allclose(linear_start(times, R, valid, 5, nan_first)[1], candidate_moments[0])
    np.testing.assert_allclose(start_omega, rates[jnp.argmax(ok)])
    # The first candidate is the least-squares tensor (the smallest singular vector alone),
    # near the truth on exact measurements (centred differences over ±0.5 s bias the rates,
    # and the ratios by about 1.4 %).
    least_axes, least_moments = (part[0] for part in inertia_candidates(R, rates, ok, 1))
    np.testing.assert_allclose(candidate_moments[0], least_moments)
    np.testing.assert_allclose(candidate_axes[0], least_axes)
    np.testing.assert_allclose(least_moments[:2], moments[:2], rtol=0.03)
    assert axis_angles(least_axes, axes).max() < np.radians(1.0)


def test_prediction_past_the_data_follows_the_truth():
    target = tumble(0)
    times, R, t, references, (_, _, centre, _) = measurements(target)
    d = identify_motion(times, R, t, jnp.ones(times.shape[0], bool), references, None, 5)
    later = jnp.array([0.0, 10.0, SECONDS, SECONDS + 10.0])
    R_true, t_true, *_ = truth(target, later)
    R_pred, t_pred = d.predict(later)
    angles = [float(jp.rotation_angle(a, b)) for a, b in zip(R_pred, R_true, strict=True)]
    assert max(angles) < 1e-6
    np.testing.assert_allclose(t_pred, t_true, atol=1e-6)
    # A point 1 m from the centre: its path 10 s past the data, with a finite spread.
    point = centre + jnp.array([1.0, 0.0, 0.0])
    positions, std = d.predict_point(point, later)
    np.testing.assert_allclose(positions, R_true @ point + t_true, atol=1e-6)
    assert positions.shape == std.shape == (4, 3) and bool(jnp.all(jnp.isfinite(std)))


def dynamics_of(target: Tumble, orbit=None) -> jp.Dynamics:
    """The true dynamics of a tumble as a `Dynamics` (no fit): what `identify` should find."""
    _, _, axes, moments, centre, omega = truth(target, jnp.zeros(1))
    axes = axes.at[:, 2].multiply(jnp.linalg.det(axes))  # sorting the moments may leave it improper
    zero = jnp.zeros(())
    return jp.Dynamics(
        moments[:2], axes, centre, target.velocity, omega, jnp.zeros((14, 14)), jnp.asarray(True),
        zero, zero, zero, optx.RESULTS.successful, jnp.asarray(0), orbit,
    )  # fmt: skip


def test_the_rates_are_the_simulators_apparent_rates():
    """`Dynamics.rates` of the true dynamics against the simulator's own integration: with an
    inertial camera its body rates turned into the camera frame (G ω_b); with the chaser fixed
    in the orbital frame, centred differences of its poses, log(G(t+h) G(t−h)ᵀ) / 2h."""
    times = jnp.array([0.0, 7.5, 30.0, 45.0])
    inertial = tumble(1)
    G, _, body = tumble_poses(inertial, times)
    expected = jnp.einsum("tij,tj->ti", G, body)
    np.testing.assert_allclose(dynamics_of(inertial).rates(times), expected, atol=1e-8)

    orbiting = Tumble.random(jax.random.key(5), rates_deg_s=(3.0, 8.0), orbital_camera=True)
    orbit = jp.Orbit(jnp.asarray(orbiting.orbit_rate), C_FROM_O)
    h = 1e-3
    ahead, *_ = tumble_poses(orbiting, times + h)
    behind, *_ = tumble_poses(orbiting, jnp.maximum(times - h, 0.0))
    steps = jnp.where(times > 0, 2 * h, h)
    differences = jax.vmap(lambda a, b: jaxlie.SO3.from_matrix(a @ b.T).log())(ahead, behind) / steps[:, None]
    rates = dynamics_of(orbiting, orbit).rates(times)
    np.testing.assert_allclose(rates[1:], differences[1:], atol=1e-8)  # centred: O(h²)
    np.testing.assert_allclose(rates[0], differences[0], atol=1e-5)  # one-sided at t = 0: O(h)
    # Beyond the body's own rate turned into the camera frame, the camera's turn at the orbit rate.
    G, _, body = tumble_poses(orbiting, times)
    camera_turn = jnp.linalg.norm(rates - jnp.einsum("tij,tj->ti", G, body), axis=1)
    np.testing.assert_allclose(camera_turn, orbiting.orbit_rate, rtol=1e-6)


def test_noisy_measurements_give_an_honest_covariance():
    """1 mrad of rotation noise per frame: the ratios land within a few of their standard
    deviations, and the standard deviations are not zero."""
    target = tumble(0)
    times, R, t, references, (axes, moments, _, _) = measurements(target)
    noise = jax.random.normal(jax.random.key(7), (times.shape[0], 3)) * 1e-3
    noisy = jax.vmap(lambda v, M: jaxlie.SO3.exp(v).as_matrix() @ M)(noise, R)
    d = identify_motion(times, noisy, t, jnp.ones(times.shape[0], bool), references, None, 5)
    std = np.sqrt(np.diag(np.asarray(d.covariance)))[3:5]
    assert np.all(std > 0)
    assert np.all(np.abs(np.asarray(d.inertia_ratios - moments[:2])) < 5 * std + 1e-3)


def test_spin_about_a_principal_axis_is_not_observable():
    target = tumble(1, spin_axis=(0.0, 0.0, 1.0))  # body z is a principal axis (diagonal inertia)
    times, R, t, references, _ = measurements(target)
    d = identify_motion(times, R, t, jnp.ones(times.shape[0], bool), references, None, 5)
    assert not bool(d.observable)
    assert float(d.excitation) < np.radians(0.1)


def test_a_spins_centre_is_fitted_across_its_axis_and_left_open_along_it():
    """A spin about a principal axis turns every point of the axis onto the axis, so no motion
    fixes the centre along it: with a guess 30 cm off along the axis, the centre is exact across
    it and at the guess along it, with a standard deviation of `CENTRE_FREE_STD` there."""
    target = tumble(1, spin_axis=(0.0, 0.0, 1.0))
    times, R, t, references, (_, _, centre, omega) = measurements(target)
    axis = omega / jnp.linalg.norm(omega)
    guess = centre + 0.3 * axis + jnp.array([0.2, -0.1, 0.05]) - (jnp.array([0.2, -0.1, 0.05]) @ axis) * axis
    d = identify_motion(times, R, t, jnp.ones(times.shape[0], bool), references, None, 5, centre_guess=guess)
    error = np.asarray(d.centre - centre)
    np.testing.assert_allclose(error @ np.asarray(axis), 0.3, atol=1e-6)
    np.testing.assert_allclose(error - (error @ np.asarray(axis)) * np.asarray(axis), 0.0, atol=1e-6)
    along = float(axis @ d.covariance[8:11, 8:11] @ axis)
    np.testing.assert_allclose(np.sqrt(along), CENTRE_FREE_STD, rtol=1e-6)


def test_the_registrations_covariances_weigh_the_centres_residuals():
    """Each translation measured with a slide of 2 cm along its own random direction, and a
    covariance that says so (2 cm along it, 0.1 mm across): weighted by the covariances, the
    centre comes out within 0.1 mm and within 4 of its standard deviations per axis; with equal
    weights it is at least five times farther off."""
    target = tumble(0)
    times, R, t, _, (_, _, centre, _) = measurements(target)
    T = times.shape[0]
    k1, k2 = jax.random.split(jax.random.key(11))
    direction = jax.random.normal(k1, (T, 3))
    direction = direction / jnp.linalg.norm(direction, axis=1, keepdims=True)
    slides = (0.02 * jax.random.normal(k2, (T,)))[:, None] * direction
    slid = t + slides.at[0].set(0.0)  # frame 0 is the reference, measured exactly
    cov = jnp.zeros((T, 6, 6))
    cov = cov.at[:, :3, :3].set(1e-10 * jnp.eye(3))
    cov = cov.at[:, 3:, 3:].set(1e-8 * jnp.eye(3)[None] + 4e-4 * jnp.einsum("ti,tj->tij", direction, direction))
    valid = jnp.ones(T, bool)
    weighted = identify_motion(times, R, slid, valid, None, cov[:, :3, :3], 5, motion_cov=cov)
    # Equal weights; the rotations' covariances are all alike, so leaving them out changes no
    # fit and reuses the program of the other tests' unweighted calls.
    equal = identify_motion(times, R, slid, valid, None, None, 5)
    error = np.asarray(weighted.centre - centre)
    std = np.sqrt(np.diag(np.asarray(weighted.covariance))[8:11])
    assert np.linalg.norm(error) < 1e-4
    assert np.all(np.abs(error) < 4 * std)
    assert np.linalg.norm(np.asarray(equal.centre - centre)) > 5 * np.linalg.norm(error)


def test_identify_checks_its_input():
    T = 40
    eye = jnp.broadcast_to(jnp.eye(3), (T, 3, 3))
    zeros = jnp.zeros((T, 3))
    status = jnp.zeros(T, jnp.int32).at[5:].set(2)  # 5 successes only
    track = Track.of_measurements(eye, zeros, jnp.zeros(T, jnp.int32), jnp.broadcast_to(jnp.eye(6), (T, 6, 6)), status)
    with pytest.raises(ValueError, match="dt"):
        jp.identify(track, -1.0)
    with pytest.raises(ValueError, match="at least"):
        jp.identify(track, 0.1)
    short = jax.tree.map(lambda x: x[:6], track)
    short = eqx.tree_at(lambda tr: tr.status, short, jnp.zeros(6, jnp.int32))
    with pytest.raises(ValueError, match="at least|too short"):
        jp.identify(short, 0.1)


@pytest.mark.slow  # a second compile of the whole fit; `_identify_motion` is itself jitted
def test_identify_runs_under_jit():
    target = tumble(2)
    times, R, t, references, (_, moments, _, _) = measurements(target)
    fn = jax.jit(lambda R_, t_: identify_motion(times, R_, t_, jnp.ones(times.shape[0], bool), references))
    d = fn(R, t)
    np.testing.assert_allclose(d.inertia_ratios, moments[:2], rtol=1e-4)


def test_decorrelation_whitens_a_keyframes_shared_error():
    """Within a keyframe's n frames the errors have covariance I + ρ 11ᵀ; `decorrelated` is
    its inverse square root, so the transformed errors have covariance I. Frames not used
    (the keyframe itself) are left out and come back as zeros."""
    n, ratio = 5, 2.5
    references = jnp.zeros(n + 1, jnp.int32)
    used = jnp.arange(n + 1) > 0
    columns = []
    for i in range(n):
        r = jnp.zeros((n + 1, 3)).at[i + 1, 0].set(1.0)
        columns.append(decorrelated(r, used, references, jnp.asarray(ratio))[:, 0])
    W = jnp.stack(columns, axis=1)  # (n + 1, n): frame ← used frame
    assert float(jnp.abs(W[0]).max()) == 0.0
    W = W[1:]
    covariance = jnp.eye(n) + ratio * jnp.ones((n, n))
    np.testing.assert_allclose(W @ covariance @ W.T, jnp.eye(n), atol=1e-12)


def test_shared_variance_ratio_is_estimated_from_residuals():
    """40 keyframes of 12 frames: a shared error of σ_s = 2 per keyframe and σ_w = 1 per
    frame (ρ = 4); with no shared error, ρ ≈ 0."""
    groups, per = 40, 12
    references = jnp.repeat(jnp.arange(groups) * per, per)
    used = references != jnp.arange(groups * per)
    k1, k2 = jax.random.split(jax.random.key(3))
    shared = 2.0 * jax.random.normal(k1, (groups * per, 3))[references]
    own = jax.random.normal(k2, (groups * per, 3))
    assert 3.0 < float(shared_variance_ratio(shared + own, used, references)) < 5.0
    assert float(shared_variance_ratio(own, used, references)) < 0.1


def test_the_orbits_camera_turn_is_the_simulators():
    """A target at rest in inertial space with a spherical inertia (no gravity-gradient
    torque), seen from the simulator's chaser fixed in the orbital frame: its apparent motion
    is the camera's turn alone."""
    still = eqx.tree_at(
        lambda t: (t.rate, t.inertia), Tumble.random(jax.random.key(4), orbital_camera=True), (jnp.zeros(3), jnp.eye(3))
    )
    times = jnp.array([0.0, 300.0, 1200.0])
    R, *_ = truth(still, times)
    orbit = jp.Orbit(jnp.asarray(still.orbit_rate), C_FROM_O)
    np.testing.assert_allclose(orbit.camera_turn(times), R, atol=1e-9)
    assert float(jp.rotation_angle(R[-1], jnp.eye(3))) > 1.0  # 20 minutes of orbit: a real turn


@pytest.mark.slow  # ≈ 30 s on a clean clone; the camera's turn is checked in the default run
def test_an_orbiting_camera_and_the_gravity_gradient_are_identified():
    """Exact measurements from the simulator's chaser fixed in the orbital frame, with the
    gravity-gradient torque: `identify_motion` with the orbit recovers the dynamics; taking the
    camera as inertial does not."""
    target = eqx.tree_at(
        lambda t: t.velocity,
        Tumble.random(jax.random.key(5), rates_deg_s=(3.0, 8.0), orbital_camera=True),
        jnp.zeros(3),
    )
    times, R, t, references, (axes, moments, centre, omega) = measurements(target)
    valid = jnp.ones(times.shape[0], bool)
    orbit = jp.Orbit(jnp.asarray(target.orbit_rate), C_FROM_O)
    d = identify_motion(times, R, t, valid, references, None, 5, orbit=orbit)
    np.testing.assert_allclose(d.inertia_ratios, moments[:2], rtol=1e-4)
    assert axis_angles(d.principal_axes, axes).max() < 1e-4
    later = jnp.array([0.0, float(times[-1]) + 10.0])
    R_pred, _ = d.predict(later)
    R_true, *_ = truth(target, later)
    assert float(jp.rotation_angle(R_pred[1], R_true[1])) < 1e-5
    inertial = identify_motion(times, R, t, valid, references, None, 5)
    assert float(jnp.max(jnp.abs(inertial.inertia_ratios / moments[:2] - 1))) > 1e-3


def test_a_slowly_varying_error_is_covered_by_the_standard_deviations():
    """Every frame measured from the first (a track against a body-frame model) with an error
    that wanders over tens of seconds, 0.3° at most, beside 1 mrad of white noise: the
    residuals are correlated in time, so they count as fewer independent ones. The ratios'
    standard deviations cover their errors: never a confident wrong answer."""
    target = tumble(0)
    times, R, t, _, (_, moments, _, _) = measurements(target)
    phases = jnp.array([0.3, 1.7, 2.9])
    periods = jnp.array([23.0, 17.0, 29.0])
    slow = jnp.radians(0.3) * jnp.sin(2 * jnp.pi * times[:, None] / periods[None] + phases[None])
    white = jax.random.normal(jax.random.key(3), (times.shape[0], 3)) * 1e-3
    measured = jax.vmap(lambda v, M: jaxlie.SO3.exp(v).as_matrix() @ M)(slow + white, R)
    references = jnp.zeros(times.shape[0], jnp.int32)
    d = identify_motion(times, measured, t, jnp.ones(times.shape[0], bool), references, None, 5)
    std = np.sqrt(np.diag(np.asarray(d.covariance)))[3:5]
    error = np.abs(np.asarray(d.inertia_ratios - moments[:2]))
    assert np.all(error < 3 * std), (error, std, bool(d.observable))


def test_a_slowly_varying_translation_error_is_covered_by_the_centres_standard_deviations():
    """Every frame measured from the first with a translation error that wanders over tens of
    seconds, 1 cm at most, beside 1 mm of white noise: the centre of mass's standard
    deviations cover its error (the split check, `_split_inflation`)."""
    target = tumble(0)
    times, R, t, _, (_, _, centre, _) = measurements(target)
    phases = jnp.array([0.5, 2.1, 1.1])
    periods = jnp.array([19.0, 27.0, 23.0])
    slow = 0.01 * jnp.sin(2 * jnp.pi * times[:, None] / periods[None] + phases[None])
    white = jax.random.normal(jax.random.key(5), (times.shape[0], 3)) * 1e-3
    references = jnp.zeros(times.shape[0], jnp.int32)
    d = identify_motion(times, R, t + slow + white, jnp.ones(times.shape[0], bool), references, None, 5)
    std = np.sqrt(np.diag(np.asarray(d.covariance)))[8:11]
    error = np.abs(np.asarray(d.centre - centre))
    assert np.all(error < 3 * std), (error, std)
