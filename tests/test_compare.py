"""`compare` pieces: the error measures, the summary, and a real peer (small_gicp, a dev
dependency) on a paper pair."""

import numpy as np
import pytest

from jaxpose.evaluation.comparison import pair_errors, run_peer, summarise
from jaxpose.evaluation.peers import PEERS, available_peers
from jaxpose.sim import paper_pair

PAIR = paper_pair("N5", "variant 2")


def test_the_true_motion_has_zero_error_and_a_perturbed_one_does_not():
    R, t = PAIR.motion
    exact = pair_errors(PAIR, R, t)
    assert max(exact.values()) < 1e-5
    turned = pair_errors(
        PAIR, R @ np.array([[1, 0, 0], [0, np.cos(0.01), -np.sin(0.01)], [0, np.sin(0.01), np.cos(0.01)]]), t
    )
    assert abs(turned["rotation_error_deg"] - np.degrees(0.01)) < 1e-4
    shifted = pair_errors(PAIR, R, np.asarray(t) + np.array([0.0, 0.0, 0.02]))
    assert shifted["rotation_error_deg"] < 1e-5 and 1.0 < shifted["translation_error_cm"] <= 2.0 + 1e-4


def test_summary_counts_found_and_false_successes():
    rows = [
        {"pair": "a", "method": "jaxpose", "rotation_error_deg": 0.2, "angle_error_deg": 0.1,
         "translation_error_cm": 0.1, "seconds": 0.1, "status": "success"},
        {"pair": "b", "method": "jaxpose", "rotation_error_deg": 3.0, "angle_error_deg": 2.0,
         "translation_error_cm": 1.0, "seconds": 0.3, "status": "success"},
        {"pair": "c", "method": "jaxpose", "rotation_error_deg": 5.0, "angle_error_deg": 4.0,
         "translation_error_cm": 2.0, "seconds": 0.2, "status": "low score"},
        {"pair": "d", "method": "jaxpose", "unusable": "flat"},
    ]  # fmt: skip
    s = summarise(rows, {"a": 10.0, "b": 20.0, "c": 20.0}, ((5, 15), (15, 25)))["jaxpose"]
    assert (s["pairs"], s["unusable"], s["found"], s["success"], s["false_success"]) == (3, 1, 1, 1, 1)
    assert s["found_by_angle"] == {"5-15 deg": (1, 1), "15-25 deg": (0, 2)}
    assert s["median_seconds"] == 0.2 and s["max_translation_error_cm"] == 2.0


def test_missing_peer_libraries_are_reported_not_raised():
    found, missing = available_peers()
    assert set(found) | set(missing) == set(PEERS)
    assert all(reason for reason in missing.values())


def test_small_gicp_gicp_is_the_sub_hundredth_degree_peer_on_the_paper_pair():
    found, _ = available_peers()
    if "small_gicp GICP" not in found:
        pytest.fail("small_gicp is a dev dependency and should import")
    (row,) = run_peer("small_gicp GICP", found["small_gicp GICP"], [PAIR])
    # Issue 4 quotes ≤ 0.003° and ≤ 0.005 cm on the paper's pairs; allow rounding of those.
    assert row["angle_error_deg"] < 0.01 and row["translation_error_cm"] < 0.01


def test_the_benchmarks_gicp_starts_where_it_is_told():
    """`realistic.gicp(..., start=(R, t))` starts small_gicp at that motion: from the true
    motion of a noise-free satellite pair it stays at the truth, and from a start turned a
    further 90° it ends elsewhere, so the start is the one given, not the identity."""
    from jaxpose.evaluation import realistic

    (case,) = realistic.make_cases(1, names=("satellite",), levels=(0.0,))
    prev, curr = case.prev.compact(), case.curr.compact()
    R, t = realistic.gicp(prev, curr, (case.rotation, case.translation))
    assert realistic.errors(case, R, t)["rotation_error_deg"] < 0.05
    quarter = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
    R, t = realistic.gicp(prev, curr, (quarter @ case.rotation, case.translation))
    assert realistic.errors(case, R, t)["rotation_error_deg"] > 10.0
