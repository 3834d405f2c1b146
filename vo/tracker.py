"""The SDVL tracker (thesis 6.1): frames in, world-from-camera poses out.

A state machine over the stages, in the shape of rpg_svo's frame handler (uzh-rpg/rpg_svo
svo/src/frame_handler_mono.cpp): while INITIALIZING, frames go to the initialiser until it
builds a map (vo.map_start); while TRACKING, each frame is tracked from the last one
(vo.frame_tracking); once tracking is lost the tracker is RELOCALIZING against the map
(vo.relocalization; a pose found is believed once the next frame confirms it:
vo.relocalizing) while a new map is initialised on the side, which replaces the old one if
relocalisation keeps failing. With depth maps (issue 30; `depth` in the config) a map starts
on one frame from its measured depths instead (vo.map_start.build_depth_map), metric, and so
does a new map while lost; nothing else in tracking changes. Each frame tracked against the
map then goes to mapping (6.6), run after the frame (sequential, reproducible), in its own
thread (vo.mapping_thread) or stepped by the caller (vo.stepped_mapping, a test hook); a
frame tracked while frames wait for mapping is not rated good.
"""

from __future__ import annotations

import time
from enum import Enum

import numpy as np

from calib.camera import CameraModel
from vo import bundle_adjustment
from vo.config import TrackerConfig
from vo.depth_seeds import DepthSeeds, check_depth_map
from vo.frame import Frame, check_image
from vo.frame_tracking import FrameTracking
from vo.initialization import Initializer, InitialMap, InitOutcome
from vo.keyframe_policy import KeyframePolicy
from vo.late_poses import late_poses
from vo.map import Map
from vo.map_matching import MapMatcher
from vo.map_merge import MapMerger
from vo.map_start import MapStart, build_depth_map, build_initial_map, init_step, seeds_for_map
from vo.mapping import Mapper
from vo.mapping_control import InlineMapping, MappingBacklog
from vo.mapping_thread import ThreadedMapping
from vo.relocalization import Relocalizer
from vo.relocalizing import Relocalizing
from vo.reprojector import Reprojector
from vo.result import FrameResult, Quality, ms_since
from vo.rotation_prior import Orientation
from vo.stepped_mapping import SteppedMapping


class TrackerState(Enum):
    """What the tracker does with the next frame."""

    INITIALIZING = "initializing"  # no map: the initialiser tracks corners until it builds one
    TRACKING = "tracking"  # tracking from the last frame in the map
    RELOCALIZING = "relocalizing"  # lost: looking for the pose in the map, a new one aside


