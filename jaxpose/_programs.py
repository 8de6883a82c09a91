"""Compiled programs of the public path: a bounded cache in memory, and files on disk.

Each compiled XLA:CPU program keeps a few thousand memory mappings while it lives, and Linux
allows 65,530 per process: a session that met a few dozen capacity buckets through
`jax.jit`'s unbounded cache would abort in the compiler. The public functions therefore
compile ahead of time (`jax.jit(…).lower(…).compile()`) and keep the `PROGRAMS` most
recently used programs; an evicted one is freed.

Every compiled program is also kept on disk by default, as XLA's serialised executable
(`jax.experimental.serialize_executable`), in `$JAXPOSE_CACHE/programs` (default
`~/.cache/jaxpose/programs`): a new process loads it instead of tracing, lowering and
compiling the Python functions again (about 2 s instead of 20 s for `estimate`'s program on a
2-core CPU). Nothing else in the process is touched: JAX's own configuration stays as the user
set it. `JAXPOSE_CACHE=off` (or `disable_compile_cache()`) keeps nothing on disk;
`enable_compile_cache(folder)` chooses the folder and also turns on JAX's persistent
compilation cache there, for the rest of the process's jitted code (the CLI calls it).
"""

from __future__ import annotations

import functools
import hashlib
import importlib
import os
import pickle
import platform
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
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
    next use (or load from their files)."""
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
"""The shortest compilation that `enable_compile_cache` keeps in JAX's persistent cache."""

MAX_CACHE_BYTES = 2 * 2**30
"""The most bytes of program files kept in a folder: after a program is saved, the least
recently used files (by modification time; a load touches its file) are deleted down to
this. `estimate`'s program is about 12 MB, so about 170 programs stay."""

OFF = frozenset({"", "0", "off", "false", "no", "none"})
"""Values of `$JAXPOSE_CACHE` (any case) that keep nothing on disk."""

_CHOICE: list[Path | None] = []
"""The folder chosen in this process (`enable_compile_cache`; None after
`disable_compile_cache`); empty: the default, read from `$JAXPOSE_CACHE` at each compile."""


def default_folder() -> Path | None:
    """The cache folder of the environment: `$JAXPOSE_CACHE`, `~/.cache/jaxpose` where it is
    not set, None where it is one of `OFF`."""
    value = os.environ.get("JAXPOSE_CACHE")
    if value is None:
        return Path.home() / ".cache" / "jaxpose"
    return None if value.strip().lower() in OFF else Path(value).expanduser()


def program_folder() -> Path | None:
    """Where compiled programs are kept now (`<folder>/programs`), or None for nowhere."""
    folder = _CHOICE[0] if _CHOICE else default_folder()
    return None if folder is None else folder / "programs"


