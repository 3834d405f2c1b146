"""Camera models: pinhole with OpenCV radial-tangential distortion, and equidistant fisheye.

`CameraModel` is the Python-side object; its `params` array is what numba kernels take, with the
njit functions `project_point` and `unproject_pixel` callable from inside other kernels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numba
import numpy as np

from sdvl.errors import InputError

KIND_NONE = 0
KIND_RADTAN = 1
KIND_EQUIDISTANT = 2

MODEL_KINDS = {"none": KIND_NONE, "radtan_opencv": KIND_RADTAN, "equidistant": KIND_EQUIDISTANT}
MODEL_ALIASES = {
    "none": "none",
    "pinhole": "none",
    "radtan_opencv": "radtan_opencv",
    "radtan": "radtan_opencv",
    "radial-tangential": "radtan_opencv",
    "plumb_bob": "radtan_opencv",
    "pinhole-radtan": "radtan_opencv",
    "equidistant": "equidistant",
    "equi": "equidistant",
    "fisheye": "equidistant",
    "kannala_brandt": "equidistant",
}
N_COEFFS = {"none": (0, 5), "radtan_opencv": (4, 5), "equidistant": (4, 4)}

# params layout: [kind, fx, fy, cx, cy, d0, d1, d2, d3, d4, r2_max]
_NEWTON_ITERATIONS = 30
_NEWTON_TOL = 1e-14


@numba.njit(cache=True, nogil=True)
def _radtan(d, x, y):
    """Distorted normalised point and its 2x2 Jacobian for OpenCV's k1 k2 p1 p2 k3."""
    k1, k2, p1, p2, k3 = d[0], d[1], d[2], d[3], d[4]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    d_radial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    j00 = radial + 2.0 * x * x * d_radial + 2.0 * p1 * y + 6.0 * p2 * x
    j01 = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    j10 = 2.0 * x * y * d_radial + 2.0 * p1 * x + 2.0 * p2 * y
    j11 = radial + 2.0 * y * y * d_radial + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, j00, j01, j10, j11


@numba.njit(cache=True, nogil=True)
def _equidistant_theta_d(d, theta):
    """Distorted angle and its derivative for the Kannala-Brandt (OpenCV fisheye) polynomial."""
    t2 = theta * theta
    poly = 1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3])))
    d_poly = 1.0 + t2 * (3.0 * d[0] + t2 * (5.0 * d[1] + t2 * (7.0 * d[2] + t2 * 9.0 * d[3])))
    return theta * poly, d_poly


@numba.njit(cache=True, nogil=True)
def project_point(params, X, Y, Z):
    """Pixel (u, v) of a camera-frame point; NaN when the point cannot be seen by the model."""
    kind = int(params[0])
    d = params[5:10]
    if kind == KIND_EQUIDISTANT:
        r = np.sqrt(X * X + Y * Y)
        theta = np.arctan2(r, Z)
        theta_d, _ = _equidistant_theta_d(d, theta)
        if r > 1e-12:
            xd = theta_d * X / r
            yd = theta_d * Y / r
        elif Z > 0.0:
            xd = X / Z
            yd = Y / Z
        else:
            return np.nan, np.nan
    else:
        if Z <= 0.0:
            return np.nan, np.nan
        xd = X / Z
        yd = Y / Z
        if kind == KIND_RADTAN:
            if xd * xd + yd * yd > params[10]:
                return np.nan, np.nan
            xd, yd, _, _, _, _ = _radtan(d, xd, yd)
    return params[1] * xd + params[3], params[2] * yd + params[4]


@numba.njit(cache=True, nogil=True)
def unproject_pixel(params, u, v):
    """Unit bearing (x, y, z) in the camera frame of the ray seen at pixel (u, v)."""
    kind = int(params[0])
    d = params[5:10]
    xd = (u - params[3]) / params[1]
    yd = (v - params[4]) / params[2]
    if kind == KIND_EQUIDISTANT:
        theta_d = np.sqrt(xd * xd + yd * yd)
        if theta_d < 1e-15:
            return 0.0, 0.0, 1.0
        theta = theta_d
        for _ in range(_NEWTON_ITERATIONS):
            f, df = _equidistant_theta_d(d, theta)
            step = (f - theta_d) / df
            theta -= step
            if abs(step) < _NEWTON_TOL:
                break
        s = np.sin(theta) / theta_d
        return xd * s, yd * s, np.cos(theta)
    x, y = xd, yd
    if kind == KIND_RADTAN:
        for _ in range(_NEWTON_ITERATIONS):
            fx, fy, j00, j01, j10, j11 = _radtan(d, x, y)
            ex = fx - xd
            ey = fy - yd
            det = j00 * j11 - j01 * j10
            dx = (j11 * ex - j01 * ey) / det
            dy = (-j10 * ex + j00 * ey) / det
            x -= dx
            y -= dy
            if abs(dx) + abs(dy) < _NEWTON_TOL:
                break
    n = np.sqrt(x * x + y * y + 1.0)
    return x / n, y / n, 1.0 / n


