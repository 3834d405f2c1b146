"""The calibration report: is the result good, per-view errors, skipped images, coverage advice."""

from __future__ import annotations

from dataclasses import dataclass, field

from calib.board import BoardSpec
from calib.coverage import Coverage
from calib.view_selection import RobustCalibration

GOOD_RMS_PX = 0.5
USABLE_RMS_PX = 1.0
GOOD_COVERAGE = 0.6


@dataclass
class CalibrationReport:
    """Everything the user needs to judge a calibration, as text or as a JSON-ready dict."""

    board: BoardSpec
    model: str
    calibration: RobustCalibration
    coverage: Coverage
    skipped: list[tuple[str, str]] = field(default_factory=list)

    @property
    def verdict(self) -> str:
        """'good', 'usable' or 'poor', from the RMS error and the image coverage."""
        rms = self.calibration.result.rms
        if rms < GOOD_RMS_PX and self.coverage.fraction >= GOOD_COVERAGE:
            return "good"
        return "usable" if rms < USABLE_RMS_PX else "poor"

    def advice(self) -> list[str]:
        """What to do to improve the calibration, one sentence each."""
        out = []
        areas = self.coverage.empty_areas()
        if areas:
            out.append(f"add views with the board in the {', '.join(areas)} of the image")
        if self.calibration.result.rms >= GOOD_RMS_PX:
            out.append("RMS error is high: use a flat, rigid board, sharp images, steady poses")
        return out

    def to_dict(self) -> dict:
        """JSON-ready summary (camera, errors, views, skipped images, coverage, verdict)."""
        res = self.calibration.result
        cam = res.camera
        return {
            "verdict": self.verdict,
            "board": self.board.describe(),
            "model": self.model,
            "camera": {"width": cam.width, "height": cam.height, "fx": cam.fx, "fy": cam.fy,
                       "cx": cam.cx, "cy": cam.cy, "distortion_model": cam.distortion_model,
                       "distortion": list(cam.distortion)},
            "std_intrinsics": res.std_intrinsics,
            "rms_px": res.rms,
            "views": [{"name": v.name, "rms_px": float(e)}
                      for v, e in zip(self.calibration.views, res.per_view_rms, strict=True)],
            "rejected_outliers": [{"name": n, "rms_px": e} for n, e in self.calibration.rejected],
            "skipped": [{"name": n, "reason": r} for n, r in self.skipped],
            "coverage": self.coverage.fraction,
            "areas_needing_views": self.coverage.empty_areas(),
            "advice": self.advice(),
        }

    def to_text(self) -> str:
        """The report as lines for the terminal."""
        res = self.calibration.result
        cam = res.camera
        std = res.std_intrinsics or {}

        def pm(name: str) -> str:
            value = getattr(cam, name)
            return f"{name} {value:.2f}" + (f" +- {std[name]:.2f}" if name in std else "")

        lines = [f"calibration: {self.verdict} (RMS {res.rms:.3f} px over "
                 f"{len(self.calibration.views)} views; {self.board.describe()})",
                 f"  {self.model} {cam.width}x{cam.height}: "
                 + ", ".join(pm(n) for n in ("fx", "fy", "cx", "cy")),
                 f"  {cam.distortion_model} distortion: "
                 + " ".join(f"{d:.6g}" for d in cam.distortion),
                 "  per-view RMS (px):"]
        lines += [f"    {v.name}: {e:.3f}"
                  for v, e in zip(self.calibration.views, res.per_view_rms, strict=True)]
        lines += [f"  rejected {n}: outlier reprojection error {e:.3f} px"
                  for n, e in self.calibration.rejected]
        if self.skipped:
            lines.append(f"  {len(self.skipped)} image(s) skipped (each named with its reason)")
        lines.append(f"  coverage: corners seen in {self.coverage.fraction:.0%} of the image")
        lines += [f"  advice: {a}" for a in self.advice()]
        return "\n".join(lines)
