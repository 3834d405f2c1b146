"""The map: points as numpy columns, keyframe pyramids in fixed slots, observations table.

Points are stored in inverse depth relative to their host keyframe (thesis 6.3): bearing `f` at
host pixel (`u`, `v`, `level`), inverse depth `rho` +- `sigma`, Beta(`a`, `b`) inlier model.
`pos_w` caches the world position (eq. 6.4). Deleted point slots are recycled two mapping steps
later, and only once every frame that existed when they were deleted has been mapped, so a
frame's feature list never refers to a recycled point (a threaded mapper may be several frames
behind tracking).
"""

from __future__ import annotations

import threading

import numba
import numpy as np

from vo.frame import Frame, Pyramid
from vo.orb import DESC_BYTES, UNKNOWN, describe_levels

FREE, CANDIDATE, CONVERGED, DELETED = 0, 1, 2, 3
RELEASE_DELAY = 2


class PointStore:
    """Structure-of-arrays store of map points with slot recycling."""

    FLOAT_COLS = ("u", "v", "rho", "sigma", "a", "b", "rho_range")
    INT_COLS = ("host", "level", "n_found", "n_failed", "n_missed", "n_updates", "n_rejected",
                "n_unmatched")

    def __init__(self, capacity: int = 1024, levels: int = 5):
        self.capacity = 0
        self.status = np.zeros(0, dtype=np.int8)
        for name in self.FLOAT_COLS:
            setattr(self, name, np.zeros(0))
        for name in self.INT_COLS:
            setattr(self, name, np.zeros(0, dtype=np.int64))
        self.f = np.zeros((0, 3))
        self.pos_w = np.zeros((0, 3))
        # ORB descriptors at the host pixel, per pyramid level (vo.orb), computed when needed
        self.desc = np.zeros((0, levels, DESC_BYTES), dtype=np.uint8)
        self.desc_state = np.zeros((0, levels), dtype=np.int8)
        self._free: list[int] = []
        # (mapping step, newest frame id, point ids) of each deletion waiting for release
        self._pending: list[tuple[int, int, np.ndarray]] = []
        self._step = 0
        # id of the newest frame tracking has started on (set by the tracker)
        self.newest_frame = -1
        self._grow(capacity)

    def _grow(self, capacity: int) -> None:
        old = self.capacity
        for name in ("status", *self.FLOAT_COLS, *self.INT_COLS, "f", "pos_w", "desc",
                     "desc_state"):
            col = getattr(self, name)
            new = np.zeros((capacity, *col.shape[1:]), dtype=col.dtype)
            new[:old] = col
            setattr(self, name, new)
        self._free.extend(range(capacity - 1, old - 1, -1))
        self.capacity = capacity

    def alloc(self, n: int) -> np.ndarray:
        """Indices of n free point slots (growing the store when needed)."""
        while len(self._free) < n:
            self._grow(max(2 * self.capacity, self.capacity + n))
        idx = np.array([self._free.pop() for _ in range(n)], dtype=np.int64)
        return idx

    def add(self, host: int, u: np.ndarray, v: np.ndarray, level: np.ndarray, f: np.ndarray,
            rho: np.ndarray, sigma: np.ndarray, rho_range: np.ndarray, a0: float, b0: float,
            T_w_host: np.ndarray) -> np.ndarray:
        """New candidate points hosted by keyframe slot `host`; returns their indices."""
        idx = self.alloc(len(u))
        self.status[idx] = CANDIDATE
        self.host[idx] = host
        self.u[idx], self.v[idx], self.level[idx] = u, v, level
        self.f[idx] = f
        self.rho[idx], self.sigma[idx], self.rho_range[idx] = rho, sigma, rho_range
        self.a[idx], self.b[idx] = a0, b0
        self.n_found[idx] = 0
        self.n_failed[idx] = 0
        self.n_missed[idx] = 0
        self.n_updates[idx] = 0
        self.n_rejected[idx] = 0
        self.n_unmatched[idx] = 0
        self.desc_state[idx] = UNKNOWN
        self.update_positions(idx, T_w_host)
        return idx

    def update_positions(self, idx: np.ndarray, T_w_host: np.ndarray) -> None:
        """Recompute world positions of points idx (all hosted by the keyframe at T_w_host)."""
        local = self.f[idx] / self.rho[idx, None]
        self.pos_w[idx] = local @ T_w_host[:3, :3].T + T_w_host[:3, 3]

    def delete(self, idx: np.ndarray) -> None:
        """Mark points deleted; their slots are recycled after RELEASE_DELAY mapping steps,
        once a frame newer than every frame that may have matched them is mapped."""
        idx = np.asarray(idx, dtype=np.int64)
        idx = idx[self.status[idx] != DELETED]
        if len(idx):
            self.status[idx] = DELETED
            self._pending.append((self._step, self.newest_frame, idx))

    def step(self, frame_id: int) -> bool:
        """Advance the recycling clock by one mapping step, that of frame `frame_id` (frames
        are mapped in order); True when slots were freed."""
        self._step += 1
        keep = []
        for when, newest, idx in self._pending:
            if self._step - when >= RELEASE_DELAY and frame_id > newest:
                self.status[idx] = FREE
                self._free.extend(int(i) for i in idx)
            else:
                keep.append((when, newest, idx))
        freed = len(keep) < len(self._pending)
        self._pending = keep
        return freed

    def alive(self) -> np.ndarray:
        """Indices of candidate and converged points."""
        return np.flatnonzero((self.status == CANDIDATE) | (self.status == CONVERGED))