@numba.njit(cache=True, nogil=True)
def project_points(params, points):
    """Pixels (N, 2) of camera-frame points (N, 3); rows of NaN where not visible."""
    out = np.empty((points.shape[0], 2))
    for i in range(points.shape[0]):
        out[i, 0], out[i, 1] = project_point(params, points[i, 0], points[i, 1], points[i, 2])
    return out


@numba.njit(cache=True, nogil=True)
def unproject_pixels(params, pixels):
    """Unit bearings (N, 3) of pixels (N, 2)."""
    out = np.empty((pixels.shape[0], 3))
    for i in range(pixels.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = unproject_pixel(params, pixels[i, 0], pixels[i, 1])
    return out


def canonical_model_name(name: str) -> str:
    """The canonical distortion model name for a name or alias; InputError if unknown."""
    key = str(name).strip().lower()
    if key not in MODEL_ALIASES:
        known = ", ".join(sorted(MODEL_KINDS))
        raise InputError(f"unknown distortion_model '{name}' (expected one of: {known})")
    return MODEL_ALIASES[key]


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and distortion of one camera; pixel <-> unit bearing for arrays of points."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = "none"
    distortion: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        model = canonical_model_name(self.distortion_model)
        object.__setattr__(self, "distortion_model", model)
        coeffs = tuple(float(c) for c in self.distortion)
        lo, hi = N_COEFFS[model]
        if not lo <= len(coeffs) <= hi:
            raise InputError(
                f"distortion_model '{model}' takes {lo}..{hi} coefficients, got {len(coeffs)}"
            )
        if model == "none" and any(c != 0.0 for c in coeffs):
            raise InputError("distortion_model 'none' with non-zero distortion coefficients")
        object.__setattr__(self, "distortion", coeffs)
        if self.width <= 0 or self.height <= 0 or self.fx <= 0 or self.fy <= 0:
            raise InputError("width, height, fx and fy must be positive")
        for name in ("fx", "fy", "cx", "cy"):
            if not np.isfinite(getattr(self, name)):
                raise InputError(f"{name} is not a finite number")

    @cached_property
    def params(self) -> np.ndarray:
        """The float64 array numba kernels take: [kind, fx, fy, cx, cy, d0..d4, r2_max]."""
        p = np.zeros(11)
        p[0] = MODEL_KINDS[self.distortion_model]
        p[1:5] = (self.fx, self.fy, self.cx, self.cy)
        p[5 : 5 + len(self.distortion)] = self.distortion
        p[10] = self.max_radius2()
        return p

    def max_radius2(self) -> float:
        """Squared normalised radius up to which radial distortion still grows with the radius;
        beyond it the polynomial folds back and points outside the lens's view would land in
        the image, so `project` returns NaN there."""
        if self.distortion_model != "radtan_opencv":
            return np.inf
        k1, k2, _, _, k3 = self.dist_coeffs
        # d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)] = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3, s = r^2
        roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0])
        real = roots[(np.abs(roots.imag) < 1e-12) & (roots.real > 0)].real
        return float(real.min()) if real.size else np.inf

    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> np.ndarray:
        """Distortion coefficients in the order OpenCV's functions take for this model."""
        n = 4 if self.distortion_model == "equidistant" else 5
        out = np.zeros(n)
        out[: len(self.distortion)] = self.distortion
        return out

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def project(self, points: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of camera-frame points (N, 3); NaN rows for points the model cannot see."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        return project_points(self.params, pts)

    def unproject(self, pixels: np.ndarray) -> np.ndarray:
        """Unit bearings (N, 3) in the camera frame for pixels (N, 2)."""
        px = np.ascontiguousarray(np.asarray(pixels, dtype=np.float64).reshape(-1, 2))
        return unproject_pixels(self.params, px)

    def in_image(self, pixels: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels at least `margin` inside the image."""
        px = np.asarray(pixels, dtype=np.float64).reshape(-1, 2)
        with np.errstate(invalid="ignore"):
            return (
                (px[:, 0] >= margin)
                & (px[:, 1] >= margin)
                & (px[:, 0] <= self.width - 1 - margin)
                & (px[:, 1] <= self.height - 1 - margin)
            )

    def scaled(self, factor: float) -> CameraModel:
        """The same camera for an image resized by `factor` (pyramid levels, --size)."""
        return CameraModel(
            width=max(1, round(self.width * factor)),
            height=max(1, round(self.height * factor)),
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            distortion_model=self.distortion_model,
            distortion=self.distortion,
        )
