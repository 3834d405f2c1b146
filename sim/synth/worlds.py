"""The worlds presets fly in: open ground with buildings, ramps and photo patches (for the
downward-looking flights), and a furnished room (for the hand-held camera)."""

from __future__ import annotations

import numpy as np

from sim.synth.scene import INFINITE, QuadList, Scene, add_box, add_ramp, add_room
from sim.synth.textures import build_atlas, photo_textures, procedural_texture

GROUND, DETAIL, PHOTO0 = 0, 1, 2
N_PHOTOS = 4
OVERLAY = PHOTO0 + N_PHOTOS
GROUND_TEXEL = 0.012  # m: the 2048-texel ground tile is 24.6 m wide
# A second ground tiling, 22.75 m wide and turned by 33 degrees: wherever the first tile
# repeats within 200 m the second is at least 2.6 m off its own lattice, so the sum of the
# two never repeats at flight scale (a repeating ground fooled relocalisation by a tile).
GROUND_OVERLAY = (GROUND, OVERLAY, 1024 * GROUND_TEXEL / 22.75, np.radians(33.0), 0.7)


def texture_images(seed: int, source: str | None) -> list[np.ndarray]:
    """Ground (2048 px), detail (1024 px), four photos (procedural stand-ins when the photos
    are not there or `source` is 'procedural') and the ground overlay (1024 px)."""
    photos = photo_textures(source)[:N_PHOTOS]
    photos += [procedural_texture(seed + 10 + k, 512) for k in range(N_PHOTOS - len(photos))]
    return [procedural_texture(seed, 2048), procedural_texture(seed + 1, 1024), *photos,
            procedural_texture(seed + 2, 1024)]


def outdoor_scene(seed: int, source: str | None, clear_radius: float = 4.0,
                  extent: float = 60.0, blocks: int = 30) -> Scene:
    """Textured ground at z = 0 with buildings (0.5-3 m), ramps and flat photo patches
    (fields, roofs; those of the second photo are shiny metal roofs) in a square of
    +-`extent` m; nothing taller than the ground within `clear_radius` m of the origin
    (take-off spot)."""
    rng = np.random.default_rng(seed)
    quads = QuadList()
    quads.add([-INFINITE / 2, -INFINITE / 2, 0.0], [1, 0, 0], [0, 1, 0], INFINITE, INFINITE,
              GROUND, GROUND_TEXEL, (0.0, 0.0))
    for _ in range(blocks // 2):
        corner = rng.uniform(-extent, extent, 2)
        size = rng.uniform(4.0, 12.0, 2)
        quads.add([corner[0], corner[1], -0.01], [1, 0, 0], [0, 1, 0], size[0], size[1],
                  int(PHOTO0 + rng.integers(N_PHOTOS)), rng.uniform(0.02, 0.05),
                  rng.uniform(0, 4096, 2), rng.uniform(0.8, 1.1))
    placed = 0
    while placed < blocks:
        center = rng.uniform(-extent, extent, 2)
        if np.linalg.norm(center) < clear_radius + 8.0:
            continue
        placed += 1
        if rng.random() < 0.2:
            add_ramp(quads, center, rng.uniform(0, 2 * np.pi), rng.uniform(3, 6),
                     rng.uniform(1.5, 3), rng.uniform(0.5, 1.5), DETAIL, 0.006, rng)
            continue
        size = (rng.uniform(2, 8), rng.uniform(2, 8), rng.uniform(0.5, 3.0))
        add_box(quads, center, size, rng.uniform(0, np.pi), DETAIL, 0.008, rng)
    return Scene(quads, build_atlas(texture_images(seed, source)), background=150.0,
                 detail=(DETAIL, 8.0, 0.4), overlay=GROUND_OVERLAY, glossy=(PHOTO0 + 1,))


def room_scene(seed: int, source: str | None, size=(10.0, 7.0), height: float = 3.0) -> Scene:
    """A room centred on the origin with photo and pattern walls, tables and cabinets; the
    posters (and furniture covered with the same photo) are glossy prints."""
    rng = np.random.default_rng(seed)
    quads = QuadList()
    add_room(quads, size, height, (GROUND, PHOTO0 + 2, DETAIL), 0.004, rng)
    sx, sy = size
    for x, y in ((-sx / 2 + 0.4, -1.5), (-sx / 2 + 0.4, 1.5), (sx / 2 - 0.4, 0.0),
                 (0.0, sy / 2 - 0.4), (-2.0, -sy / 2 + 0.4), (2.5, -sy / 2 + 0.4)):
        add_box(quads, (x, y), (0.8, 1.2, rng.uniform(0.7, 2.0)), 0.0,
                int(PHOTO0 + rng.integers(N_PHOTOS)), 0.003, rng)
    for wall_x in (-sx / 2 + 0.01, sx / 2 - 0.01):  # posters
        quads.add([wall_x, -1.0, -0.8], [0, 1, 0], [0, 0, -1], 2.0, 1.4,
                  PHOTO0 + 3, 0.003, (0.0, 0.0))
    return Scene(quads, build_atlas(texture_images(seed, source)), background=150.0,
                 detail=(DETAIL, 8.0, 0.3), glossy=(PHOTO0 + 3,))
