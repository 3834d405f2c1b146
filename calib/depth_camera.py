"""What a depth camera adds to a colour camera: the unit of its 16-bit images, its valid range,
and where its pixels are relative to the colour camera's.

A depth map in this project is float32 metres along the optical axis (z), one value per colour
pixel, 0 (or NaN) where there is no measurement. `DepthSpec` turns a sensor's raw 16-bit image
into that: scale, range gate, and, when the sensor does not register depth to the colour camera
itself, `register_depth` (each depth pixel moved to the colour pixel it falls on, the nearest
surface kept).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np

from calib.camera import CameraModel, project_point, unproject_pixel
from sdvl.errors import InputError

# metres per unit of the TUM RGB-D depth PNGs (TUM "file formats": depth factor 5000)
TUM_DEPTH_SCALE = 1.0 / 5000.0


@dataclass(frozen=True)
class DepthSpec:
    """How to read one depth camera.

    `scale`: metres per unit of the raw image (TUM 1/5000, RealSense 0.001); `min_m`/`max_m`:
    measurements outside this range are dropped (max 0 = no upper limit); `registered`: the
    depth image is already in the colour camera's pixels (TUM, RealSense with align-to-colour);
    otherwise `camera` is the depth camera's intrinsics and `T_c_d` the 4x4 colour-from-depth
    transform.
    """

    scale: float = 0.001
    min_m: float = 0.0
    max_m: float = 0.0
    registered: bool = True
    camera: CameraModel | None = None
    T_c_d: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise InputError(f"depth.scale must be a positive number of metres per unit, got "
                             f"{self.scale}")
        if self.min_m < 0 or self.max_m < 0 or (self.max_m and self.max_m <= self.min_m):
            raise InputError(f"depth range must satisfy 0 <= min_m < max_m (max_m 0 = no limit), "
                             f"got {self.min_m}..{self.max_m}")
        if not self.registered and (self.camera is None or self.T_c_d is None):
            raise InputError("depth.registered is false: give the depth camera's intrinsics "
                             "(depth.camera) and depth.T_color_depth (4x4 colour-from-depth)")
        if self.T_c_d is not None:
            T = np.asarray(self.T_c_d, dtype=np.float64)
            R = T[:3, :3] if T.shape == (4, 4) else None
            if R is None or not np.allclose(R @ R.T, np.eye(3), atol=1e-4) \
                    or np.linalg.det(R) < 0 or not np.allclose(T[3], (0, 0, 0, 1)):
                raise InputError("depth.T_color_depth must be a 4x4 rigid transform (rotation "
                                 "block orthonormal, last row 0 0 0 1)")
            object.__setattr__(self, "T_c_d", T)

    def to_metres(self, raw: np.ndarray, colour: CameraModel) -> np.ndarray:
        """The depth map (float32 metres, 0 = none) in `colour`'s pixels from a raw image."""
        depth = raw.astype(np.float32) * np.float32(self.scale)
        if not self.registered:
            if raw.shape != (self.camera.height, self.camera.width):
                raise InputError(f"depth image is {raw.shape[1]}x{raw.shape[0]}, depth.camera "
                                 f"says {self.camera.width}x{self.camera.height}")
            depth = register_depth(depth, self.camera, colour, self.T_c_d)
        elif raw.shape != (colour.height, colour.width):
            raise InputError(f"depth image is {raw.shape[1]}x{raw.shape[0]} but the camera is "
                             f"{colour.width}x{colour.height}: a registered depth image has the "
                             "colour image's size (else set depth.registered: false)")
        return gate_range(depth, self.min_m, self.max_m)

    def to_raw(self, depth: np.ndarray) -> np.ndarray:
        """A registered depth map (float metres, 0 or NaN = none) as the 16-bit image in this
        unit that `to_metres` reads back; depths beyond 65535 units saturate there."""
        return np.clip(np.rint(np.nan_to_num(depth) / self.scale), 0, 65535).astype(np.uint16)


def gate_range(depth: np.ndarray, min_m: float, max_m: float) -> np.ndarray:
    """`depth` with values outside [min_m, max_m] (max_m 0: no limit) and NaN set to 0."""
    bad = ~(depth >= min_m) | (depth <= 0)
    if max_m > 0:
        bad |= depth > max_m
    depth[bad] = 0.0
    return depth


