"""A bounded in-memory cache of compiled programs for the public path, backed by a disk cache.

Each compiled XLA:CPU program keeps a few thousand memory mappings while it lives, and Linux
allows 65,530 per process: a session that met a few dozen capacity buckets through
`jax.jit`'s unbounded cache would abort in the compiler. The public functions therefore
compile ahead of time (`jax.jit(…).lower(…).compile()`) and keep the `PROGRAMS` most
recently used programs; an evicted one is freed.

When JAX's persistent compilation cache is set (`jax_compilation_cache_dir`, as the CLI
does), each compiled program is also serialised to `<that folder>/jaxpose-programs`
(`jax.experimental.serialize_executable`) under a key of its signature, the package versions,
the device and the digest of jaxpose's own sources. A new process then loads it without
tracing or lowering the program: JAX's own cache still traces and lowers to compute its key,
about 3 s of the estimate's warm start on the 2-core CPU. A file that does not load (another
version of a library, a truncated write) is compiled again and replaced.
"""

from __future__ import annotations

import copyreg
import hashlib
import importlib.metadata
import io
import os
import pickle
import re
import threading
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
from jax.experimental import serialize_executable

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


PROGRAM_FOLDER = "jaxpose-programs"
"""Sub-folder of JAX's compilation cache folder that holds the serialised programs."""


def program_cache_dir() -> Path | None:
    """The folder of serialised programs: `PROGRAM_FOLDER` in JAX's persistent compilation
    cache folder when one is set (and local), else None (no disk cache)."""
    root = jax.config.jax_compilation_cache_dir
    if not root or "://" in str(root):
        return None
    return Path(root) / PROGRAM_FOLDER


def enable_compile_cache(folder: str | Path | None = None) -> Path:
    """Keep compiled programs on disk, so that a new process skips compiling `estimate` and
    `track`: sets JAX's persistent compilation cache to `folder` (default `$JAXPOSE_CACHE`,
    else `~/.cache/jaxpose/xla`) for compilations of 1 s and longer, which also turns on
    jaxpose's own cache of whole programs (`program_cache_dir`). Returns the folder. The CLI
    calls it. Files are never deleted; remove the folder to reclaim the space (about 10 MB
    per capacity bucket of `estimate`)."""
    if folder is None:
        folder = os.environ.get("JAXPOSE_CACHE", Path.home() / ".cache" / "jaxpose" / "xla")
    folder = Path(folder).expanduser()
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return folder


_LIBRARIES = ("jax", "jaxlib", "equinox", "optimistix", "lineax", "evosax", "jaxlie")


def _environment() -> str:
    """What a serialised program depends on besides its signature: library versions, the
    devices, XLA's flags, 64-bit mode and jaxpose's sources."""
    versions = []
    for name in _LIBRARIES:
        try:
            versions.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name}=none")
    devices = [f"{d.platform}:{d.device_kind}" for d in jax.devices()]
    return repr((versions, devices, os.environ.get("XLA_FLAGS", ""), jax.config.jax_enable_x64, _source_digest()))


_SOURCE_DIGEST: list[str] = []


def _source_digest() -> str:
    """sha256 of every Python file of the jaxpose package (computed once per process)."""
    if not _SOURCE_DIGEST:
        digest = hashlib.sha256()
        package = Path(__file__).parent
        for path in sorted(package.rglob("*.py")):
            digest.update(str(path.relative_to(package)).encode())
            digest.update(path.read_bytes())
        _SOURCE_DIGEST.append(digest.hexdigest())
    return _SOURCE_DIGEST[0]


_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")

TRUSTED_MODULES = (*_LIBRARIES, "jaxpose", "numpy", "builtins")
"""Packages whose functions a key may name without their code: the versions (or, for jaxpose,
the sources) in `_environment()` fix what they do."""


def _static_values(node) -> list:
    """The non-array values of a signature (`_signature`): its static leaves and the static
    fields held in its tree definitions' node data."""
    if isinstance(node, jax.tree_util.PyTreeDef):
        data = node.node_data()
        values = [] if data is None else _static_values(data[1])
        return values + [v for child in node.children() for v in _static_values(child)]
    if isinstance(node, tuple | list):
        return [v for item in node for v in _static_values(item)]
    if isinstance(node, dict):
        return [v for item in node.values() for v in _static_values(item)]
    return [node]


def cacheable(signature: tuple) -> bool:
    """Whether a program can be found again by its signature's text: every function in it
    comes from a `TRUSTED_MODULES` package (its text is its name, not its code), and no other
    value prints as an anonymous `<… at 0x…>` object. A config holding a user's own function
    is compiled in every process instead: its name would not say which code it ran."""
    for value in _static_values(signature):
        if isinstance(value, type):
            continue
        if callable(value) and not isinstance(value, eqx.Module):
            module = getattr(value, "__module__", None) or ""
            if module.split(".")[0] not in TRUSTED_MODULES:
                return False
        elif _ADDRESS.search(repr(value)):
            return False
    return True


