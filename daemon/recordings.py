"""Recorded frames on disk as a camera: a frame list of `timestamp relative/path` lines
(frames.txt of the shared-data layout and of `sdvl render`, rgb.txt of TUM RGB-D) or a folder of
images, with a camera.yaml in the folder or beside it, and the depth maps beside the frames: a
`depth.txt` list (TUM format, `timestamp path`) of 16-bit PNGs, each associated with the colour
frame nearest in time. The replay side's dataset readers (sim.datasets) build on these
functions."""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from calib.camera_yaml import load_camera, load_depth_spec
from calib.depth_camera import TUM_DEPTH_SCALE, DepthSpec
from sdvl.errors import InputError
from sdvl.textfile import check_increasing, parse_floats, read_lines

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
FRAME_LISTS = ("frames.txt", "rgb.txt")
DEFAULT_FPS = 30.0


def load_grey(path: str | Path) -> np.ndarray:
    """A uint8 grey image from a file; InputError if it cannot be decoded."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError("cannot read image (missing or corrupt)", path)
    return image


def read_frame_list(path: Path) -> tuple[np.ndarray, list[Path]]:
    """Times and absolute image paths from a `timestamp relative/path` list."""
    times, files = [], []
    for line, fields in read_lines(path):
        if len(fields) != 2:
            raise InputError("expected 'timestamp relative/path'", path, line)
        times.append(parse_floats(fields[:1], path, line, "a timestamp")[0])
        files.append(path.parent / fields[1])
    times = np.array(times)
    check_increasing(times, path)
    return times, files


def _natural_key(path: Path) -> list:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", path.name)]


def image_files(path: Path) -> list[Path]:
    """The image files of a folder in natural order (img2 before img10)."""
    return sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                  key=_natural_key)


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


class DepthMaps:
    """Frame-indexed depth maps of a recording or sequence with a `name` and a
    `depth_loader(i)` (None where it has no depth)."""

    name: str
    depth_loader: Callable[[int], np.ndarray | None] | None

    @property
    def has_depth(self) -> bool:
        """True when it comes with depth maps."""
        return self.depth_loader is not None

    def depth(self, index: int) -> np.ndarray | None:
        """Depth map of frame `index`: float32 metres along the optical axis in the frame's
        pixels, 0 or NaN = no measurement; None when that frame has none. InputError when its
        file is missing or corrupt, or there are no depth maps at all."""
        if self.depth_loader is None:
            raise InputError(f"'{self.name}' has no depth (no depth.txt beside its frame list)")
        return self.depth_loader(index)


@dataclass
class Recording(DepthMaps):
    """Image files with their times; `camera` is None when no camera.yaml was found;
    `depth_loader(i)` gives frame i's depth map (as sim.sequence.Sequence's) where the folder
    has a depth.txt."""

    name: str
    camera: CameraModel | None
    timestamps: np.ndarray
    files: list[Path]
    depth_loader: Callable[[int], np.ndarray | None] | None = None

    def __len__(self) -> int:
        return len(self.files)

    def frames(self, max_frames: int | None = None) -> Iterator[tuple[float, np.ndarray]]:
        """(t seconds, grey uint8 image), each image read when it is asked for."""
        for t, path in zip(self.timestamps[:max_frames], self.files[:max_frames], strict=True):
            yield float(t), load_grey(path)


def open_recording(path: str | Path, fps: float | None = None,
                   camera: CameraModel | None = None) -> Recording:
    """The folder's frame list if it has one, else its images in natural order at `fps`
    (default 30) from t = 0; `camera` overrides the camera.yaml found in the folder or beside
    it. A depth.txt in the folder gives depth maps, read as that camera.yaml's `depth` keys say
    (TUM's convention without them); they need a camera to be registered to."""
    path = Path(path)
    frame_list = next((path / n for n in FRAME_LISTS if (path / n).is_file()), None)
    if frame_list is not None:
        times, files = read_frame_list(frame_list)
    else:
        files = image_files(path)
        times = np.arange(len(files)) / (fps or DEFAULT_FPS)
    if not files:
        raise InputError("no images in folder", path)
    yaml = next((p for p in (path / "camera.yaml", path.parent / "camera.yaml") if p.is_file()),
                None)
    camera = camera or (load_camera(yaml) if yaml else None)
    depth = None
    if camera is not None:
        depth = depth_list(path, times, folder_depth_spec(yaml.parent if yaml else path), camera)
    return Recording(path.resolve().name, camera, times, files, depth)
