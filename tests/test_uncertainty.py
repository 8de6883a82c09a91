"""Hessian covariance of a displacement (issue 7)."""

import math

import jax
import numpy as np
import pytest
from conftest import PAPER_CAPACITIES, T_PAPER, paper_rotation

import jaxpose as jp
from jaxpose._search import local_refine
from jaxpose._uncertainty import covariance, curvature, nees

CONFIG = jp.Config.fast(capacities=PAPER_CAPACITIES)  # fixed capacities: the tests share one compile


def test_curvature_at_the_optimum_is_positive_definite_and_matches_finite_differences(paper_clouds):
    problem = jp.Problem.build(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"], CONFIG)
    R1, R2 = paper_rotation("previous"), paper_rotation("variant2")
    truth = jp.true_displacement(problem.frame, R1, T_PAPER, R2, T_PAPER)
    p = local_refine(problem, CONFIG, truth).params
    H = np.asarray(curvature(p, problem))
    np.testing.assert_allclose(H, H.T, rtol=1e-9, atol=1e-9 * np.abs(H).max())
    assert np.linalg.eigvalsh(H).min() > 0
    # Second difference of −f along the first angle, with a step of 0.01° (radians).
    h, e = np.radians(0.01), np.eye(6)[0]
    f = lambda q: -float(jp.soft_score(q, problem))  # noqa: E731
    fd = (f(p + h * e) - 2 * f(p) + f(p - h * e)) / h**2
    assert abs(fd - H[0, 0]) < 0.05 * abs(H[0, 0])
    sigma = np.asarray(covariance(p, problem, 2.0))
    np.testing.assert_allclose(sigma @ H, 2.0 * np.eye(6), atol=1e-6 * np.abs(sigma @ H).max())
    error = jax.numpy.asarray([1e-3, -2e-3, 0.0, 1e-3, 0.0, -1e-3])
    assert np.isclose(float(nees(error, sigma)), float(error @ H @ error) / 2.0, rtol=1e-6)


def test_the_motion_covariance_is_the_least_squares_one_times_the_configured_factor(n5_problem):
    """`motion_covariance` is linear in `FineStage.covariance_scale`: Σ(k) = k / k₀ · Σ(k₀), and
    `motion_uncertainty` gives the same covariance and the σ̂ of `fine_least_squares`. The
    default is the realistic calibration (`COVARIANCE_SCALE`, `COVARIANCE_NOISE`); the tracker's
    registrations (`registration_config`) and the model's (`model_config`) take the constant
    `TRACKING_COVARIANCE_SCALE`."""
    import dataclasses

    from jaxpose._config import COVARIANCE_NOISE
    from jaxpose._fine import fine_least_squares
    from jaxpose._uncertainty import COVARIANCE_SCALE, covariance_factor, motion_covariance, motion_uncertainty
    from jaxpose.tracking._against_model import model_config
    from jaxpose.tracking._track import TRACKING_COVARIANCE_SCALE, registration_config

    config = jp.Config()
    assert config.fine.covariance_scale == COVARIANCE_SCALE
    assert config.fine.covariance_noise == COVARIANCE_NOISE
    p = jax.numpy.zeros(6).at[0].set(1e-3)
    base = np.asarray(motion_covariance(n5_problem, config, p))
    cov, sigma = motion_uncertainty(n5_problem, config, p)
    np.testing.assert_array_equal(np.asarray(cov), base)
    assert float(sigma) == float(fine_least_squares(n5_problem, config, p)[0])
    doubled = dataclasses.replace(config, fine=dataclasses.replace(config.fine, covariance_scale=2 * COVARIANCE_SCALE))
    np.testing.assert_allclose(np.asarray(motion_covariance(n5_problem, doubled, p)), 2 * base, rtol=1e-6)
    tracked = np.asarray(motion_covariance(n5_problem, registration_config(config), p))
    ratio = TRACKING_COVARIANCE_SCALE / float(covariance_factor(config, sigma))
    np.testing.assert_allclose(tracked, ratio * base, rtol=1e-6)
    assert model_config(config).fine.covariance_scale == TRACKING_COVARIANCE_SCALE
    assert model_config(config).fine.covariance_noise == math.inf


def test_the_covariance_factor_grows_with_the_residual_scale():
    """k(σ̂) = scale · (1 + σ̂ / noise): the scale at σ̂ = 0, twice it at σ̂ = noise, increasing
    in σ̂; constant with noise = inf."""
    from jaxpose._uncertainty import covariance_factor

    stage = jp.FineStage(covariance_scale=0.5, covariance_noise=2e-3)
    config = jp.Config(fine=stage)
    sigmas = np.array([0.0, 1e-3, 2e-3, 1e-2])
    k = np.array([float(covariance_factor(config, s)) for s in sigmas])
    np.testing.assert_allclose(k, 0.5 * (1 + sigmas / 2e-3), rtol=1e-6)
    assert np.all(np.diff(k) > 0) and k[2] == pytest.approx(2 * k[0])
    constant = jp.Config(fine=jp.FineStage(covariance_scale=0.5, covariance_noise=math.inf))
    assert {float(covariance_factor(constant, s)) for s in sigmas} == {0.5}


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_the_covariance_noise_is_checked(value):
    with pytest.raises(ValueError, match="covariance_noise"):
        jp.FineStage(covariance_noise=value)


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_the_covariance_scale_is_checked(value):
    with pytest.raises(ValueError, match="covariance_scale"):
        jp.FineStage(covariance_scale=value)
