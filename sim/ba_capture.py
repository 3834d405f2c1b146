"""The local BA problems the mapping thread builds while a sequence is tracked, captured with
what is needed to score a solution against ground truth (`sdvl ba-bench`)."""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sdvl.errors import InputError
from sim.metrics import interpolate, umeyama
from vo import bundle_adjustment
from vo.bundle_adjustment import Problem
from vo.se3 import inv_se3

MIN_ALIGN = 3  # keyframes to align the map to the truth with


@dataclass
class Captured:
    """One local BA problem as the tracker built it, and the map's keyframes around it."""

    label: str  # sequence, world and tracker seed it came from
    problem: Problem
    gated: bool  # its rms was below ba_min_rms_px: the tracker did not solve it
    window_T: np.ndarray  # (A, 4, 4) T_c_w of every keyframe of the map at capture
    window_gt: np.ndarray  # (A, 3) their true camera centres (NaN: no ground truth)
    slot_index: np.ndarray  # (K,) the problem's keyframes (free first) as indices into window


def capture(sequence, config, label: str) -> list[Captured]:
    """Track `sequence` sequentially with `config` (local BA on) and return every local BA
    problem built, with the true centres of the map's keyframes when the sequence has
    ground truth."""
    from sim.track_command import track_sequence

    if not config.local_ba:
        raise InputError("capturing BA problems needs local_ba = true")
    raw: list[tuple[Problem, np.ndarray, np.ndarray, np.ndarray]] = []

    def observe(problem: Problem, map_) -> None:
        slots = np.array(sorted(map_.keyframes), dtype=np.int64)
        times = np.array([map_.keyframes[int(s)].t for s in slots])
        raw.append((problem, map_.kf_T_c_w[slots].copy(), times,
                     np.searchsorted(slots, problem.slots)))

    bundle_adjustment.PROBLEM_OBSERVERS.append(observe)
    try:
        track_sequence(sequence, config, False, None, quiet=True)
    finally:
        bundle_adjustment.PROBLEM_OBSERVERS.remove(observe)
    return [Captured(label, p, p.rms_px() < config.ba_min_rms_px, T, _true_centres(
        sequence.groundtruth, t), index) for p, T, t, index in raw]


def _true_centres(groundtruth, times: np.ndarray) -> np.ndarray:
    """(n, 3) true camera centres at `times`, NaN where the ground truth does not cover."""
    out = np.full((len(times), 3), np.nan)
    if groundtruth is not None:
        gt, covered = interpolate(groundtruth, times)
        out[covered] = gt.positions
    return out


def free_keyframe_errors(c: Captured, T: np.ndarray) -> np.ndarray | None:
    """Distances (ground-truth units) of the free keyframes' centres from the truth when the
    problem's keyframes are at T (its slots' T_c_w), after the Sim(3) that maps the centres of
    its fixed keyframes onto the truth (or of all the map's other keyframes when fewer than 3
    are fixed): they do not move, so the alignment favours neither the start nor a solution,
    and being the free ones' neighbours, it measures the local error, not the drift; None
    without enough ground truth."""
    p = c.problem
    centres = np.array([inv_se3(t)[:3, 3] for t in c.window_T])
    known = np.isfinite(c.window_gt).all(axis=1)
    free = c.slot_index[:p.n_free]
    ref = c.slot_index[p.n_free:]
    ref = ref[known[ref]]
    if len(ref) < MIN_ALIGN:
        ref = np.setdiff1d(np.flatnonzero(known), free)
    if len(ref) < MIN_ALIGN or not known[free].all():
        return None
    R, t, s = umeyama(centres[ref], c.window_gt[ref], with_scale=True)
    moved = np.array([inv_se3(T[k])[:3, 3] for k in range(p.n_free)])
    return np.linalg.norm(s * moved @ R.T + t - c.window_gt[free], axis=1)


def save(captures: list[Captured], path: Path) -> None:
    """Pickle captures to a file (a folder outside the repository: they are large)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as f:
        pickle.dump(captures, f)


def load(path: Path) -> list[Captured]:
    """Captures pickled by `save` (a file, or every *.pkl of a folder, in name order)."""
    files = sorted(path.glob("*.pkl")) if path.is_dir() else [path]
    if not files or not all(f.is_file() for f in files):
        raise InputError(f"no captured BA problems at {path} (write some with --save)")
    out: list[Captured] = []
    for file in files:
        with file.open("rb") as f:
            out += pickle.load(f)
    return out