class Tracker:
    """SDVL tracker for one camera, monocular or with a depth camera."""

    def __init__(self, camera: CameraModel, config: TrackerConfig | None = None,
                 threaded: bool = False, stepped_mapping: bool = False):
        """`threaded`: mapping in its own thread; `stepped_mapping` (a test hook, without
        `threaded`): mapping as in threaded mode, but only when the caller runs it
        (map_waiting), so a slow mapping thread can be emulated deterministically."""
        self.camera = camera
        self.config = config or TrackerConfig()
        self.threaded = threaded
        self.stepped_mapping = stepped_mapping and not threaded
        if threaded:
            self.mapping = ThreadedMapping(self.config.mapping_queue_size)
        elif self.stepped_mapping:
            self.mapping = SteppedMapping(self.config.mapping_queue_size)
        else:
            self.mapping = InlineMapping()
        self._frame_id = 0
        # set by the first depth map (with config.depth): from then on maps start only from
        # depth, so every map is metric (a monocular one's scale would be arbitrary)
        self.depth_mode = False
        self.reprojector = Reprojector(camera, self.config)
        self.merger = MapMerger(camera, self.config, self.reprojector)
        self.map: Map | None = None
        self._reset()

    # ------------------------------------------------------------------ lifecycle
    def _reset(self) -> None:
        """Start initialising a new map; the one it replaces is kept for merging
        (vo.map_merge)."""
        self.mapping.stop()
        cfg = self.config
        if self.map is not None:
            self.merger.retire(self.map, self.tracking.last, metric=self.depth_mode)
        self.map = Map(self.camera.width, self.camera.height, cfg.pyramid_levels,
                       cfg.max_keyframes)
        self.map.points.newest_frame = self._frame_id - 1
        self.mapper = Mapper(self.camera, cfg, self.map)
        self.mapper.after_ba = self._follow_ba
        self.mapper.merge_step = self.merger.step
        matcher = MapMatcher(self.camera, cfg, self.map, self.reprojector)
        self.tracking = FrameTracking(cfg, matcher, KeyframePolicy(cfg, self.mapper))
        self.relocalizing = Relocalizing(cfg, Relocalizer(self.camera, cfg, matcher),
                                         self.tracking)
        self.start = MapStart(self.camera, cfg)
        self.state = TrackerState.INITIALIZING
        self.lost_init: Initializer | None = None  # a new map, built while relocalising
        self.view_since: float | None = None  # lost, and the view usable since this time
        self.mapping.attach(self.mapper)

    def close(self) -> None:
        """Stop the mapping thread (if any)."""
        self.mapping.stop()

    @property
    def last(self) -> Frame | None:
        """The last frame tracked in the current map (None before the map)."""
        return self.tracking.last

    @property
    def backlog(self) -> MappingBacklog | None:
        """Tracked frames waiting for mapping (None with sequential mapping)."""
        return self.mapping.backlog

    def wait_for_mapping(self, timeout: float | None = None) -> bool:
        """Wait (threaded mapping) until the mapping backlog has room for another frame;
        False on timeout. A service calls this before taking the newest frame, so a slow
        mapper makes it skip whole frames instead of tracking against a stale map; process()
        waits too."""
        return self.mapping.wait_for_room(timeout)

    def map_waiting(self, n: int = 1) -> int:
        """Stepped mapping: run the mapping steps of up to n waiting frames, oldest first;
        how many ran."""
        if not isinstance(self.mapping, SteppedMapping):
            raise RuntimeError("map_waiting is for a tracker with stepped_mapping")
        return self.mapping.run_waiting(n)

    def _follow_ba(self, moved: dict[int, tuple[np.ndarray, np.ndarray]]) -> None:
        """A BA moved keyframes (the mapping thread calls this with the map lock held, so
        between two frames): the last frame, tracked against the map before, moves along
        with them; it is the next frame's prior and alignment reference (threaded, a stale
        one is far off); so does the last frame published, which a hold may end in. A
        keyframe's pose is the map's: the BA set it."""
        frames = [self.tracking.last]
        published = self.tracking.published
        if published is not None and published[0] is not frames[0]:
            frames.append(published[0])
        for frame in frames:
            if frame is not None and not frame.is_keyframe:
                frame.T_c_w = bundle_adjustment.follow(frame.T_c_w, frame.feat_point, self.map,
                                                       moved)

    # ------------------------------------------------------------------ per frame
    def process(self, image: np.ndarray, t: float, depth: np.ndarray | None = None,
                orientation: Orientation | None = None) -> FrameResult:
        """Track one grey uint8 image taken at time t (seconds), with its depth map when the
        camera has one (float metres along the optical axis, registered to the image, 0 or
        NaN = none; vo.depth_seeds) and the camera's orientation when the caller knows it
        (vo.rotation_prior)."""
        image = check_image(image, self.camera)
        if depth is not None:
            depth = check_depth_map(depth, self.camera.width, self.camera.height)
        self.mapping.before_frame()
        try:
            return self._process(image, float(t), depth if self.config.depth else None,
                                 orientation)
        finally:
            self.mapping.frame_tracked()

    def _process(self, image: np.ndarray, t: float, depth: np.ndarray | None,
                 orientation: Orientation | None) -> FrameResult:
        timings: dict[str, float] = {}
        t0 = time.perf_counter()
        unmapped = self.mapping.unmapped()
        frame = Frame(self._frame_id, float(t), image, self.camera, self.config.pyramid_levels)
        frame.depth = depth
        frame.orientation = orientation
        self.depth_mode = self.depth_mode or depth is not None
        self._frame_id += 1
        self.map.points.newest_frame = frame.id
        timings["pyramid"] = ms_since(t0)
        result, keyframe = self._step(frame, timings)
        timings["track"] = ms_since(t0)
        if result.quality == Quality.GOOD and unmapped > self.config.mapping_lag_good:
            result.quality = Quality.INSUFFICIENT  # the map lags: its pose may be off
        self.mapping.frame_tracked()  # tracked: a BA may go on
        if result.quality == Quality.LOST:
            self._on_lost()  # outside the map lock: a reset joins the mapping thread
        # mapping follows frames tracked against the map, relocalised ones too (a new map's
        # frames are in it already; poses before the map have none)
        new_map = result.new_segment and not result.relocalized
        if result.has_pose and self.last is frame and not (new_map or frame.is_keyframe):
            t1 = time.perf_counter()
            self.mapping.submit(frame, keyframe)
            timings["mapping"] = ms_since(t1)
        with self.map.lock:
            result.merged = self.merger.take_merged()
        result.timings = timings
        result.keyframe = keyframe
        return result

    def _step(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        """Frame's result in the current state, and whether it is a new keyframe."""
        if self.state is TrackerState.INITIALIZING:
            return self._initialize(frame, timings)
        if self.state is TrackerState.RELOCALIZING:
            with self.map.lock:
                result, keyframe = self._relocalize(frame, timings)
            if result.quality == Quality.LOST:
                return self._initialize_while_lost(frame, timings, result)
            return result, keyframe
        with self.map.lock:
            return self.tracking.track(frame, timings)

    def _initialize(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        if self.depth_mode:
            return self._start_from_depth(frame, timings)
        found = self.start.step(frame, timings)
        if isinstance(found, FrameResult):
            return found, False
        # the map's world is the reference camera, in which the poses so far were given
        posed = self.start.posed_ref is self.start.initializer.ref
        result = self._start_map(self.start.initializer, frame, found, timings,
                                 self.start.posed_t if posed else None)
        return result, True

    def _start_map(self, init: Initializer, frame: Frame, views: InitialMap,
                   timings: dict[str, float], posed_until: float | None = None) -> FrameResult:
        """A new map from the initialiser's two views; frame's result: a new segment unless
        poses were given from the same reference (until `posed_until`), with late poses for
        the frames the initialiser saw since (vo.late_poses)."""
        cfg = self.config
        n = build_initial_map(self.map, init.ref, frame, views, self.mapper.px_angle, cfg)
        self.state = TrackerState.TRACKING
        result = self.tracking.start(frame, n)
        result.new_segment = posed_until is None
        t0 = time.perf_counter()
        result.earlier = late_poses(list(init.views), views, init.ref.feat_point,
                                    self.tracking.matcher, cfg, posed_until)
        timings["late_poses"] = ms_since(t0)
        return result

    def _start_from_depth(self, frame: Frame,
                          timings: dict[str, float]) -> tuple[FrameResult, bool]:
        """A new map from frame's depth map alone (frame is its first keyframe, a new
        segment); no pose while the frame has no depth map or too few corners with depth."""
        seeds = self._depth_seeds(frame, timings)
        if seeds is None:
            return FrameResult(frame.t, None, Quality.INITIALIZING), False
        return self._start_depth_map(frame, seeds), True

    def _depth_seeds(self, frame: Frame, timings: dict[str, float]) -> DepthSeeds | None:
        """The points of a map started on frame from its depth map (None: no depth map, or
        too few corners with depth)."""
        t0 = time.perf_counter()
        seeds = None if frame.depth is None else seeds_for_map(frame, self.mapper, self.config)
        timings["init"] = ms_since(t0)
        return seeds

    def _start_depth_map(self, frame: Frame, seeds: DepthSeeds) -> FrameResult:
        """A new map of frame and its depth seeds; frame's result (a new segment)."""
        n = build_depth_map(self.map, frame, seeds, self.config)
        self.state = TrackerState.TRACKING
        return self.tracking.start(frame, n)

    def _on_lost(self) -> None:
        """Tracking is lost: relocalise (6.9) against the map from now on (building a new
        map on the side when re-initialisation is allowed), or start a new map at once when
        relocalisation is off."""
        cfg = self.config
        if self.state is TrackerState.RELOCALIZING:
            return
        if cfg.relocalize and self.map.keyframes:
            self.state = TrackerState.RELOCALIZING
            self.relocalizing.reset()
            self.view_since = None
            self.lost_init = (Initializer(self.camera, cfg)
                              if cfg.reinit_when_lost and not self.depth_mode else None)
        elif cfg.reinit_when_lost:
            self._reset()

    def _relocalize(self, frame: Frame, timings: dict[str, float]) -> tuple[FrameResult, bool]:
        """Frame's verified pose in the map (vo.relocalizing), tracking going on from it, and
        whether it becomes a keyframe; quality LOST if none."""
        result, keyframe = self.relocalizing.step(frame, timings, self.last)
        if result.has_pose:
            self.state = TrackerState.TRACKING
            self.lost_init = None
        return result, keyframe

    def _initialize_while_lost(self, frame: Frame, timings: dict[str, float],
                               lost: FrameResult) -> tuple[FrameResult, bool]:
        """While relocalising, a new map is initialised on the side; it replaces the old map
        once relocalisation has failed for reinit_after_lost_s seconds since the view
        became usable (the initialiser could first track features into a frame: a covered
        lens does not count)."""
        if self.depth_mode:
            return self._restart_from_depth(frame, timings, lost)
        init = self.lost_init
        if init is None:
            return lost, False
        # the two views are fitted only once their map may replace the old one (the view
        # usable since this frame if not before)
        since = frame.t if self.view_since is None else self.view_since
        outcome = init_step(init, frame, timings,
                            build=frame.t - since >= self.config.reinit_after_lost_s)
        if outcome is not InitOutcome.RESTART and self.view_since is None:
            self.view_since = frame.t
        if not isinstance(outcome, InitialMap):
            return lost, False
        self._reset()
        return self._start_map(init, frame, outcome, timings), True

    def _restart_from_depth(self, frame: Frame, timings: dict[str, float],
                            lost: FrameResult) -> tuple[FrameResult, bool]:
        """With depth, a new map from a frame's depth replaces the old one once relocalisation
        has failed for reinit_after_lost_s seconds since a frame could start one (enough
        corners with depth: a covered lens does not count)."""
        seeds = self._depth_seeds(frame, timings) if self.config.reinit_when_lost else None
        if seeds is None:
            return lost, False
        if self.view_since is None:
            self.view_since = frame.t
        if frame.t - self.view_since < self.config.reinit_after_lost_s:
            return lost, False
        self._reset()
        return self._start_depth_map(frame, seeds), True
