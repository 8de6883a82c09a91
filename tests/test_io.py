"""Point-cloud files: round trips with the validity mask, foreign conventions, clear errors,
and the `jaxpose estimate PREV CURR` command on saved files."""

import json

import numpy as np
import plyfile
import pytest
from conftest import T_PAPER, paper_rotation
from typer.testing import CliRunner

import jaxpose as jp
from jaxpose._cli import app
from jaxpose._io import FORMATS


@pytest.mark.parametrize("suffix", FORMATS)
def test_round_trip_keeps_points_and_mask(tmp_path, paper_clouds, suffix):
    cloud = paper_clouds["n5", "previous"]  # organised 204 × 204 frame, most pixels missing
    assert 0 < int(cloud.num_valid) < cloud.points.shape[0]
    back = jp.load_cloud(jp.save_cloud(tmp_path / f"c{suffix}", cloud))
    np.testing.assert_array_equal(np.asarray(back.valid), np.asarray(cloud.valid))
    np.testing.assert_allclose(back.compact(), cloud.compact(), rtol=1e-7, atol=1e-12)


def test_nan_rows_are_missing_points_without_a_mask(tmp_path):
    xyz = np.random.default_rng(0).normal(size=(6, 4, 3))  # organised (H, W, 3)
    xyz[1, 2] = np.nan
    np.save(tmp_path / "o.npy", xyz)
    cloud = jp.load_cloud(tmp_path / "o.npy")
    assert cloud.points.shape == (24, 3) and int(cloud.num_valid) == 23
    assert not bool(cloud.valid[1 * 4 + 2])


def test_foreign_ply_and_headerless_csv(tmp_path):
    pts = np.random.default_rng(1).normal(size=(50, 3)).astype(np.float32)
    rows = np.array([tuple(p) for p in pts], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")], text=True).write(str(tmp_path / "a.ply"))
    np.savetxt(tmp_path / "a.csv", pts, delimiter=",")
    for name in ("a.ply", "a.csv"):
        cloud = jp.load_cloud(tmp_path / name)
        assert int(cloud.num_valid) == 50
        np.testing.assert_allclose(cloud.compact(), pts, rtol=1e-6)


@pytest.mark.parametrize(
    "name, content, message",
    [
        ("a.xyz", "1,2,3\n", "unknown point-cloud format"),
        ("a.csv", "1,2\n3,4\n", "3 or 4 CSV columns"),
        ("a.csv", "1,2,3,2\n", "must hold 0 or 1"),
        ("a.csv", "1,2,nan,1\n", "NaN or inf"),
        ("a.csv", "x,y,z\n1,2,banana\n", "cannot read it as CSV"),
        ("a.ply", "not a ply file", "cannot read it as PLY"),
        ("a.pcd", "garbage\n", "cannot read it as PCD"),
    ],
)
def test_bad_files_raise_a_clear_error(tmp_path, name, content, message):
    (tmp_path / name).write_text(content)
    with pytest.raises(ValueError, match=message):
        jp.load_cloud(tmp_path / name)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError):
        jp.load_cloud(tmp_path / "nothing.ply")


@pytest.fixture(scope="module")
def saved_pair(tmp_path_factory, paper_clouds):
    folder = tmp_path_factory.mktemp("pair")
    prev = jp.save_cloud(folder / "prev.ply", paper_clouds["n5", "previous"])
    curr = jp.save_cloud(folder / "curr.pcd", paper_clouds["n5", "variant2"])
    return prev, curr


def test_estimate_command_on_files(saved_pair, paper_clouds, monkeypatch, tmp_path_factory):
    monkeypatch.setenv("JAXPOSE_CACHE", str(tmp_path_factory.mktemp("xla")))
    prev, curr = saved_pair
    result = CliRunner().invoke(app, ["estimate", str(prev), str(curr), "--preset", "fast", "--json"])
    assert result.exit_code in (0, 1), result.output
    out = json.loads(result.output)
    frame = jp.plane_frame(paper_clouds["n5", "previous"])
    R1, R2 = paper_rotation("previous"), paper_rotation("variant2")
    truth = np.asarray(jp.true_displacement(frame, R1, T_PAPER, R2, T_PAPER))
    assert np.max(np.abs(np.array(out["frame_n"]["angles_deg"]) - np.degrees(truth[:3]))) < 0.5
    assert np.max(np.abs(np.array(out["frame_n"]["translation_cm"]) - 100 * truth[3:])) < 0.5
    # camera frame: the motion's rotation is G2 G1ᵀ (degrees at this boundary)
    R_true = np.asarray(R2 @ R1.T)
    R = np.array(out["camera_frame"]["rotation_matrix"])
    assert np.degrees(float(jp.rotation_angle(R, R_true))) < 0.5
    assert (result.exit_code == 0) == (out["status"] == 0)
    # The distinct hypotheses, the estimate first (degrees and centimetres at this boundary).
    first = out["hypotheses"][0]
    np.testing.assert_allclose(first["rotation_angles_deg"], out["camera_frame"]["rotation_angles_deg"])
    np.testing.assert_allclose(first["translation_cm"], out["camera_frame"]["translation_cm"])
    assert out["ambiguous"] in (True, False)
    assert 0.0 <= out["spread_deg"] < 0.5  # degrees: the fits of a noise-free pair agree
    assert 0.0 < out["residual_scale_cm"] < 0.1  # centimetres: a noise-free pair's residuals are round-off


def test_estimate_command_rejects_bad_input(saved_pair, tmp_path):
    prev, _ = saved_pair
    # Collinear points: no plane frame (a coplanar cloud has one).
    (tmp_path / "flat.csv").write_text("\n".join(f"{0.01 * i},{0.02 * i},{4 + 0.005 * i}" for i in range(60)))
    result = CliRunner().invoke(app, ["estimate", str(tmp_path / "flat.csv"), str(prev)])
    assert result.exit_code == 2
    assert "flat" in result.output or "plane frame" in result.output
    result = CliRunner().invoke(app, ["estimate", str(tmp_path / "none.ply"), str(prev)])
    assert result.exit_code == 2 and "no such file" in result.output