def enable_compile_cache(folder: str | Path | None = None) -> Path | None:
    """Keep compiled programs in `folder` (default: `$JAXPOSE_CACHE`, else `~/.cache/jaxpose`),
    and turn on JAX's persistent compilation cache in `folder/xla` for the rest of the
    process's jitted code (compilations of `MIN_COMPILE_S` and longer). jaxpose's own programs
    go to `folder/programs` even without this call (see the module docstring); the CLI calls
    it. Returns the folder, or None where `folder` is None and `$JAXPOSE_CACHE` is off (then
    nothing is turned on). A program's file name hashes everything it depends on: the
    function, the static arguments, the argument shapes and dtypes, JAX's version and flags,
    the devices and the CPU, and jaxpose's own source, so that a changed program is never
    loaded. Files beyond `MAX_CACHE_BYTES` are deleted, least recently used first; remove the
    folder to reclaim all the space."""
    if folder is None:
        folder = default_folder()
        if folder is None:
            _CHOICE[:] = [None]
            return None
    folder = Path(folder).expanduser()
    jax.config.update("jax_compilation_cache_dir", str(folder / "xla"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    _CHOICE[:] = [folder]
    return folder


def disable_compile_cache() -> None:
    """Keep no compiled program on disk in this process, whatever `$JAXPOSE_CACHE` says (JAX's
    own persistent cache stays as it is)."""
    _CHOICE[:] = [None]


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


def _cpuinfo(prefixes: tuple[str, ...]) -> list[str] | None:
    """The distinct lines of Linux's /proc/cpuinfo that start with one of `prefixes`, stripped,
    in order (one per kind on a machine whose cores are alike); None where it cannot be read."""
    try:
        with open("/proc/cpuinfo") as info:
            return list(dict.fromkeys(line.strip() for line in info if line.startswith(prefixes)))
    except OSError:
        return None


@functools.cache
def _cpu_identity() -> str:
    """The CPU's model and instruction-set flags (Linux's /proc/cpuinfo, else the platform's
    description): XLA:CPU compiles for the host's instruction set, so a program compiled on one
    CPU must never run on another (a home folder shared between machines)."""
    lines = _cpuinfo(("model name", "flags", "Features"))
    return f"{platform.machine()} {platform.processor()}" if lines is None else "\n".join(lines)


def cpu_model() -> str:
    """The CPU's model name (Linux's /proc/cpuinfo; else the platform's processor), for the
    record of what results were measured on: the same code gives different round-off on
    different CPUs (`_cpu_identity`), and a tracker's chain of registrations carries such a
    difference on."""
    lines = _cpuinfo(("model name",))
    return lines[0].split(":", 1)[1].strip() if lines else platform.processor() or platform.machine()


def machine_identity() -> tuple:
    """What a compiled program depends on beyond its source: JAX's and jaxlib's versions, the
    devices, the CPU (`_cpu_identity`) and `XLA_FLAGS`."""
    from jaxlib import version as jaxlib_version

    devices = tuple((d.platform, d.device_kind) for d in jax.local_devices())
    return jax.__version__, jaxlib_version.__version__, devices, _cpu_identity(), os.environ.get("XLA_FLAGS", "")


def program_name(fn: Callable, static, intree, leaves) -> str:
    """The file name (without suffix) of `fn`'s program for these arguments: a hash of the
    function, the pickled static arguments, the argument tree, shapes and dtypes, the backend
    and tracing flags (x64, matmul precision, rank and dtype promotion), `machine_identity`,
    and jaxpose's source. Raises if the static arguments cannot be pickled."""
    digest = hashlib.sha256()
    parts = (
        fn.__module__,
        fn.__qualname__,
        source_digest(),
        machine_identity(),
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


SUFFIX = ".xla"


CPU_COMPILER_OPTIONS = {"xla_cpu_opt_preset": "CPU_OPT_PRESET_FAST_COMPILE"}
"""XLA options of jaxpose's own programs on the CPU backend (`jax.stages.Lowered.compile`'s
`compiler_options`, which apply to that program alone; the user's other jitted code keeps XLA's
defaults): XLA:CPU's optimisation preset for a short compile, meant to leave out passes that
spend compile time to buy run time. On jaxpose's programs it buys run time too, for reasons
not traced to a single pass (the programs are mostly small while loops: the search's
generations, the fine stage's rounds and Gauss–Newton steps): on eight realistic-benchmark
pairs (four targets, σ 0 and 1 cm) the public program's warm call took 0.62–0.84× the time
of XLA's defaults (median 0.70×), where XLA:CPU's elemental loop emitters alone
(`{"xla_cpu_use_fusion_emitters": False}`) gave 0.79–1.02× (median 0.87×); the compile took
as long, and the estimates are the same to round-off (`experiments/compiler_options.py`,
2-core AMD EPYC). An XLA that no longer knows an option, or this value of it, compiles
without it (`compile_lowered`)."""


def compiler_options() -> dict:
    """The XLA options jaxpose compiles its programs with: `CPU_COMPILER_OPTIONS` on the CPU
    backend, none elsewhere."""
    return dict(CPU_COMPILER_OPTIONS) if jax.default_backend() == "cpu" else {}


UNKNOWN_OPTION = ("No such compile option", "is not a valid enum value")
"""The messages with which XLA refuses an option it does not know, or a value of an enumerated
option it does not know ([`compile_lowered`][])."""


def compile_lowered(lowered: jax.stages.Lowered, options: dict | None = None) -> jax.stages.Compiled:
    """`lowered` compiled with `options` (default: [`compiler_options`][]); without them where
    XLA refuses one as unknown, or an enumerated option's value as unknown (an XLA that has
    dropped it). Any other refusal, such as a value of the wrong type, raises."""
    options = compiler_options() if options is None else options
    if not options:
        return lowered.compile()
    try:
        return lowered.compile(compiler_options=options)
    except jax.errors.JaxRuntimeError as error:
        if not any(reason in str(error) for reason in UNKNOWN_OPTION):
            raise
        return lowered.compile()


JAX_CACHE_HIT = "/jax/compilation_cache/cache_hits"
"""The monitoring event JAX records when a compile is answered by its persistent compilation
cache (`jax.monitoring`)."""


def _compile_flat(fn: Callable, static, intree, leaves):
    """`fn` traced, lowered and compiled on flat arguments (with [`compiler_options`][]): the
    compiled program (a callable of the leaves, returning the output's leaves), the output
    tree, and whether JAX's persistent compilation cache answered the compile
    (`JAX_CACHE_HIT`). Such an executable runs, but XLA:CPU cannot serialise it again: the
    copy fails at its first run ("Function ... not found", jaxlib 0.10.2), so it is never
    saved to a program file."""
    trees, hits = [], []

    def flat(*flat_args):
        out = fn(*eqx.combine(jax.tree.unflatten(intree, flat_args), static))
        out_leaves, out_tree = jax.tree.flatten(out)
        trees.append(out_tree)
        return out_leaves

    def count(event, **_):
        if event == JAX_CACHE_HIT:
            hits.append(event)

    jax.monitoring.register_event_listener(count)
    try:
        compiled = compile_lowered(jax.jit(flat).lower(*leaves))
    finally:
        jax.monitoring.unregister_event_listener(count)
    return compiled, trees[0], bool(hits)


LAPACK_PREPARATION = ("jax._src.lib.lapack", "prepare_lapack_call")
"""Module and name of the function that JAX's linear-algebra lowerings call to initialise
the CPU's LAPACK kernels (private to JAX: looked up when needed, so that a JAX without it
falls back to a lowering, `prepare_custom_calls`)."""


@functools.cache
def prepare_custom_calls() -> None:
    """Make ready, once per process, what the custom calls of a loaded program need: JAX
    initialises the CPU's LAPACK kernels (eigh, LU, Cholesky) when it first lowers a linear
    algebra operation, and a program loaded from a file is never lowered. Without this, the
    first program loaded in a fresh process that called eigh crashed it (segmentation fault,
    jaxlib 0.10.2). It calls the initialisation JAX's lowerings call (`LAPACK_PREPARATION`,
    0.3 s); where a JAX lacks it, it lowers a small program of those operations instead (not
    compiling it; 0.8 s on the 2-core CPU)."""
    module, name = LAPACK_PREPARATION
    try:
        getattr(importlib.import_module(module), name)("syevd_ffi", np.dtype(np.float32))
    except (ImportError, AttributeError):
        a = jnp.eye(2, dtype=jnp.float32)
        jax.jit(lambda a: (jnp.linalg.eigh(a), jnp.linalg.solve(a, a), jnp.linalg.cholesky(a))).lower(a)


def _load(path: Path):
    """The compiled program and output tree saved at `path`, or None if it cannot be read or
    loaded. A load touches the file (least recently used files are deleted first)."""
    if not os.path.isfile(path):  # no file (or none that can be read): compile
        return None
    prepare_custom_calls()
    try:
        payload, in_tree, flat_out, skeleton = pickle.loads(path.read_bytes())
        compiled = serialize_executable.deserialize_and_load(payload, in_tree, flat_out)
    except Exception:  # a missing, partial or incompatible file: compile again
        return None
    try:
        os.utime(path)
    except OSError:
        pass
    return compiled, jax.tree.structure(skeleton)


def _save(path: Path, compiled, out_tree) -> None:
    """Write the serialised program and its output tree (as a pytree of zeros) atomically, then
    trim the folder to `MAX_CACHE_BYTES`. A program that cannot be serialised (host callbacks)
    or a folder that cannot be written keeps no file."""
    try:
        payload, in_tree, flat_out = serialize_executable.serialize(compiled)
    except Exception:  # what XLA cannot serialise: the program still runs
        return
    skeleton = jax.tree.unflatten(out_tree, [0] * out_tree.num_leaves)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.parent / f"{path.name}.{os.getpid()}.partial"
        partial.write_bytes(pickle.dumps((payload, in_tree, flat_out, skeleton)))
        os.replace(partial, path)
        trim(path.parent)
    except OSError:  # a folder that cannot be written: the program still runs
        pass


def trim(folder: Path, limit: int = MAX_CACHE_BYTES) -> None:
    """Delete the least recently used program files of `folder` until they hold at most
    `limit` bytes (the newest file always stays)."""
    files = []
    for path in folder.glob(f"*{SUFFIX}"):
        try:
            stat = path.stat()
        except OSError:  # deleted meanwhile by another process
            continue
        files.append((stat.st_mtime, stat.st_size, path))
    files.sort()
    total = sum(size for _, size, _ in files)
    for _, size, path in files[:-1]:
        if total <= limit:
            break
        path.unlink(missing_ok=True)
        total -= size


def program_path(fn: Callable, static, intree, leaves, folder: Path | None) -> Path | None:
    """Where `fn`'s program for these arguments is kept in `folder` (`program_name`), or None:
    no folder, or static arguments that pickle cannot write (no file name)."""
    if folder is None:
        return None
    try:
        return folder / (program_name(fn, static, intree, leaves) + SUFFIX)
    except Exception:  # static arguments that pickle cannot write
        return None


def compiled_program(fn: Callable, static, dynamic, folder: Path | None) -> Callable:
    """`fn` compiled for these arguments: loaded from its program file in `folder` where it is
    there, else traced, lowered and compiled on the flat arguments (`_compile_flat`) and saved
    there, unless JAX's persistent compilation cache answered the compile (that executable
    cannot be serialised again). `folder` None (or static arguments that pickle cannot write)
    keeps no file. Returns a callable of `dynamic`."""
    leaves, intree = jax.tree.flatten(dynamic)
    path = program_path(fn, static, intree, leaves, folder)
    loaded = None if path is None else _load(path)
    if loaded is None:
        compiled, out_tree, from_jax_cache = _compile_flat(fn, static, intree, leaves)
        if path is not None and not from_jax_cache:
            _save(path, compiled, out_tree)
    else:
        compiled, out_tree = loaded

    def program(dyn):
        return jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(dyn)))

    return program


class BoundedJit:
    """`fn` compiled once per argument signature (shapes, dtypes and non-array leaves, as
    `eqx.filter_jit`), keeping the `size` most recently used programs. `last_compile_s` is
    the wall time (s) of the last compile (tracing and lowering included; or of the load,
    where the program came from a file), for benchmarks that report compile time apart from
    run time."""

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
            program = compiled_program(self.fn, static, dynamic, program_folder())
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
    "default_folder",
    "disable_compile_cache",
    "enable_compile_cache",
    "memory_mappings",
    "program_folder",
    "release_all",
]