class Observations:
    """Which keyframe saw which point where: columns point, kf, u, v (level 0), level."""

    def __init__(self):
        self.point = np.zeros(0, dtype=np.int64)
        self.kf = np.zeros(0, dtype=np.int64)
        self.uv = np.zeros((0, 2))
        self.level = np.zeros(0, dtype=np.int64)
        self._csr: tuple[np.ndarray, np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self.point)

    def add(self, slot: int, point: np.ndarray, uv: np.ndarray, level: np.ndarray) -> None:
        """Append observations of `point` by keyframe `slot`."""
        self.point = np.concatenate((self.point, point))
        self.kf = np.concatenate((self.kf, np.full(len(point), slot, np.int64)))
        self.uv = np.concatenate((self.uv, uv))
        self.level = np.concatenate((self.level, level))
        self._csr = None

    def keep(self, mask: np.ndarray) -> None:
        """Drop the observations where mask is False."""
        self.point, self.kf = self.point[mask], self.kf[mask]
        self.uv, self.level = self.uv[mask], self.level[mask]
        self._csr = None

    def by_point(self, n_points: int) -> tuple[np.ndarray, np.ndarray]:
        """(start offsets per point (n_points + 1), observation order) grouping rows by point."""
        if self._csr is None or len(self._csr[0]) != n_points + 1:
            order = np.argsort(self.point, kind="stable")
            start = np.searchsorted(self.point[order], np.arange(n_points + 1))
            self._csr = (start.astype(np.int64), order.astype(np.int64))
        return self._csr


