"""Scenes of textured rectangles (quads) in the world frame (NED: x north, y east, z down;
the ground is z = 0, so things above it have negative z).

A quad is an origin corner, two orthonormal edge directions u and v and its extent along each, in
metres; its texture coordinate (texels) at a point is ((p - origin).u, (p - origin).v) / texel
+ offset, wrapped. Boxes, ramps, walls and the ground are quads; moving objects are boxes whose
position is a function of time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.synth.textures import TextureAtlas

INFINITE = 1.0e5  # extent of the ground plane, m
QUAD_FIELDS = 14  # origin 3, u 3, v 3, extent 2, texel 1, offset 2


@dataclass
class QuadList:
    """Quads as rows of `geometry` (origin, u, v, extent_u, extent_v, texel_m, offset_u,
    offset_v) with their texture index and brightness gain."""

    geometry: np.ndarray = field(default_factory=lambda: np.zeros((0, QUAD_FIELDS)))
    texture: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    gain: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add(self, origin, u, v, extent_u: float, extent_v: float, texture: int,
            texel_m: float, offset=(0.0, 0.0), gain: float = 1.0) -> None:
        """Append one quad; u and v are normalised, v is made orthogonal to u."""
        u = np.asarray(u, float) / np.linalg.norm(u)
        v = np.asarray(v, float)
        v = v - (v @ u) * u
        v /= np.linalg.norm(v)
        row = np.concatenate([origin, u, v, [extent_u, extent_v, texel_m], offset])
        self.geometry = np.vstack([self.geometry, row])
        self.texture = np.append(self.texture, texture)
        self.gain = np.append(self.gain, gain)

    def extend(self, other: QuadList) -> QuadList:
        """A new list with `other`'s quads after these."""
        return QuadList(np.vstack([self.geometry, other.geometry]),
                        np.concatenate([self.texture, other.texture]),
                        np.concatenate([self.gain, other.gain]))

    def __len__(self) -> int:
        return len(self.texture)


def add_box(quads: QuadList, center, size, yaw: float, texture: int, texel_m: float,
            rng: np.random.Generator, ground_z: float = 0.0) -> None:
    """A box standing on the ground (z = ground_z): `size` (length, width, height) m, rotated
    by `yaw` about the vertical; top and four sides, each face its own texture region and
    shade."""
    L, W, H = size
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    up = np.array([0.0, 0.0, -1.0])
    base = np.array([center[0], center[1], ground_z]) - fwd * L / 2 - side * W / 2

    def face(origin, u, v, eu, ev, gain):
        quads.add(origin, u, v, eu, ev, texture, texel_m, rng.uniform(0, 4096, 2), gain)

    face(base + up * H, fwd, side, L, W, 1.0)
    face(base, fwd, up, L, H, rng.uniform(0.6, 0.9))
    face(base + side * W, fwd, up, L, H, rng.uniform(0.6, 0.9))
    face(base, side, up, W, H, rng.uniform(0.5, 0.8))
    face(base + fwd * L, side, up, W, H, rng.uniform(0.5, 0.8))


def add_ramp(quads: QuadList, start, direction_yaw: float, length: float, width: float,
             rise: float, texture: int, texel_m: float, rng: np.random.Generator) -> None:
    """A sloped plank from the ground at `start` (x, y) rising `rise` m over `length` m."""
    fwd = np.array([np.cos(direction_yaw), np.sin(direction_yaw), 0.0])
    side = np.array([-np.sin(direction_yaw), np.cos(direction_yaw), 0.0])
    slope = fwd * length + np.array([0.0, 0.0, -rise])
    origin = np.array([start[0], start[1], 0.0]) - side * width / 2
    quads.add(origin, slope, side, float(np.linalg.norm(slope)), width, texture, texel_m,
              rng.uniform(0, 4096, 2), 0.9)


def add_room(quads: QuadList, size, height: float, textures: tuple[int, int, int],
             texel_m: float, rng: np.random.Generator) -> None:
    """Floor, ceiling and four walls of a room centred on the origin: `size` (x, y) m, floor at
    z = 0; textures (floor, walls, ceiling)."""
    sx, sy = size
    floor, walls, ceiling = textures
    c = np.array([-sx / 2, -sy / 2, 0.0])
    ex, ey, up = np.eye(3)[0], np.eye(3)[1], np.array([0.0, 0.0, -1.0])

    def face(origin, u, v, eu, ev, tex, gain):
        quads.add(origin, u, v, eu, ev, tex, texel_m, rng.uniform(0, 4096, 2), gain)

    face(c, ex, ey, sx, sy, floor, 1.0)
    face(c + up * height, ex, ey, sx, sy, ceiling, 0.9)
    face(c, ex, up, sx, height, walls, 0.85)
    face(c + ey * sy, ex, up, sx, height, walls, 0.8)
    face(c, ey, up, sy, height, walls, 0.95)
    face(c + ex * sx, ey, up, sy, height, walls, 0.75)


@dataclass
class Walker:
    """A people-sized textured box walking a straight line at constant speed from t_start;
    it stands still for `pause` s after walking `pause_after` s (people who stop for a while
    become part of the map, then walk off with it)."""

    start: np.ndarray
    velocity: np.ndarray
    t_start: float
    texture: int
    texel_m: float
    seed: int
    size: tuple = (0.5, 0.3, 1.8)
    pause_after: float = 0.0
    pause: float = 0.0

    def quads(self, t: float) -> QuadList:
        """The box at time t (empty before it starts)."""
        out = QuadList()
        if t < self.t_start:
            return out
        walked = t - self.t_start
        walked -= min(max(walked - self.pause_after, 0.0), self.pause)
        pos = self.start + self.velocity * walked
        yaw = float(np.arctan2(self.velocity[1], self.velocity[0]))
        add_box(out, pos, self.size, yaw, self.texture, self.texel_m,
                np.random.default_rng(self.seed))
        return out


@dataclass
class Scene:
    """Static quads, moving objects and the textures they use; `background` is the grey level
    of rays that hit nothing; `detail` (texture, frequency factor, amplitude) adds fine
    structure to surfaces seen closer than one texel per pixel; `overlay` (base texture,
    overlay texture, scale, angle rad, weight) blends a second, scaled and turned texture into
    every quad of the base texture (an aperiodic ground); quads with a texture in `glossy`
    are shiny for depth cameras (sim.synth.depth_sensor)."""

    quads: QuadList
    atlas: TextureAtlas
    movers: list = field(default_factory=list)
    background: float = 128.0
    detail: tuple[int, float, float] | None = None
    overlay: tuple[int, int, float, float, float] | None = None
    height_at: Callable | None = None
    glossy: tuple[int, ...] = ()

    def quads_at(self, t: float) -> QuadList:
        """Everything in the scene at time t."""
        out = self.quads
        for mover in self.movers:
            out = out.extend(mover.quads(t))
        return out
