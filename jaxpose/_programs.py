"""A bounded in-memory cache of compiled programs for the public path.

Each compiled XLA:CPU program keeps a few thousand memory mappings while it lives, and Linux
allows 65,530 per process: a session that met a few dozen capacity buckets through
`jax.jit`'s unbounded cache would abort in the compiler. The public functions therefore
compile ahead of time (`jax.jit(…).lower(…).compile()`) and keep the `PROGRAMS` most
recently used programs; an evicted one is freed.

With `enable_compile_cache` (the CLI enables it) a program is also kept on disk twice: its
StableHLO as a `jax.export` file, and XLA's compiled code in JAX's persistent compilation
cache. A new process deserialises the first instead of tracing and lowering the Python
function again (seconds for `estimate`'s program), and compiling it is then a load from the
second.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pickle
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


MIN_COMPILE_S = 0.1
"""The shortest compilation that `enable_compile_cache` keeps on disk: the sizing program at
the public boundary compiles in under a second, and a new process would otherwise compile
it again before its first estimate."""

_EXPORTS: list[Path] = []
"""The folder of exported programs, once `enable_compile_cache` set one."""


def enable_compile_cache(folder: str | Path | None = None) -> Path:
    """Keep the public path's programs on disk, so that a new process starts `estimate` and
    `track` in seconds instead of compiling them (first estimate ≈ 3 s after the call on a
    2-core CPU, against ≈ 25 s cold). `folder` (default `$JAXPOSE_CACHE`, else
    `~/.cache/jaxpose`) gets `programs/`, each `BoundedJit` program exported as StableHLO
    (`jax.export`), and `xla/`, JAX's persistent compilation cache (compilations of
    `MIN_COMPILE_S` and longer: this process's other jitted code is cached there too). A
    program's file name hashes everything its tracing depends on: the function, the static
    arguments, the argument shapes and dtypes, JAX's version and flags, and jaxpose's own
    source, so that a changed program is never loaded. Returns `folder`. Files are never
    deleted; remove the folder to reclaim the space."""
    if folder is None:
        folder = os.environ.get("JAXPOSE_CACHE", Path.home() / ".cache" / "jaxpose")
    folder = Path(folder).expanduser()
    jax.config.update("jax_compilation_cache_dir", str(folder / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    _EXPORTS[:] = [folder / "programs"]
    return folder


def disable_program_files() -> None:
    """Stop keeping exported programs on disk (JAX's compilation cache stays as set)."""
    _EXPORTS.clear()


@functools.cache
def source_digest() -> str:
    """SHA-256 of jaxpose's Python source, computed once per process: part of every program
    file's name, so that an edited jaxpose never loads a stale program."""
    digest = hashlib.sha256()
    package = Path(__file__).parent
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def program_name(fn: Callable, static, intree, leaves) -> str:
    """The file name of `fn`'s program for these arguments: a hash of the function, the
    pickled static arguments, the argument tree, shapes and dtypes, JAX's version, backend and
    tracing flags (x64, matmul precision, rank and dtype promotion), and jaxpose's source.
    Raises if the static arguments cannot be pickled."""
    digest = hashlib.sha256()
    parts = (
        fn.__module__,
        fn.__qualname__,
        source_digest(),
        jax.__version__,
        jax.default_backend(),
        bool(jax.config.jax_enable_x64),
        str(jax.config.jax_default_matmul_precision),
        str(jax.config.jax_numpy_rank_promotion),
        str(jax.config.jax_numpy_dtype_promotion),
        str(intree),
        tuple((x.shape, str(x.dtype), bool(getattr(x, "weak_type", False))) for x in leaves),
    )
    digest.update(repr(parts).encode())
    digest.update(pickle.dumps(static))
    return f"{fn.__name__.strip('_')}-{digest.hexdigest()[:32]}"


def _export(fn: Callable, static, intree, leaves):
    """Trace and lower `fn` on flat arguments: the `jax.export.Exported` and the output tree."""
    trees = []

    def flat(*flat_args):
        out = fn(*eqx.combine(jax.tree.unflatten(intree, flat_args), static))
        out_leaves, out_tree = jax.tree.flatten(out)
        trees.append(out_tree)
        return out_leaves

    avals = [jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves]
    exported = jax.export.export(jax.jit(flat))(*avals)
    return exported, trees[0]


def _sibling(path: Path, suffix: str) -> Path:
    return path.parent / (path.name + suffix)


def _load(path: Path):
    """The exported program and output tree saved at `path`, or None if it cannot be read."""
    try:
        exported = jax.export.deserialize(bytearray(_sibling(path, ".stablehlo").read_bytes()))
        skeleton = pickle.loads(_sibling(path, ".tree").read_bytes())
    except Exception:  # a missing, partial or incompatible file: trace again
        return None
    return exported, jax.tree.structure(skeleton)


def _save(path: Path, exported, out_tree) -> None:
    """Write the program and its output tree (as a pytree of zeros), each atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    skeleton = jax.tree.unflatten(out_tree, [0] * out_tree.num_leaves)
    for suffix, data in ((".stablehlo", exported.serialize()), (".tree", pickle.dumps(skeleton))):
        partial = _sibling(path, f"{suffix}.{os.getpid()}.partial")
        partial.write_bytes(data)
        os.replace(partial, _sibling(path, suffix))


def exported_program(fn: Callable, static, dynamic, folder: Path) -> Callable | None:
    """`fn` compiled for these arguments through a program file in `folder`: loaded if it is
    there, else traced, exported and saved. Returns a callable of `dynamic`, or None where
    the program cannot go through a file (static arguments that pickle cannot write, what
    `jax.export` refuses, such as host callbacks): the caller then compiles it directly."""
    leaves, intree = jax.tree.flatten(dynamic)
    try:
        path = folder / program_name(fn, static, intree, leaves)
    except Exception:  # static arguments that pickle cannot write
        return None
    loaded = _load(path)
    if loaded is None:
        try:
            loaded = _export(fn, static, intree, leaves)
        except Exception:  # what jax.export refuses (host callbacks, say): the jit path
            return None
        try:
            _save(path, *loaded)
        except OSError:  # a folder that cannot be written: the program still runs
            pass
    exported, out_tree = loaded
    try:
        compiled = jax.jit(exported.call).lower(*leaves).compile()
    except Exception:  # a program file this JAX cannot compile: the jit path
        return None

    def program(dyn):
        return jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(dyn)))

    return program


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
            program = self._compile(static, dynamic)
            self.last_compile_s = time.perf_counter() - start
            self.programs[key] = program
            while len(self.programs) > self.size:
                self.programs.popitem(last=False)
        self.programs.move_to_end(key)
        return program(dynamic)

    def _compile(self, static, dynamic) -> Callable:
        """The compiled program: through a program file when `enable_compile_cache` set a
        folder and the program exports, else traced, lowered and compiled here."""
        if _EXPORTS:
            program = exported_program(self.fn, static, dynamic, _EXPORTS[0])
            if program is not None:
                return program
        return jax.jit(lambda dyn: self.fn(*eqx.combine(dyn, static))).lower(dynamic).compile()

    def clear(self) -> None:
        """Drop every compiled program (they are freed once no result refers to them)."""
        self.programs.clear()


__all__ = [
    "CROWDED",
    "PROGRAMS",
    "BoundedJit",
    "clear_programs",
    "disable_program_files",
    "enable_compile_cache",
    "memory_mappings",
    "release_all",
]
