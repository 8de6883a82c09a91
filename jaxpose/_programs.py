"""A bounded in-memory cache of compiled programs for the public path.

Each compiled XLA:CPU program keeps a few thousand memory mappings while it lives, and Linux
allows 65,530 per process: a session that met a few dozen capacity buckets through
`jax.jit`'s unbounded cache would abort in the compiler. The public functions therefore
compile ahead of time (`jax.jit(…).lower(…).compile()`) and keep the `PROGRAMS` most
recently used programs; an evicted one is freed, and JAX's persistent compilation cache
(when enabled, as the CLI does) makes its recompilation a load from disk.
"""

from __future__ import annotations

import os
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax

PROGRAMS = 4
"""Compiled programs kept in memory per cached function (≈ 3,000 mappings each for
`estimate`'s)."""

_INSTANCES: weakref.WeakSet = weakref.WeakSet()


CROWDED = 40_000
"""Memory mappings of the process above which a new compile first releases every compiled
program (`release_all`): other jitted code and eager operations also hold mappings, and a
crowded process aborts in the compiler rather than raising."""


def memory_mappings() -> int:
    """The process's memory mappings (Linux; 0 where /proc is not there)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


def release_all() -> None:
    """Drop JAX's in-memory caches and every `BoundedJit`'s programs: they recompile on their
    next use (from the persistent compilation cache where one is set)."""
    jax.clear_caches()
    clear_programs()


def clear_programs() -> None:
    """Drop the compiled programs of every `BoundedJit` (`jax.clear_caches` does not see them)."""
    for instance in list(_INSTANCES):
        instance.clear()


def _signature(static, dynamic) -> tuple:
    """A hashable key: the static part as is, the arrays by shape, dtype and weak type."""
    leaves, treedef = jax.tree.flatten(dynamic)
    shapes = tuple((x.shape, str(x.dtype), getattr(x, "weak_type", False)) for x in leaves)
    static_leaves, static_def = jax.tree.flatten(static)
    return (treedef, shapes, static_def, tuple(static_leaves))


def enable_compile_cache(folder: str | Path | None = None) -> Path:
    """Keep XLA's compilations on disk, so that a new process compiles `estimate` and `track`
    faster: sets JAX's persistent compilation cache to `folder` (default `$JAXPOSE_CACHE`,
    else `~/.cache/jaxpose/xla`) for compilations of 1 s and longer. Returns the folder. The
    CLI calls it. Files are never deleted; remove the folder to reclaim the space."""
    if folder is None:
        folder = os.environ.get("JAXPOSE_CACHE", Path.home() / ".cache" / "jaxpose" / "xla")
    folder = Path(folder).expanduser()
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return folder


class BoundedJit:
    """`fn` compiled once per argument signature (shapes, dtypes and non-array leaves, as
    `eqx.filter_jit`), keeping the `size` most recently used programs. `last_compile_s` is
    the wall time (s) of the last compile (lowering included), for benchmarks that report
    compile time apart from run time."""

    def __init__(self, fn: Callable, size: int = PROGRAMS):
        self.fn, self.size = fn, size
        self.nested = eqx.filter_jit(fn)
        self.programs: OrderedDict = OrderedDict()
        self.last_compile_s = 0.0
        _INSTANCES.add(self)

    def __call__(self, *args):
        dynamic, static = eqx.partition(args, eqx.is_array)
        if any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(dynamic)):
            # Inside a caller's jit or vmap: a nested jit in the caller's program (inlined, the
            # vmapped build crashed XLA:CPU's compiler, JAX 0.10.2).
            return self.nested(*args)
        key = _signature(static, dynamic)
        program = self.programs.get(key)
        if program is None:
            if memory_mappings() > CROWDED:
                release_all()
            start = time.perf_counter()
            program = jax.jit(lambda dyn: self.fn(*eqx.combine(dyn, static))).lower(dynamic).compile()
            self.last_compile_s = time.perf_counter() - start
            self.programs[key] = program
            while len(self.programs) > self.size:
                self.programs.popitem(last=False)
        self.programs.move_to_end(key)
        return program(dynamic)

    def clear(self) -> None:
        """Drop every compiled program (they are freed once no result refers to them)."""
        self.programs.clear()


__all__ = [
    "CROWDED",
    "PROGRAMS",
    "BoundedJit",
    "clear_programs",
    "enable_compile_cache",
    "memory_mappings",
    "release_all",
]