def program_key(fn: Callable, signature: tuple) -> str:
    """The disk cache's file name of `fn`'s program for `signature` (`_signature`): a sha256
    of the function's name, the signature's text without memory addresses (a library function
    in a config prints as `<function max_norm at 0x…>`; see `cacheable`) and `_environment()`."""
    text = _ADDRESS.sub("", f"{fn.__module__}.{fn.__qualname__}|{signature!r}|{_environment()}")
    return hashlib.sha256(text.encode()).hexdigest()


def _equinox_missing():
    """equinox's marker of an absent field (None if this equinox has none)."""
    try:
        from equinox._module._flatten import MISSING
    except ImportError:
        return None
    return MISSING


class _TreePickler(pickle.Pickler):
    """Pickles JAX tree definitions of equinox modules: equinox marks an absent field with a
    singleton (`MISSING`) that plain pickling would copy, and its unflattening compares by
    identity, so the singleton is pickled as a reference to itself."""

    dispatch_table = copyreg.dispatch_table.copy()
    if _equinox_missing() is not None:
        dispatch_table[type(_equinox_missing())] = lambda _: (_equinox_missing, ())


def save_program(path: Path, program) -> None:
    """Serialise a compiled program to `path` (written apart, then renamed: a reader never sees
    a partial file). Failures are ignored: the disk cache only saves time. Serialising the
    estimate's program takes about 0.8 s on the 2-core CPU, so `BoundedJit` calls this in a
    thread of its own while the program runs (`save_in_background`)."""
    try:
        buffer = io.BytesIO()
        _TreePickler(buffer, protocol=pickle.HIGHEST_PROTOCOL).dump(serialize_executable.serialize(program))
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(f".{os.getpid()}.partial")
        partial.write_bytes(buffer.getvalue())
        os.replace(partial, path)
    except Exception:  # noqa: BLE001 - a cache write must never fail the call
        pass


def save_in_background(path: Path, program) -> threading.Thread:
    """`save_program` in a (non-daemon) thread: the process waits for it before it exits, so
    the file is written whole or not at all."""
    thread = threading.Thread(target=save_program, args=(path, program), name="jaxpose-save-program")
    thread.start()
    return thread


def load_program(path: Path):
    """The compiled program serialised at `path`, or None when there is none or it does not
    load (it is then compiled again and overwritten)."""
    if not path.is_file():
        return None
    try:
        return serialize_executable.deserialize_and_load(*pickle.loads(path.read_bytes()))
    except Exception:  # noqa: BLE001 - a stale or damaged file is recompiled
        return None


class BoundedJit:
    """`fn` compiled once per argument signature (shapes, dtypes and non-array leaves, as
    `eqx.filter_jit`), keeping the `size` most recently used programs, and loaded from the
    disk cache (`program_cache_dir`) where one is set. `last_compile_s` is the wall time (s)
    of the last program made (tracing, lowering and compiling, or loading it from disk) and
    `last_source` says which ("compiled" or "disk"), for benchmarks that report compile
    time apart from run time."""

    def __init__(self, fn: Callable, size: int = PROGRAMS):
        self.fn, self.size = fn, size
        self.nested = eqx.filter_jit(fn)
        self.programs: OrderedDict = OrderedDict()
        self.last_compile_s = 0.0
        self.last_source = ""
        self.saving: threading.Thread | None = None  # the last program's write to the disk cache
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
            program = self._make(key, static, dynamic)
            self.last_compile_s = time.perf_counter() - start
            self.programs[key] = program
            while len(self.programs) > self.size:
                self.programs.popitem(last=False)
        self.programs.move_to_end(key)
        return program(dynamic)

    def _make(self, key, static, dynamic):
        """The program for one signature: from the disk cache, or compiled (and saved there)."""
        folder = program_cache_dir()
        path = None if folder is None or not cacheable(key) else folder / f"{program_key(self.fn, key)}.program"
        program = None if path is None else load_program(path)
        self.last_source = "disk" if program is not None else "compiled"
        if program is None:
            program = jax.jit(lambda dyn: self.fn(*eqx.combine(dyn, static))).lower(dynamic).compile()
            if path is not None:
                self.saving = save_in_background(path, program)
        return program

    def clear(self) -> None:
        """Drop every compiled program (they are freed once no result refers to them)."""
        self.programs.clear()


__all__ = [
    "CROWDED",
    "PROGRAMS",
    "BoundedJit",
    "cacheable",
    "clear_programs",
    "enable_compile_cache",
    "load_program",
    "memory_mappings",
    "program_cache_dir",
    "program_key",
    "release_all",
    "save_program",
]
