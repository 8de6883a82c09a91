"""Reading and writing point clouds: PLY (plyfile), PCD (pypcd4), NPY/NPZ (numpy), CSV.

Every format carries the validity mask, so an organised 204 × 204 frame survives a round
trip with its missing pixels. Conventions (camera frame c, metres):

- a `valid` field/column (0/1) is the mask when present;
- otherwise a point is valid when all its coordinates are finite — the PCL convention of
  NaN for missing returns in organised clouds;
- on writing, invalid points are written as NaN *and* `valid = 0`, so readers that know
  either convention see the same cloud.

PLY and PCD need the optional `io` extra (`pip install jaxpose[io]`); NPY, NPZ and CSV need
numpy only. Loading goes through [`jaxpose.Cloud.from_points`][], so a file with the wrong
shape or non-finite valid points raises the same ValueError as an array would.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ._cloud import Cloud

FORMATS = (".ply", ".pcd", ".npy", ".npz", ".csv")


def _need(module: str):
    try:
        return __import__(module)
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(f"reading this format needs {module!r}: pip install 'jaxpose[io]'.") from err


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(f"{path}: unknown point-cloud format {suffix!r}; use one of {', '.join(FORMATS)}.")
    return suffix


def _to_cloud(xyz: np.ndarray, valid: np.ndarray | None, path: Path) -> Cloud:
    xyz = np.asarray(xyz)
    if xyz.ndim == 3 and xyz.shape[-1] == 3:  # an organised (H, W, 3) frame
        xyz = xyz.reshape(-1, 3)
        valid = None if valid is None else np.asarray(valid).reshape(-1)
    if xyz.ndim != 2 or xyz.shape[-1] != 3:
        raise ValueError(f"{path}: expected points of shape (N, 3) or (H, W, 3), got {xyz.shape}.")
    if valid is None:
        valid = np.all(np.isfinite(xyz), axis=1)
    else:
        valid = np.asarray(valid)
        if not np.all(np.isin(valid, (0, 1))):
            raise ValueError(f"{path}: the 'valid' field must hold 0 or 1.")
        valid = valid.astype(bool)
    return Cloud.from_points(xyz.astype(np.float64 if xyz.dtype == np.float64 else np.float32), valid)


def _is_numeric_row(line: str) -> bool:
    try:
        [float(field) for field in line.split(",")]
    except ValueError:
        return False
    return True


def load_cloud(path: str | Path) -> Cloud:
    """Read a point cloud (camera frame c, metres) from a PLY, PCD, NPY, NPZ or CSV file.

    - PLY: the `vertex` element's `x`, `y`, `z` (and `valid` if present).
    - PCD: fields `x`, `y`, `z` (and `valid`); ASCII, binary or compressed.
    - NPY: an `(N, 3)` or organised `(H, W, 3)` array; NaN rows are invalid.
    - NPZ: arrays `points` and optionally `valid`.
    - CSV: columns x, y, z[, valid], comma separated, an optional header line.

    **Returns:** a checked [`jaxpose.Cloud`][]. **Raises:** FileNotFoundError, or ValueError
    naming the file and what is wrong with it.
    """
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such file.")
    valid = None
    try:
        if suffix == ".npy":
            xyz = np.load(path, allow_pickle=False)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                if "points" not in z:
                    raise ValueError(f"{path}: an .npz cloud needs an array named 'points'.")
                xyz = z["points"]
                valid = z["valid"] if "valid" in z else None
        elif suffix == ".csv":
            with open(path) as f:
                header = not _is_numeric_row(f.readline())
            table = np.loadtxt(path, delimiter=",", skiprows=int(header), ndmin=2)
            if table.shape[1] not in (3, 4):
                raise ValueError(f"{path}: expected 3 or 4 CSV columns (x, y, z[, valid]), got {table.shape[1]}.")
            xyz = table[:, :3]
            valid = table[:, 3] if table.shape[1] == 4 else None
        elif suffix == ".ply":
            plyfile = _need("plyfile")
            vertex = plyfile.PlyData.read(str(path))["vertex"]
            names = vertex.data.dtype.names
            if not {"x", "y", "z"} <= set(names):
                raise ValueError(f"{path}: the PLY vertex element has no x, y, z properties.")
            xyz = np.stack([vertex[c] for c in "xyz"], axis=1)
            valid = vertex["valid"] if "valid" in names else None
        else:
            pypcd4 = _need("pypcd4")
            pc = pypcd4.PointCloud.from_path(path)
            if not {"x", "y", "z"} <= set(pc.fields):
                raise ValueError(f"{path}: the PCD file has no x, y, z fields.")
            xyz = pc.numpy(("x", "y", "z"))
            valid = pc.numpy(("valid",))[:, 0] if "valid" in pc.fields else None
    except Exception as err:  # each reader has its own error types; name the file either way
        if isinstance(err, ValueError) and str(err).startswith(str(path)):
            raise
        if isinstance(err, ImportError):
            raise
        raise ValueError(f"{path}: cannot read it as {suffix[1:].upper()}: {err}") from err
    return _to_cloud(xyz, valid, path)


def save_cloud(path: str | Path, cloud: Cloud) -> Path:
    """Write `cloud` (camera frame c, metres) with its validity mask; the format follows the
    suffix (see [`load_cloud`][]). Invalid points are written as NaN with `valid = 0`.

    **Returns:** the path written.
    """
    path = Path(path)
    suffix = _suffix(path)
    cloud.check("cloud")
    valid = np.asarray(cloud.valid)
    xyz = np.where(valid[:, None], np.asarray(cloud.points), np.nan)
    if suffix == ".npy":
        np.save(path, xyz)
    elif suffix == ".npz":
        np.savez(path, points=xyz, valid=valid)
    elif suffix == ".csv":
        table = np.column_stack([xyz, valid.astype(xyz.dtype)])
        np.savetxt(path, table, delimiter=",", header="x,y,z,valid", comments="", fmt="%.9g")
    elif suffix == ".ply":
        plyfile = _need("plyfile")
        dt = xyz.dtype.str
        rows = np.empty(len(xyz), dtype=[("x", dt), ("y", dt), ("z", dt), ("valid", "u1")])
        rows["x"], rows["y"], rows["z"], rows["valid"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], valid
        plyfile.PlyData([plyfile.PlyElement.describe(rows, "vertex")]).write(str(path))
    else:
        pypcd4 = _need("pypcd4")
        data = np.column_stack([xyz, valid.astype(xyz.dtype)])
        fields = ("x", "y", "z", "valid")
        types = (xyz.dtype.type,) * 3 + (np.uint8,)
        pypcd4.PointCloud.from_points(data, fields, types).save(path)
    return path


__all__ = ["FORMATS", "load_cloud", "save_cloud"]
