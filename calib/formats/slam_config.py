"""`Camera.*` keys of SLAM config files (OpenCV YAML): ORB-SLAM2/3 and the original C++ SDVL.

ORB-SLAM: Camera.fx fy cx cy, k1 k2 p1 p2 [k3] (Camera.type "PinHole") or k1..k4
("KannalaBrandt8"), Camera.width/height; ORB-SLAM3's `Camera1.` prefix is read too.
Original SDVL: Camera.width height fx fy u0 v0 d1..d5 (OpenCV radtan order), pinhole only.
These files are written as text: OpenCV's writer refuses keys with dots.
"""

from __future__ import annotations

from pathlib import Path

from calib.camera import CameraModel
from calib.formats.documents import full_coefficients, make_camera, number, write_text
from sdvl.errors import InputError

_HEADER = "%YAML:1.0\n---\n"


def _size(data: dict, path: str | Path) -> tuple[float, float]:
    if "Camera.width" not in data or "Camera.height" not in data:
        raise InputError("missing Camera.width / Camera.height (the image size in pixels); "
                         "add them to the file", path)
    return number(data, "Camera.width", path), number(data, "Camera.height", path)


def _lines(items: list[tuple[str, object]]) -> str:
    def value(v: object) -> str:
        if isinstance(v, str):
            return f'"{v}"'
        text = repr(v)
        mantissa, e, exponent = text.partition("e")
        return f"{mantissa}.0e{exponent}" if e and "." not in mantissa else text

    return _HEADER + "".join(f"{k}: {value(v)}\n" for k, v in items)


class OrbSlam:
    """ORB-SLAM2 / ORB-SLAM3 camera settings."""

    NAME = "orbslam"
    DESCRIPTION = "ORB-SLAM2/3 settings (Camera.fx, Camera.k1 ..., Camera.type)"

    @staticmethod
    def matches(data: dict) -> bool:
        """True for ORB-SLAM style keys."""
        return "Camera.fx" in data or "Camera1.fx" in data

    @staticmethod
    def from_mapping(data: dict, path: str | Path) -> CameraModel:
        """The (first) camera of an ORB-SLAM settings file."""
        p = "Camera1." if "Camera1.fx" in data else "Camera."
        kind = data.get("Camera.type", "PinHole")
        if kind not in ("PinHole", "KannalaBrandt8"):
            raise InputError(f"Camera.type '{kind}' is not supported (PinHole or "
                             "KannalaBrandt8)", path)
        K = tuple(number(data, p + k, path) for k in ("fx", "fy", "cx", "cy"))
        if kind == "KannalaBrandt8":
            names, model = ("k1", "k2", "k3", "k4"), "equidistant"
        else:
            names, model = ("k1", "k2", "p1", "p2", "k3"), "radtan_opencv"
        coeffs = [number(data, p + k, path, default=0.0) for k in names]
        return make_camera(path, _size(data, path), K, model, coeffs)

    @staticmethod
    def write(camera: CameraModel, path: str | Path) -> None:
        """ORB-SLAM3 'old format' keys, which ORB-SLAM2 reads as well."""
        fisheye = camera.distortion_model == "equidistant"
        names = ("k1", "k2", "k3", "k4") if fisheye else ("k1", "k2", "p1", "p2", "k3")
        items: list[tuple[str, object]] = [
            ("Camera.type", "KannalaBrandt8" if fisheye else "PinHole"),
            ("Camera.fx", camera.fx), ("Camera.fy", camera.fy),
            ("Camera.cx", camera.cx), ("Camera.cy", camera.cy)]
        items += [(f"Camera.{n}", c) for n, c in zip(names, full_coefficients(camera),
                                                     strict=True)]
        items += [("Camera.width", camera.width), ("Camera.height", camera.height)]
        write_text(path, _lines(items))


class SdvlConfig:
    """The original C++ SDVL's camera keys."""

    NAME = "sdvl-cfg"
    DESCRIPTION = "original C++ SDVL config (Camera.fx, Camera.u0, Camera.d1..d5)"
    _D = ("d1", "d2", "d3", "d4", "d5")

    @staticmethod
    def matches(data: dict) -> bool:
        """True for the original SDVL's keys."""
        return "Camera.u0" in data

    @staticmethod
    def from_mapping(data: dict, path: str | Path) -> CameraModel:
        """The camera of an original SDVL config."""
        K = tuple(number(data, "Camera." + k, path) for k in ("fx", "fy", "u0", "v0"))
        coeffs = [number(data, "Camera." + d, path, default=0.0) for d in SdvlConfig._D]
        return make_camera(path, _size(data, path), K, "radtan_opencv", coeffs)

    @staticmethod
    def write(camera: CameraModel, path: str | Path) -> None:
        """The Camera.* block of an original SDVL config; refuses fisheye cameras."""
        if camera.distortion_model == "equidistant":
            raise InputError("the original SDVL config has no fisheye model; use "
                             "another format", path)
        items: list[tuple[str, object]] = [
            ("Camera.width", camera.width), ("Camera.height", camera.height),
            ("Camera.fx", camera.fx), ("Camera.fy", camera.fy),
            ("Camera.u0", camera.cx), ("Camera.v0", camera.cy)]
        items += [(f"Camera.{d}", c) for d, c in zip(SdvlConfig._D, full_coefficients(camera),
                                                     strict=True)]
        write_text(path, _lines(items))
