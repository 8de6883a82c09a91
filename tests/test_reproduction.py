"""The reproduction (`jaxpose reproduce`): Table 3's definitions, the paper's truth frame, and
the command end to end on small searches."""

import csv

import numpy as np
import pytest
from typer.testing import CliRunner

from jaxpose._cli import app
from jaxpose.evaluation.reproduction import PAPER_TABLE3, PAPER_TABLES, paper_truth_angles, relative_errors


def test_relative_errors_recompute_the_papers_table3_from_its_tables_1_and_2():
    # Table 3 agrees with found − truth (not the printed Δ row of Table 1 N1; DECISIONS.md).
    # Printed values are rounded to integers, and METHOD.md §11.7 recomputes N5 v1 δr as 61.1
    # against a printed 60: the paper's own inconsistency, hence 1.5 points.
    for key, rows in PAPER_TABLES.items():
        error = np.subtract(rows["found"], rows["truth"])
        d_alpha, d_r = relative_errors(rows["truth"], error)
        assert abs(d_alpha - PAPER_TABLE3[key][0]) <= 1.5, key
        assert abs(d_r - PAPER_TABLE3[key][1]) <= 1.5, key


def test_relative_errors_do_not_depend_on_units():
    truth, error = np.array([1.0, -2.0, 3.0, 0.01, 0.02, -0.03]), np.array([0.1, 0.1, -0.3, 0.001, 0.0, 0.002])
    to_deg_cm = np.array([57.29577951308232] * 3 + [100.0] * 3)
    np.testing.assert_allclose(relative_errors(truth, error), relative_errors(truth * to_deg_cm, error * to_deg_cm))
    assert np.allclose(relative_errors(truth, error), (100 * np.mean([0.1, 0.05, 0.1]), 100 * np.sqrt(5e-6 / 14e-4)))


def test_papers_truth_rows_are_recomputed_in_its_fixed_frame():
    for variant in ("variant 1", "variant 2"):
        printed = PAPER_TABLES[(variant, "N5")]["truth"][:3]
        np.testing.assert_allclose(paper_truth_angles(variant), printed, atol=0.01)


@pytest.mark.slow  # the whole command (46 s); the paper's pairs are checked in test_estimate
def test_reproduce_command_writes_tables_and_figures(tmp_path):
    result = CliRunner().invoke(app, ["reproduce", "--quick", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    text = (tmp_path / "reproduction.md").read_text()
    for title in ("Table 1 — variant 1", "Table 2 — variant 2", "Table 3 — relative errors"):
        assert title in text
    assert "| N1 | paper: Δ as printed | -1.29 | 0.10 | -0.59 | 0.34 | 0.38 | -0.02 |" in text
    with open(tmp_path / "reproduction.csv") as f:
        rows = list(csv.DictReader(f))
    ours = [r for r in rows if r["source"].startswith("jaxpose")]
    assert len([r for r in rows if r["source"] == "paper"]) == 12 and len(ours) == 24
    angles = ("θ, °", "φ, °", "ψ, °")
    errors = np.array([[float(r[k]) for k in angles] for r in ours if r["row"] == "error"])
    assert np.all(np.isfinite(errors))
    # The default method, even with the quick (fast) search, beats the paper's worst error
    # (1.29°) on every pair and stays under 1° on variant 2.
    default = [r for r in ours if r["source"] == "jaxpose default" and r["row"] == "error"]
    assert max(abs(float(r[k])) for r in default for k in angles) < 1.29
    assert max(abs(float(r[k])) for r in default if r["variant"] == "variant 2" for k in angles) < 1.0
    for name in ("fig4_clouds", "fig5_selected", "fig6_patterns_paper", "fig6_patterns_default"):
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000
