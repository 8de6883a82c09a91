"""Running one computation over a batch (`jaxpose._batch`): `map_batch` gives `vmap`'s values
whether it maps (CPU) or vmaps (accelerator), and `estimate_batch`'s default chunk follows the
backend. The accelerator branch is taken here by making `on_accelerator` answer True."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose import _batch, _estimate_batch


def _newton_sqrt(x):
    """√x by Newton's method in a while loop whose trip count depends on x (as the refine's
    and fine stage's loops do), and a branch on x."""

    def step(state):
        y, n = state
        return 0.5 * (y + x / y), n + 1

    y, n = jax.lax.while_loop(lambda s: jnp.abs(s[0] ** 2 - x) > 1e-5 * x, step, (jnp.maximum(x, 1.0), 0))
    return jax.lax.cond(x > 50.0, lambda: -y, lambda: y), n


@pytest.mark.parametrize("accelerator", [False, True])
@pytest.mark.parametrize("cpu_chunk", [1, 3])
def test_map_batch_gives_vmaps_values_either_way(monkeypatch, accelerator, cpu_chunk):
    monkeypatch.setattr(_batch, "on_accelerator", lambda: accelerator)
    x = jnp.asarray(np.random.default_rng(0).uniform(0.01, 100.0, 10), jnp.float32)
    y, n = jax.jit(lambda x: _batch.map_batch(_newton_sqrt, x, cpu_chunk))(x)
    y_ref, n_ref = jax.vmap(_newton_sqrt)(x)
    np.testing.assert_allclose(np.asarray(y), np.asarray(y_ref), rtol=1e-6)
    np.testing.assert_allclose(np.abs(np.asarray(y)), np.sqrt(np.asarray(x)), rtol=1e-4)
    assert np.all(np.sign(np.asarray(y)) == np.where(np.asarray(x) > 50, -1, 1))
    # Each item stops at its own count when mapped; under vmap the values of a finished item
    # stay put, so the counts agree with the per-item loop either way.
    np.testing.assert_array_equal(np.asarray(n), np.asarray(n_ref))


def test_the_backend_decides_estimate_batchs_chunk(monkeypatch):
    assert _batch.on_accelerator() == (jax.default_backend() != "cpu")
    monkeypatch.setattr(_estimate_batch, "on_accelerator", lambda: False)
    assert _estimate_batch.default_chunk(64) == 1
    monkeypatch.setattr(_estimate_batch, "on_accelerator", lambda: True)
    assert _estimate_batch.default_chunk(64) == 64
