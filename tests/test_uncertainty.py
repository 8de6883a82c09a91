"""Hessian covariance of a displacement (issue 7)."""

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


def test_the_motion_covariance_is_the_least_squares_one_times_the_configured_scale(n5_problem):
    """`motion_covariance` is linear in `FineStage.covariance_scale`: Σ(k) = k / k₀ · Σ(k₀); the
    default is the realistic calibration `COVARIANCE_SCALE`, and the tracker's registrations
    (`registration_config`) and the model's (`model_config`) take `TRACKING_COVARIANCE_SCALE`."""
    import dataclasses

    from jaxpose._uncertainty import COVARIANCE_SCALE, motion_covariance
    from jaxpose.tracking._against_model import model_config
    from jaxpose.tracking._track import TRACKING_COVARIANCE_SCALE, registration_config

    config = jp.Config()
    assert config.fine.covariance_scale == COVARIANCE_SCALE
    p = jax.numpy.zeros(6).at[0].set(1e-3)
    base = np.asarray(motion_covariance(n5_problem, config, p))
    doubled = dataclasses.replace(config, fine=dataclasses.replace(config.fine, covariance_scale=2 * COVARIANCE_SCALE))
    np.testing.assert_allclose(np.asarray(motion_covariance(n5_problem, doubled, p)), 2 * base, rtol=1e-12)
    tracked = np.asarray(motion_covariance(n5_problem, registration_config(config), p))
    np.testing.assert_allclose(tracked, TRACKING_COVARIANCE_SCALE / COVARIANCE_SCALE * base, rtol=1e-12)
    assert model_config(config).fine.covariance_scale == TRACKING_COVARIANCE_SCALE


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_the_covariance_scale_is_checked(value):
    with pytest.raises(ValueError, match="covariance_scale"):
        jp.FineStage(covariance_scale=value)
