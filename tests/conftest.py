"""Shared fixtures. Tests run in float64 (the reference comparisons need it); the few float32
checks create their arrays explicitly. Clouds and problems are built once per session so
compiled functions are shared."""

import os
import shutil
import tempfile

import jax

jax.config.update("jax_enable_x64", True)
# Implicit rank promotion ((N, 3) − (3,)) is an error in the tests, as in optimistix.
jax.config.update("jax_numpy_rank_promotion", "raise")
# The package's annotations are checked at run time (jaxtyping + beartype, pyproject's addopts).
# One persistent compilation cache per test session, empty at its start, so the notebooks'
# kernels (which inherit the environment) reuse each other's compiles. jaxpose's own program
# files (on by default, `jaxpose._programs`) are off unless a test turns them on: each would
# add a serialisation and a file of megabytes to every compile of the session. The tests of
# the program files and of the CLI set `JAXPOSE_CACHE` to a folder of their own. The process
# that makes the XLA folder (pytest-xdist's controller; its workers inherit the variables)
# removes it when the session ends.
_OWN_FOLDERS = []
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxpose-test-xla-")
    _OWN_FOLDERS.append(os.environ["JAX_COMPILATION_CACHE_DIR"])
os.environ.setdefault("JAXPOSE_CACHE", "off")

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import jaxpose as jp  # noqa: E402
from jaxpose import _programs  # noqa: E402
from jaxpose._programs import memory_mappings, release_all  # noqa: E402
from jaxpose.sim import PAPER_T, paper_pose  # noqa: E402

DEG = np.pi / 180
PAPER_POSE_NAMES = {"previous": "previous", "variant1": "variant 1", "variant2": "variant 2"}
"""Short fixture keys for the paper's poses (jaxpose.sim.PAPER_POSES)."""
T_PAPER = np.asarray(PAPER_T)
PAPER_CAPACITIES = jp.Capacities(max_points=5120, max_prev_points=8192, grid_cells=128, max_cells=512)
"""Capacities that hold both paper shapes' pairs (what `sized_config` gives N5): tests that
fix them share one compiled program per preset across the paper's pairs and files (the
session's persistent compilation cache), where sizing from each pair compiles N1's and N5's."""


def paper_rotation(name):
    return paper_pose(PAPER_POSE_NAMES[name])[0]


@pytest.fixture(scope="session")
def camera():
    return jp.Camera.camcube2()


@pytest.fixture(scope="session")
def paper_clouds(camera):
    """{(shape, pose): Cloud} for the paper's shapes and poses (noise-free)."""
    out = {}
    for shape in ("n1", "n5"):
        target = getattr(jp.targets, shape)()
        for pose in PAPER_POSE_NAMES:
            out[shape, pose] = jp.simulate(camera, target, paper_rotation(pose), jnp.asarray(T_PAPER))
    return out


@pytest.fixture(scope="session")
def n5_problem(paper_clouds):
    return jp.Problem.build(paper_clouds["n5", "previous"], paper_clouds["n5", "variant2"])


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The reproduction notebook reruns the paper's table (what `jaxpose reproduce` does,
    tested by test_reproduction and test_cli) in a kernel of its own, ≈ 65 s of the default
    run: it runs with `-m slow`, as does the quickstart notebook (≈ 80 s of a kernel that
    compiles its own programs; the calls it shows are tested here)."""
    for item in items:
        if item.nodeid.endswith(".ipynb"):
            item.add_marker(pytest.mark.slow)


MAX_MAPPINGS = 30_000  # Linux allows 65,530 memory mappings per process (vm.max_map_count)


@pytest.fixture(autouse=True)
def release_compiled_programs():
    """Each compiled XLA:CPU program holds ≈ 3,000 memory mappings while it is cached, so a
    session that compiles a few dozen capacity buckets would exhaust Linux's per-process
    limit and abort. Releasing the compiled programs when the count grows frees them; the
    persistent compilation cache above makes the recompiles that follow cheap."""
    yield
    if memory_mappings() > MAX_MAPPINGS:
        release_all()


@pytest.fixture(autouse=True)
def restore_compile_cache():
    """The CLI's commands, invoked in process by the tests, choose a folder for the program
    files and turn on JAX's compilation cache (`enable_compile_cache`); each test's successors
    start as they would have without it, so which tests run through program files does not
    depend on the scheduling."""
    before = (
        list(_programs._CHOICE),
        jax.config.jax_compilation_cache_dir,
        jax.config.jax_persistent_cache_min_compile_time_secs,
    )
    yield
    _programs._CHOICE[:] = before[0]
    jax.config.update("jax_compilation_cache_dir", before[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", before[2])


def pytest_sessionfinish(session, exitstatus):
    for folder in _OWN_FOLDERS:
        shutil.rmtree(folder, ignore_errors=True)
