"""The public path's bounded cache of compiled programs (jaxpose._programs)."""

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from jaxpose._programs import BoundedJit, clear_programs, memory_mappings


def _scaled_sum(x, scale: float):
    return jnp.sum(x) * scale


def test_keeps_the_most_recent_programs_and_computes_the_same():
    cached = BoundedJit(_scaled_sum, size=2)
    for n in (3, 4, 5, 4):
        x = jnp.arange(n, dtype=jnp.float32)
        assert float(cached(x, 2.0)) == float(_scaled_sum(x, 2.0))
    assert len(cached.programs) == 2  # shapes 5 and 4 kept, 3 evicted
    assert float(cached(jnp.ones(5), 3.0)) == 15.0  # a new static value is a new program
    assert len(cached.programs) == 2
    clear_programs()
    assert len(cached.programs) == 0


def test_inside_jit_and_vmap_it_is_part_of_the_callers_program():
    cached = BoundedJit(_scaled_sum, size=2)
    xs = jnp.arange(12.0).reshape(3, 4)
    out = jax.jit(jax.vmap(lambda x: cached(x, 0.5)))(xs)
    np.testing.assert_allclose(np.asarray(out), np.asarray(xs).sum(1) * 0.5)
    assert len(cached.programs) == 0


def test_memory_mappings_are_counted_on_linux():
    assert memory_mappings() >= 0


def test_enable_compile_cache_sets_the_folder_and_the_threshold(tmp_path):
    before = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    try:
        assert jp.enable_compile_cache(tmp_path / "xla") == tmp_path / "xla"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 1.0
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])
