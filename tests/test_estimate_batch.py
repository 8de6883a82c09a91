"""`jp.estimate_batch`: many pairs in one compiled `lax.map` call (jaxpose._estimate_batch)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose._problem import sized_batch_config, sized_stacked_config

PAIRS = [("n5", "previous", "variant1"), ("n5", "previous", "variant2"), ("n1", "previous", "variant2")]


def _stack(clouds):
    return jp.Cloud(jnp.stack([c.points for c in clouds]), jnp.stack([c.valid for c in clouds]))


@pytest.fixture(scope="module")
def batch(paper_clouds):
    prev = [paper_clouds[shape, a] for shape, a, _ in PAIRS]
    curr = [paper_clouds[shape, b] for shape, _, b in PAIRS]
    return prev, curr


# The two tests below compile the batch program (≈ 50 s in one process): `-m slow`, like the
# other checks of an API beside the method (docs/testing.md); the default run keeps the checks
# at the boundary.
@pytest.mark.slow
def test_each_pair_gets_what_estimate_gives_it_with_the_batchs_capacities(batch):
    prev, curr = batch
    config = jp.Config.fast()
    keys = jax.random.split(jax.random.key(3), len(PAIRS))
    est = jp.estimate_batch(_stack(prev), _stack(curr), config, key=keys)
    assert est.params.shape == (len(PAIRS), 6) and est.status.shape == (len(PAIRS),)
    sized = sized_batch_config(list(zip(prev, curr, strict=True)), config)
    for i in range(len(PAIRS)):
        one = jp.estimate(prev[i], curr[i], sized, key=keys[i])
        assert int(est.status[i]) == int(one.status)
        np.testing.assert_allclose(np.asarray(est.params[i]), np.asarray(one.params), atol=1e-6)
        np.testing.assert_allclose(np.asarray(est.rotation[i]), np.asarray(one.rotation), atol=1e-6)


@pytest.mark.slow
def test_a_pair_that_estimate_refuses_is_named(batch):
    # Pair 2's current cloud keeps 5 of its points: the capacities (and so the compiled
    # program) are those of the test above, and the program reports too few current points.
    prev, curr = batch
    kept = jnp.cumsum(curr[2].valid) <= 5
    few = jp.Cloud(curr[2].points, curr[2].valid & kept)
    with pytest.raises(ValueError, match="pair 2: current cloud: fewer than 10 valid points"):
        jp.estimate_batch(_stack(prev), _stack([curr[0], curr[1], few]), jp.Config.fast(), key=jax.random.key(0))


def test_batch_shapes_keys_and_chunk_are_checked_before_any_compile(batch):
    prev, curr = _stack(batch[0]), _stack(batch[1])
    with pytest.raises(ValueError, match="leading batch axis"):
        jp.estimate_batch(prev, jp.Cloud(curr.points[:2], curr.valid[:2]), key=jax.random.key(0))
    with pytest.raises(ValueError, match="one key or 3 keys"):
        jp.estimate_batch(prev, curr, key=jax.random.split(jax.random.key(0), 2))
    with pytest.raises(ValueError, match="chunk"):
        jp.estimate_batch(prev, curr, key=jax.random.key(0), chunk=0)
    with pytest.raises(ValueError, match="pair 1: current cloud"):
        nan = curr.points.at[1, 0].set(jnp.nan)
        jp.estimate_batch(prev, jp.Cloud(nan, curr.valid.at[1, 0].set(True)), key=jax.random.key(0))
    with pytest.raises(ValueError, match="pair 2: previous cloud: points reach .* beyond Config.thresholds.max_range"):
        jp.estimate_batch(jp.Cloud(prev.points.at[2].multiply(1e4), prev.valid), curr, key=jax.random.key(0))


def test_the_stacked_sizing_is_the_sizing_of_the_list_of_pairs(batch):
    config = jp.Config.fast()
    stacked = sized_stacked_config(_stack(batch[0]), _stack(batch[1]), config)
    listed = sized_batch_config(list(zip(*batch, strict=True)), config)
    assert stacked.capacities == listed.capacities
    assert stacked.capacities.max_points is not None  # sized, not left open