class Map:
    """Keyframes (Python objects, pyramids in slots), points and observations of one map."""

    def __init__(self, width: int, height: int, levels: int, max_keyframes: int):
        self.lock = threading.RLock()
        n_slots = max_keyframes + 2
        self.pyr_size = Pyramid.flat_size(width, height, levels)
        self.kf_pyr = np.zeros((n_slots, self.pyr_size), dtype=np.uint8)
        self.kf_T_c_w = np.tile(np.eye(4), (n_slots, 1, 1))
        self.keyframes: dict[int, Frame] = {}
        self.points = PointStore(levels=levels)
        self.obs = Observations()

    def __len__(self) -> int:
        return len(self.keyframes)

    def add_keyframe(self, frame: Frame, observations: bool = True) -> int:
        """Store a keyframe in a free slot; its matched points become observations (unless
        the caller adds them: vo.map_merge)."""
        slot = next(s for s in range(len(self.kf_pyr)) if s not in self.keyframes)
        frame.is_keyframe = True
        frame.slot = slot
        self.kf_pyr[slot, : len(frame.pyr.flat)] = frame.pyr.flat
        self.kf_T_c_w[slot] = frame.T_c_w
        self.keyframes[slot] = frame
        if observations:
            self.obs.add(slot, frame.feat_point, frame.feat_px, frame.feat_level)
        return slot

    def remove_keyframe(self, slot: int) -> None:
        """Drop a keyframe, the points it hosts and its observations."""
        self.points.delete(np.flatnonzero((self.points.host == slot)
                                          & (self.points.status != FREE)))
        self.obs.keep(self.obs.kf != slot)
        del self.keyframes[slot]

    def prune_observations(self) -> None:
        """Forget observations of deleted points (keeps the table bounded)."""
        status = self.points.status[self.obs.point]
        self.obs.keep((status != DELETED) & (status != FREE))

    def observed_by(self, slot: int) -> tuple[np.ndarray, np.ndarray]:
        """(point ids, level-0 pixels) of the live points keyframe `slot` observes now: its
        observations (its own feature list may name slots recycled since it was taken), then
        the live points it hosts, where it detected them: those never get a row for their
        host, and a map of rotations converges few points (tum_fr1_rpy: none in 50 frames),
        so most keyframes observe only candidates."""
        with self.lock:
            rows = self.obs.kf == slot
            ids, uv = self.obs.point[rows], self.obs.uv[rows]
            pts = self.points
            hosted = np.flatnonzero((pts.host == slot) & ((pts.status == CANDIDATE)
                                                          | (pts.status == CONVERGED)))
            hosted = hosted[~np.isin(hosted, ids)]
            return (np.concatenate((ids, hosted)),
                    np.concatenate((uv, np.column_stack((pts.u[hosted], pts.v[hosted])))))

    def covisible(self, point_ids: np.ndarray, exclude: int, min_shared: int) -> list[int]:
        """Keyframe slots sharing at least `min_shared` of `point_ids`, most shared first."""
        counts = _shared_counts(self.obs.point, self.obs.kf, np.asarray(point_ids, np.int64),
                                self.points.capacity, len(self.kf_pyr))
        counts[exclude] = 0
        order = np.argsort(-counts, kind="stable")
        return [int(s) for s in order if counts[s] >= min_shared and s in self.keyframes]

    def farthest_keyframe(self, position: np.ndarray, keep: set[int]) -> int | None:
        """Slot of the keyframe farthest from `position`, not in `keep`."""
        best, best_d = None, -1.0
        for slot, kf in self.keyframes.items():
            d = float(np.linalg.norm(kf.position - position))
            if slot not in keep and d > best_d:
                best, best_d = slot, d
        return best

    def describe_points(self, ids: np.ndarray, need: np.ndarray) -> None:
        """Compute the ORB descriptors of points `ids` at the levels where need (N, levels)
        and none is cached, from each point's host keyframe."""
        pts = self.points
        hosts = pts.host[ids]
        for slot in np.unique(hosts):
            rows = ids[hosts == slot]
            desc, state = pts.desc[rows], pts.desc_state[rows]
            describe_levels(self.keyframes[int(slot)].pyr.images, pts.u[rows], pts.v[rows],
                            need[hosts == slot], desc, state)
            pts.desc[rows], pts.desc_state[rows] = desc, state

    def n_points(self) -> int:
        """Number of live (candidate or converged) points."""
        return len(self.points.alive())


@numba.njit(cache=True, nogil=True)
def _shared_counts(obs_point, obs_kf, point_ids, n_points, n_slots):
    """Per keyframe slot, how many of point_ids it observes."""
    mark = np.zeros(n_points, dtype=np.bool_)
    for p in point_ids:
        mark[p] = True
    counts = np.zeros(n_slots, dtype=np.int64)
    for k in range(obs_point.shape[0]):
        if mark[obs_point[k]]:
            counts[obs_kf[k]] += 1
    return counts