def register_depth(depth: np.ndarray, depth_camera: CameraModel, colour: CameraModel,
                   T_c_d: np.ndarray) -> np.ndarray:
    """A depth map seen by `depth_camera` moved into `colour`'s pixels: each measured pixel is
    lifted to 3D, moved by T_c_d and projected; where several land on one colour pixel the
    nearest wins (z-buffer). Colour pixels nothing lands on get 0."""
    T = np.ascontiguousarray(T_c_d, dtype=np.float64)
    return _register(np.ascontiguousarray(depth, dtype=np.float32), depth_camera.params,
                     colour.params, T, colour.width, colour.height)


@numba.njit(cache=True, nogil=True)
def _register(depth, params_d, params_c, T, width, height):
    out = np.zeros((height, width), np.float32)
    for r in range(depth.shape[0]):
        for c in range(depth.shape[1]):
            z = depth[r, c]
            if not z > 0.0:
                continue
            bx, by, bz = unproject_pixel(params_d, float(c), float(r))
            if bz <= 0.0:
                continue
            s = z / bz
            X, Y, Z = bx * s, by * s, bz * s
            x = T[0, 0] * X + T[0, 1] * Y + T[0, 2] * Z + T[0, 3]
            y = T[1, 0] * X + T[1, 1] * Y + T[1, 2] * Z + T[1, 3]
            zc = T[2, 0] * X + T[2, 1] * Y + T[2, 2] * Z + T[2, 3]
            if zc <= 0.0:
                continue
            u, v = project_point(params_c, x, y, zc)
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            cu, cv = int(np.floor(u + 0.5)), int(np.floor(v + 0.5))
            if 0 <= cu < width and 0 <= cv < height:
                old = out[cv, cu]
                if old == 0.0 or zc < old:
                    out[cv, cu] = zc
    return out


def decimate(depth: np.ndarray, camera: CameraModel, factor: int,
             edge_rel: float = 0.05) -> tuple[np.ndarray, CameraModel]:
    """The depth map averaged over factor x factor blocks (as a depth camera's decimation
    filter), with the camera of the smaller image: a block's mean where at least half of it
    is measured and its measurements span at most `edge_rel` of their mean (else 0: a block
    across a depth edge would average two surfaces into a point on neither)."""
    if factor == 1:
        return depth, camera
    small = camera.scaled(1.0 / factor)
    out = _decimate(np.ascontiguousarray(depth, dtype=np.float32), factor, edge_rel)
    return out, small


@numba.njit(cache=True, nogil=True)
def _decimate(depth, k, edge_rel):
    h, w = depth.shape[0] // k, depth.shape[1] // k
    out = np.zeros((h, w), np.float32)
    for r in range(h):
        for c in range(w):
            n, total, lo, hi = 0, 0.0, np.inf, -np.inf
            for i in range(r * k, r * k + k):
                for j in range(c * k, c * k + k):
                    z = depth[i, j]
                    if 0.0 < z < np.inf:  # not a hole (0, NaN)
                        n += 1
                        total += z
                        lo, hi = min(lo, z), max(hi, z)
            if 2 * n >= k * k and hi - lo <= edge_rel * total / n:
                out[r, c] = total / n
    return out


def points_from_depth(depth: np.ndarray, camera: CameraModel,
                      rays: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame 3D points (N, 3) of the measured pixels of a depth map, and their pixel
    indices (N, 2) as (column, row). `rays` (H, W, 3) are the camera's bearings scaled to
    z = 1, if already computed (`unit_depth_rays`)."""
    if rays is None:
        rays = unit_depth_rays(camera)
    rr, cc = np.nonzero(depth > 0)
    z = depth[rr, cc].astype(np.float64)
    return rays[rr, cc] * z[:, None], np.column_stack([cc, rr])


def unit_depth_rays(camera: CameraModel) -> np.ndarray:
    """(H, W, 3) bearings of every pixel centre scaled to z = 1: a pixel's 3D point is its ray
    times its depth (depth is along the optical axis)."""
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64),
                       np.arange(camera.height, dtype=np.float64))
    rays = camera.unproject(np.column_stack([u.ravel(), v.ravel()]))
    rays = rays / rays[:, 2:3]
    return rays.reshape(camera.height, camera.width, 3)
