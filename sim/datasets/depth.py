"""Depth maps beside a sequence's frames: a `depth.txt` list (TUM format, `timestamp path`) of
16-bit PNGs, each associated with the colour frame nearest in time."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from calib.camera_yaml import load_depth_spec
from calib.depth_camera import TUM_DEPTH_SCALE, DepthSpec
from daemon.recordings import read_frame_list
from sdvl.errors import InputError

# s: a depth map further than this from every colour frame is not used; TUM's associate.py
# uses 0.02 s by default, and the Kinect's depth and colour streams are 1/60 s apart at worst
MAX_ASSOCIATION_S = 0.02


def associate(frame_times: np.ndarray, depth_times: np.ndarray,
              max_dt: float = MAX_ASSOCIATION_S) -> np.ndarray:
    """For each frame, the index of its depth map (-1: none): pairs closer than `max_dt`,
    closest first, each frame and each depth map used at most once (as TUM's associate.py)."""
    out = np.full(frame_times.size, -1, dtype=np.int64)
    if depth_times.size == 0:
        return out
    j = np.searchsorted(depth_times, frame_times)
    pairs = []
    for k in (j - 1, j):  # the depth maps just before and just after each frame
        ok = (k >= 0) & (k < depth_times.size)
        i = np.flatnonzero(ok)
        dt = np.abs(depth_times[k[ok]] - frame_times[ok])
        pairs.append(np.column_stack([dt, i, k[ok]])[dt < max_dt])
    pairs = np.vstack(pairs)
    used = np.zeros(depth_times.size, dtype=bool)
    for _, i, k in pairs[np.argsort(pairs[:, 0], kind="stable")]:
        i, k = int(i), int(k)
        if out[i] < 0 and not used[k]:
            out[i], used[k] = k, True
    return out


class DepthFiles:
    """Depth map of frame i on demand (None when no depth map was associated with it)."""

    def __init__(self, files: list[Path], index: np.ndarray, spec: DepthSpec,
                 camera: CameraModel):
        self.files, self.index, self.spec, self.camera = files, index, spec, camera

    def __call__(self, i: int) -> np.ndarray | None:
        k = int(self.index[i])
        if k < 0:
            return None
        path = self.files[k]
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise InputError("cannot read depth image (missing or corrupt)", path)
        if raw.dtype != np.uint16 or raw.ndim != 2:
            raise InputError(f"depth image must be a 16-bit single-channel PNG, got {raw.dtype} "
                             f"with {1 if raw.ndim == 2 else raw.shape[2]} channel(s)", path)
        try:
            return self.spec.to_metres(raw, self.camera)
        except InputError as exc:
            raise InputError(exc.message, path) from None


def folder_depth_spec(folder: Path) -> DepthSpec:
    """The `depth` keys of the folder's camera.yaml if it has them, else TUM's convention:
    16-bit PNG at 5000 units per metre, registered to the colour camera (by the Kinect's
    driver in TUM RGB-D)."""
    spec = None
    if (folder / "camera.yaml").is_file():
        spec = load_depth_spec(folder / "camera.yaml")
    return spec or DepthSpec(TUM_DEPTH_SCALE)


def depth_list(folder: Path, frame_times: np.ndarray, spec: DepthSpec,
               camera: CameraModel) -> DepthFiles | None:
    """The depth maps listed in `folder/depth.txt`, associated with the frames; None without
    the file. InputError when it lists depth maps but none is near any frame's time."""
    path = folder / "depth.txt"
    if not path.is_file():
        return None
    times, files = read_frame_list(path)
    index = associate(frame_times, times)
    if times.size and not np.any(index >= 0):
        raise InputError(f"no depth map within {MAX_ASSOCIATION_S} s of any frame (are the "
                         "timestamps of depth.txt and the frame list on the same clock?)", path)
    return DepthFiles(files, index, spec, camera)
