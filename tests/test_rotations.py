import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from reference import printed_rotation  # the matrix as printed in the paper, typed element by element

import jaxpose as jp
from jaxpose._rotations import into_moved_frame, rotate_components

angle = st.floats(-np.pi, np.pi)
inner = st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3)


@settings(max_examples=50, deadline=None)
@given(angle, angle, angle)
def test_rotation_is_the_printed_matrix_and_ry_rx_rz(t, f, s):
    G = np.asarray(jp.rotation(t, f, s))
    np.testing.assert_allclose(G, printed_rotation(t, f, s), atol=1e-14)
    lie = jaxlie.SO3.from_y_radians(t) @ jaxlie.SO3.from_x_radians(f) @ jaxlie.SO3.from_z_radians(s)
    np.testing.assert_allclose(G, np.asarray(lie.as_matrix()), atol=1e-12)
    np.testing.assert_allclose(G @ G.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(G) > 0


@settings(max_examples=100, deadline=None)
@given(angle, inner, angle)
def test_angles_inverts_rotation_away_from_gimbal_lock(t, f, s):
    np.testing.assert_allclose(np.asarray(jp.angles(jp.rotation(t, f, s))), [t, f, s], atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(angle, st.sampled_from([-np.pi / 2, np.pi / 2]), angle)
def test_gimbal_lock_still_reproduces_the_matrix(t, f, s):
    G = jp.rotation(t, f, s)
    a = jp.angles(G)
    assert np.all(np.isfinite(np.asarray(a)))
    assert abs(float(a[1]) - f) < 1e-6 and float(a[2]) == 0.0
    np.testing.assert_allclose(np.asarray(jp.rotation(*a)), np.asarray(G), atol=1e-6)


def test_rotation_batches_and_jits():
    t = jnp.linspace(-1, 1, 5)
    G = jax.jit(jp.rotation)(t, t / 2, -t)
    assert G.shape == (5, 3, 3)
    np.testing.assert_allclose(np.asarray(jp.angles(G)), np.stack([t, t / 2, -t], 1), atol=1e-12)


def test_rotation_angle():
    G = jp.rotation(0.3, -0.2, 0.1)
    axis_angle = np.linalg.norm(np.asarray(jaxlie.SO3.from_matrix(G).log()))
    np.testing.assert_allclose(float(jp.rotation_angle(G, jnp.eye(3))), axis_angle, atol=1e-12)
    assert float(jp.rotation_angle(G, G)) == 0.0


@given(angle, angle, angle, st.integers(0, 2**31 - 1))
@settings(max_examples=30, deadline=None)
def test_points_into_the_moved_frame_are_g_transposed_times_the_shifted_points(t, f, s, seed):
    """The structure-of-arrays transform (used by the objectives, the fine stage and the
    simulator) against the plain matrix product q = Gᵀ (b − (x, y, z))."""
    rng = np.random.default_rng(seed)
    b, shift = rng.normal(size=(3, 17)), rng.normal(size=3)
    p = jnp.array([t, f, s, *shift])
    G = np.asarray(jp.rotation(t, f, s))
    want = G.T @ (b - shift[:, None])
    got = np.stack(into_moved_frame(p, *jnp.asarray(b)))
    np.testing.assert_allclose(got, want, atol=1e-12)
    np.testing.assert_allclose(np.stack(rotate_components(jnp.asarray(G), *jnp.asarray(b))), G @ b, atol=1e-12)
