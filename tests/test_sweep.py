"""`sweep` (Monte Carlo over one condition, batched through `estimate_sharded`) and `bench`."""

import json

import jax
import jax.numpy as jnp
import pytest
from typer.testing import CliRunner

import jaxpose as jp
from jaxpose._cli import app
from jaxpose.evaluation.bench import machine, time_call
from jaxpose.evaluation.sweep import AXES, sweep_value

CONFIG = jp.Config.fast()  # capacities sized from each batch's pairs


@pytest.fixture(scope="module")
def noisy():
    return sweep_value("noise", 1.0, 3, CONFIG)


@pytest.mark.slow  # a vmapped compile of its own (~40 s); run with -m slow
def test_sweep_value_counts_are_consistent(noisy):
    assert noisy["trials"] == 3 and noisy["unusable"] == 0
    assert 0 <= noisy["success"] <= noisy["found"] <= 3 and noisy["false_success"] <= 3 - noisy["found"]
    assert len(noisy["rotation_errors_deg"]) == 3
    # 10° about a random axis with 1 cm range noise: the base case works (degraded.py: 100 %).
    assert noisy["found"] >= 2


@pytest.mark.slow  # a vmapped compile of its own (~40 s); run with -m slow
def test_sweep_value_is_reproducible(noisy):
    assert sweep_value("noise", 1.0, 3, CONFIG) == noisy


@pytest.mark.slow  # a vmapped compile of its own (~40 s); run with -m slow
def test_sweep_command_writes_json_and_plot(tmp_path, monkeypatch, noisy):
    # The fixture's condition and config, so the command reuses its compiled batch.
    monkeypatch.setitem(AXES, "noise", ("range noise σ, cm", (1.0,)))
    monkeypatch.setattr("jaxpose._cli._preset", lambda name: CONFIG)
    result = CliRunner().invoke(app, ["sweep", "--axes", "noise", "--trials", "3", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "sweep_default.json").read_text())
    assert data["results"]["noise"] == [noisy]
    assert (tmp_path / "sweep_default.png").stat().st_size > 10_000
    assert CliRunner().invoke(app, ["sweep", "--axes", "tilt"]).exit_code != 0


def test_time_call_reports_compile_and_median():
    res = time_call(jax.jit(lambda x: jnp.sin(x).sum()), jnp.ones(100), repeats=3)
    assert res["repeats"] == 3 and res["compile_s"] > 0 and res["median_s"] > 0
    assert machine()["backend"] == jax.default_backend()


def test_machine_names_the_cpu_model():
    """Results record the CPU's model: XLA:CPU compiles for the host's instruction set, so
    the same code gives different round-off (and a tracker's chain different tracks) on
    another CPU."""
    import platform

    model = machine()["cpu_model"]
    assert isinstance(model, str) and model
    try:
        with open("/proc/cpuinfo") as info:
            names = [line.split(":", 1)[1].strip() for line in info if line.startswith("model name")]
    except OSError:
        names = []
    assert model == (names[0] if names else platform.processor() or platform.machine())
