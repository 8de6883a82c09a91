"""The public path's bounded cache of compiled programs (jaxpose._programs)."""

import subprocess
import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import jaxpose as jp
from jaxpose import _programs as programs
from jaxpose._estimate import _build_and_estimate
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


class _Scaled(eqx.Module):
    """A result with a static field: its tree definition must survive the disk cache."""

    total: jax.Array
    label: str = eqx.field(static=True, default="sum")


def _scaled_module(x, scale: float) -> _Scaled:
    return _Scaled(jnp.sum(x) * scale)


def test_a_new_process_loads_the_program_from_disk(tmp_path, monkeypatch):
    monkeypatch.setattr(programs, "program_cache_dir", lambda: tmp_path)
    x = jnp.arange(5, dtype=jnp.float32)
    first = BoundedJit(_scaled_module)
    assert float(first(x, 2.0).total) == 20.0
    assert first.last_source == "compiled"
    first.saving.join()
    assert len(list(tmp_path.glob("*.program"))) == 1
    second = BoundedJit(_scaled_module)  # a new process has only the disk cache
    loaded = second(x, 2.0)
    assert second.last_source == "disk"
    assert isinstance(loaded, _Scaled) and loaded.label == "sum" and float(loaded.total) == 20.0
    assert float(second(x, 3.0).total) == 30.0 and second.last_source == "compiled"  # another signature


def _scaled_by(x, scale):
    return jnp.sum(x) * scale(2.0)


def _double(v):
    return 2 * v


def test_a_users_own_function_in_the_signature_is_never_cached(tmp_path, monkeypatch):
    """A static function from outside the trusted packages would be keyed by its name alone,
    so a changed body could load the old program: such programs are compiled every time."""
    monkeypatch.setattr(programs, "program_cache_dir", lambda: tmp_path)
    cached = BoundedJit(_scaled_by)
    assert float(cached(jnp.ones(3), _double)) == 12.0
    assert cached.last_source == "compiled" and cached.saving is None
    assert not list(tmp_path.glob("*.program"))
    dynamic, static = eqx.partition((jp.Config(), jax.random.key(0)), eqx.is_array)
    assert programs.cacheable(programs._signature(static, dynamic))  # optimistix's norms are trusted


def test_a_damaged_program_file_is_compiled_again(tmp_path, monkeypatch):
    monkeypatch.setattr(programs, "program_cache_dir", lambda: tmp_path)
    x = jnp.ones(4, dtype=jnp.float32)
    first = BoundedJit(_scaled_module)
    first(x, 1.0)
    first.saving.join()
    (path,) = tmp_path.glob("*.program")
    path.write_bytes(path.read_bytes()[:100])
    again = BoundedJit(_scaled_module)
    assert float(again(x, 1.0).total) == 4.0 and again.last_source == "compiled"
    again.saving.join()
    assert programs.load_program(path) is not None  # rewritten whole


def test_the_disk_cache_follows_jaxs_compilation_cache_setting(tmp_path):
    before = jax.config.jax_compilation_cache_dir
    try:
        jax.config.update("jax_compilation_cache_dir", str(tmp_path))
        assert programs.program_cache_dir() == tmp_path / programs.PROGRAM_FOLDER
        jax.config.update("jax_compilation_cache_dir", None)
        assert programs.program_cache_dir() is None
    finally:
        jax.config.update("jax_compilation_cache_dir", before)


def test_enable_compile_cache_sets_the_folder_and_the_threshold(tmp_path):
    before = jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs
    try:
        assert jp.enable_compile_cache(tmp_path / "xla") == tmp_path / "xla"
        assert programs.program_cache_dir() == tmp_path / "xla" / programs.PROGRAM_FOLDER
        assert jax.config.jax_persistent_cache_min_compile_time_secs == 1.0
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])


KEY_SCRIPT = """
import equinox as eqx, jax, jaxpose as jp
jax.config.update("jax_enable_x64", True)  # as the tests (conftest)
from jaxpose import _programs
from jaxpose._estimate import _build_and_estimate
dynamic, static = eqx.partition((jp.Config(), jax.random.key(0)), eqx.is_array)
print(_programs.program_key(_build_and_estimate, _programs._signature(static, dynamic)))
"""


def test_a_programs_key_is_the_same_in_another_process():
    """The default config holds functions (optimistix's norms) whose text carries a memory
    address; the key must not, or no other process would find the program."""
    dynamic, static = eqx.partition((jp.Config(), jax.random.key(0)), eqx.is_array)
    here = programs.program_key(_build_and_estimate, programs._signature(static, dynamic))
    there = subprocess.run([sys.executable, "-c", KEY_SCRIPT], capture_output=True, text=True, check=True)
    assert there.stdout.strip() == here
