"""The public path's bounded cache of compiled programs (jaxpose._programs)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose
import jaxpose as jp
from jaxpose import _programs
from jaxpose._programs import BoundedJit, clear_programs, memory_mappings, program_folder, program_name, trim


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


def test_enable_compile_cache_sets_the_folders_and_the_threshold(program_files):
    assert jax.config.jax_compilation_cache_dir == str(program_files.parent / "xla")
    assert jax.config.jax_persistent_cache_min_compile_time_secs == jaxpose._programs.MIN_COMPILE_S
    assert program_folder() == program_files


def test_the_folder_follows_the_environment_until_chosen(monkeypatch, tmp_path):
    monkeypatch.setattr(_programs, "_CHOICE", [])
    monkeypatch.setenv("JAXPOSE_CACHE", str(tmp_path))
    assert program_folder() == tmp_path / "programs"
    for off in ("off", "OFF", "0", "none", ""):
        monkeypatch.setenv("JAXPOSE_CACHE", off)
        assert program_folder() is None
        assert jp.enable_compile_cache() is None  # the environment's "off" holds for the CLI too
        assert program_folder() is None
        monkeypatch.setattr(_programs, "_CHOICE", [])
    monkeypatch.delenv("JAXPOSE_CACHE")
    assert program_folder() == Path.home() / ".cache" / "jaxpose" / "programs"
    monkeypatch.setenv("JAXPOSE_CACHE", str(tmp_path))
    jp.disable_compile_cache()
    assert program_folder() is None


class _Summary(eqx.Module):
    """An output with a custom pytree node and a static field, as `Estimate` has."""

    total: jax.Array
    label: str = eqx.field(static=True)


_TRACES: list[int] = []


def _summarise(x, scale: float) -> _Summary:
    _TRACES.append(x.shape[0])  # runs once per trace, never when a program file is loaded
    return _Summary(jnp.sum(x) * scale, label=f"scaled by {scale}")


@pytest.fixture
def program_files(tmp_path):
    """Program files in a fresh folder for the test; the process's choice and JAX's cache
    restored afterwards (conftest's `restore_compile_cache`)."""
    jp.enable_compile_cache(tmp_path)
    return tmp_path / "programs"


@pytest.fixture
def default_files(tmp_path, monkeypatch):
    """The default: no call, `$JAXPOSE_CACHE` names the folder."""
    monkeypatch.setattr(_programs, "_CHOICE", [])
    monkeypatch.setenv("JAXPOSE_CACHE", str(tmp_path))
    return tmp_path / "programs"


def test_by_default_a_new_cache_loads_the_program_file_without_tracing(default_files):
    before = jax.config.jax_compilation_cache_dir
    x = jnp.arange(5.0)
    _TRACES.clear()
    first = BoundedJit(_summarise)(x, 2.0)
    assert _TRACES == [5]
    assert len(list(default_files.glob("summarise-*.xla"))) == 1
    assert jax.config.jax_compilation_cache_dir == before  # JAX's own configuration untouched
    second = BoundedJit(_summarise)(x, 2.0)  # a new in-memory cache, as in a new process
    assert _TRACES == [5]
    assert second.label == first.label == "scaled by 2.0"
    assert float(second.total) == float(first.total) == 20.0


def test_other_static_values_or_shapes_are_other_files(program_files):
    cached = BoundedJit(_summarise)
    outs = [cached(jnp.arange(n, dtype=float), s) for n, s in ((5, 2.0), (5, 3.0), (4, 2.0))]
    assert [float(o.total) for o in outs] == [20.0, 30.0, 12.0]
    assert len(list(program_files.glob("summarise-*.xla"))) == 3


def test_an_unreadable_program_file_is_traced_again_and_replaced(program_files):
    # JAX's own cache keeps compiles of MIN_COMPILE_S and longer, and an executable it answers
    # is never saved as a program file; on a loaded machine this small compile can take that
    # long, so JAX's cache is kept out of the test.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1e9)
    x = jnp.arange(3.0)
    BoundedJit(_summarise)(x, 1.0)
    (path,) = program_files.glob("summarise-*.xla")
    path.write_bytes(b"not a program")
    _TRACES.clear()
    out = BoundedJit(_summarise)(x, 1.0)
    assert _TRACES == [3] and float(out.total) == 3.0
    _TRACES.clear()
    assert float(BoundedJit(_summarise)(x, 1.0).total) == 3.0
    assert _TRACES == []  # the rewritten file loads


def test_static_arguments_pickle_cannot_write_compile_without_a_file(program_files):
    cached = BoundedJit(lambda x, f: f(jnp.sum(x)))
    assert float(cached(jnp.arange(4.0), lambda s: s * 2)) == 12.0
    assert not list(program_files.glob("*.xla"))


def test_program_names_depend_on_the_static_arguments_and_the_shapes():
    leaves, tree = jax.tree.flatten((jnp.zeros(3),))
    name = program_name(_summarise, (None, 2.0), tree, leaves)
    assert name == program_name(_summarise, (None, 2.0), tree, leaves)
    assert name != program_name(_summarise, (None, 2.5), tree, leaves)
    other_leaves, other_tree = jax.tree.flatten((jnp.zeros(4),))
    assert name != program_name(_summarise, (None, 2.0), other_tree, other_leaves)
    assert name.startswith("summarise-")


def test_a_folder_that_cannot_be_written_still_gives_the_result(program_files):
    program_files.parent.mkdir(parents=True, exist_ok=True)
    program_files.write_text("a file where the folder should be")
    assert float(BoundedJit(_summarise)(jnp.arange(4.0), 1.0).total) == 6.0


def test_program_names_depend_on_the_tracing_flags():
    leaves, tree = jax.tree.flatten((jnp.zeros(3),))
    name = program_name(_summarise, (None, 2.0), tree, leaves)
    before = jax.config.jax_numpy_rank_promotion
    try:
        jax.config.update("jax_numpy_rank_promotion", "warn" if before != "warn" else "allow")
        assert program_name(_summarise, (None, 2.0), tree, leaves) != name
    finally:
        jax.config.update("jax_numpy_rank_promotion", before)


def test_off_keeps_no_file_and_gives_the_same_result(tmp_path, monkeypatch):
    monkeypatch.setattr(_programs, "_CHOICE", [])
    monkeypatch.setenv("JAXPOSE_CACHE", "off")
    monkeypatch.setenv("HOME", str(tmp_path))
    assert float(BoundedJit(_summarise)(jnp.arange(3.0), 2.0).total) == 6.0
    assert not list(tmp_path.rglob("*.xla"))


@pytest.mark.parametrize("cache", ["off", "folder"])
def test_every_compile_takes_the_one_flat_route(cache, tmp_path, monkeypatch):
    """With caching off, with a folder, and with static arguments pickle cannot write, a
    program is compiled by `_compile_flat` on the flat arguments, and gives the pytree result."""
    monkeypatch.setattr(_programs, "_CHOICE", [])
    monkeypatch.setenv("JAXPOSE_CACHE", "off" if cache == "off" else str(tmp_path))
    compiles = []
    compile_flat = _programs._compile_flat
    monkeypatch.setattr(_programs, "_compile_flat", lambda *a: compiles.append(a) or compile_flat(*a))
    out = BoundedJit(_summarise)(jnp.arange(3.0), 2.0)
    assert float(out.total) == 6.0 and isinstance(out, type(_summarise(jnp.arange(3.0), 2.0)))
    assert float(BoundedJit(lambda x, f: f(jnp.sum(x)))(jnp.arange(4.0), lambda s: s * 2)) == 12.0
    assert len(compiles) == 2
    assert len(list(tmp_path.rglob("*.xla"))) == (0 if cache == "off" else 1)


def test_programs_compile_with_jaxposes_xla_options(monkeypatch):
    """Every program of the route is compiled with `compiler_options()` (on the CPU backend,
    `CPU_COMPILER_OPTIONS`), and gives the same result as plain jit."""
    seen = []
    compile_ = jax.stages.Lowered.compile
    monkeypatch.setattr(jax.stages.Lowered, "compile", lambda self, **kw: seen.append(kw) or compile_(self, **kw))
    monkeypatch.setattr(_programs, "_CHOICE", [None])
    x = jnp.arange(5.0)
    assert float(BoundedJit(_scaled_sum)(x, 2.0)) == float(jax.jit(_scaled_sum, static_argnums=1)(x, 2.0))
    # `compile_lowered` passes no keyword where there are no options (a backend other than the CPU).
    assert seen[0].get("compiler_options", {}) == _programs.compiler_options()
    if jax.default_backend() == "cpu":
        assert _programs.compiler_options() == _programs.CPU_COMPILER_OPTIONS != {}


def test_an_option_xla_does_not_know_is_dropped_and_other_errors_raise():
    lowered = jax.jit(lambda x: jnp.sum(x) * 2.0).lower(jnp.arange(4.0))
    program = _programs.compile_lowered(lowered, {"xla_no_such_option_anywhere": True})
    assert float(program(jnp.arange(4.0))) == 12.0
    # A value of an enumerated option that this XLA does not know (one a later XLA may drop).
    program = _programs.compile_lowered(lowered, {"xla_cpu_opt_preset": "CPU_OPT_PRESET_NO_SUCH_PRESET"})
    assert float(program(jnp.arange(4.0))) == 12.0
    with pytest.raises(jax.errors.JaxRuntimeError):  # a known option with a value of the wrong type
        _programs.compile_lowered(lowered, {"xla_cpu_use_fusion_emitters": "not a boolean"})


def test_a_program_from_jaxs_cache_runs_and_keeps_no_file(program_files):
    """With JAX's persistent cache on (as `enable_compile_cache` and the test session set it),
    a program whose file is gone compiles again from JAX's cache. It runs, and no file is
    written from it: XLA:CPU cannot serialise such an executable again (the copy failed at its
    first run in a later process, "Function ... not found")."""
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    x = jnp.arange(7.0)
    first = BoundedJit(_summarise)(x, 3.0)
    (saved,) = program_files.glob("*.xla")
    saved.unlink()
    clear_programs()
    again = BoundedJit(_summarise)(x, 3.0)
    assert float(again.total) == float(first.total) == 63.0
    assert not list(program_files.glob("*.xla"))


def test_trim_deletes_the_least_recently_used_files_first(tmp_path):
    for age, name in enumerate(("newest", "middle", "oldest")):
        path = tmp_path / f"{name}.xla"
        path.write_bytes(b"x" * 100)
        os.utime(path, (1e9 - age, 1e9 - age))
    (tmp_path / "other.txt").write_bytes(b"x" * 1000)  # not a program file: never counted or deleted
    trim(tmp_path, limit=250)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["middle.xla", "newest.xla", "other.txt"]
    trim(tmp_path, limit=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["newest.xla", "other.txt"]  # the newest stays


def test_a_load_marks_the_file_as_recently_used(program_files):
    x = jnp.arange(4.0)
    BoundedJit(_summarise)(x, 5.0)
    (path,) = program_files.glob("summarise-*.xla")
    os.utime(path, (1e9, 1e9))
    BoundedJit(_summarise)(x, 5.0)
    assert path.stat().st_mtime > 1e9 + 1


def test_program_names_depend_on_the_machine(monkeypatch):
    leaves, tree = jax.tree.flatten((jnp.zeros(3),))
    name = program_name(_summarise, (None, 2.0), tree, leaves)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=true")
    assert program_name(_summarise, (None, 2.0), tree, leaves) != name
    monkeypatch.setattr(_programs, "_cpu_identity", lambda: "another CPU")
    monkeypatch.delenv("XLA_FLAGS")
    assert program_name(_summarise, (None, 2.0), tree, leaves) != name


def test_the_public_estimate_loads_its_program_from_the_file(default_files, paper_clouds, monkeypatch):
    prev, curr = paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"]
    # The smallest program of the public path, at capacities no other test compiles: a
    # program the session's JAX cache already holds would keep no file (see above).
    capacities = jp.Capacities(max_points=5184, max_prev_points=8192, grid_cells=128, max_cells=512)
    config = jp.Config.paper(capacities=capacities)
    first = jp.estimate(prev, curr, config, key=jax.random.key(0))
    assert list(default_files.glob("build_and_estimate-*.xla"))
    clear_programs()  # as a new process: nothing compiled in memory
    compiles = []
    compile_flat = _programs._compile_flat
    monkeypatch.setattr(_programs, "_compile_flat", lambda *a: compiles.append(a[0].__name__) or compile_flat(*a))
    again = jp.estimate(prev, curr, config, key=jax.random.key(0))
    assert "_build_and_estimate" not in compiles  # loaded from its file
    np.testing.assert_array_equal(np.asarray(again.params), np.asarray(first.params))
    assert again.status == first.status


_NEW_PROCESS = """
import json, sys
import jax.numpy as jnp
from jaxpose._programs import BoundedJit

traced = []


def solve(x, y):
    traced.append(1)
    m = x.reshape(3, 3) @ x.reshape(3, 3).T + jnp.eye(3)
    return jnp.linalg.eigh(m)[0], jnp.linalg.solve(m, y), jnp.linalg.cholesky(m)


out = BoundedJit(solve)(jnp.arange(9.0), jnp.ones(3))
print(json.dumps({"traced": len(traced), "out": [o.ravel().tolist() for o in out]}))
"""


def test_a_program_with_linear_algebra_loads_and_runs_in_a_new_process(tmp_path):
    """LAPACK's kernels (eigh, LU, Cholesky) are made ready before a program is loaded: a
    fresh process that loaded such a program without lowering anything crashed."""
    env = {**os.environ, "JAXPOSE_CACHE": str(tmp_path)}
    runs = []
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", _NEW_PROCESS], env=env, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]
        runs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert [r["traced"] for r in runs] == [1, 0]  # the second process loaded the file
    assert runs[0]["out"] == runs[1]["out"]
    assert len(list((tmp_path / "programs").glob("solve-*.xla"))) == 1


def test_without_jaxs_lapack_preparation_a_lowering_prepares_the_kernels(monkeypatch):
    """Where a JAX lacks the private `prepare_lapack_call` (`LAPACK_PREPARATION`),
    `prepare_custom_calls` lowers a small linear-algebra program instead; the fresh-process
    test above runs the function itself."""
    lowered = []
    jit = jax.jit
    monkeypatch.setattr(jax, "jit", lambda fn: lowered.append(fn) or jit(fn))
    for missing in (("jax._src.lib.lapack", "no_such_function"), ("no_such_module_of_jax", "prepare")):
        monkeypatch.setattr(_programs, "LAPACK_PREPARATION", missing)
        _programs.prepare_custom_calls.cache_clear()
        try:
            _programs.prepare_custom_calls()
        finally:
            _programs.prepare_custom_calls.cache_clear()
    assert len(lowered) == 2  # one lowering for each


def test_importing_jaxpose_leaves_the_search_library_for_the_first_trace():
    """A process whose programs load from their files never traces the search: evosax (half a
    second of imports) is imported where the search is traced, not with jaxpose."""
    code = "import sys, jaxpose; print('evosax' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "False"
