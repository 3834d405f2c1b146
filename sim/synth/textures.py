"""Surface textures for the synthetic world: procedural multi-scale patterns or photographs,
stored as mip-map pyramids in one flat float32 array the ray caster samples.

Texel k of level 0 covers texture coordinates [k, k+1); level L halves the resolution with a
2x2 box average, so texel k of level L covers [k 2^L, (k+1) 2^L) and every level agrees on where
an edge is (exact geometry at any distance). Sizes are powers of two so wrapping (tiling) is
consistent across levels.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from sdvl.errors import InputError
from sim import disk_cache
from sim.shared_data import shared_data_dir

TEXTURE_SUFFIXES = (".jpg", ".jpeg", ".png")
MIN_LEVEL_SIZE = 4


@dataclass
class TextureAtlas:
    """Mip pyramids of several textures: `levels[t, l] = (offset, width, height)` into `pixels`,
    `n_levels[t]` levels for texture t."""

    pixels: np.ndarray
    levels: np.ndarray
    n_levels: np.ndarray

    def __len__(self) -> int:
        return int(self.n_levels.size)


def mip_pyramid(image: np.ndarray) -> list[np.ndarray]:
    """Level 0 (float32, power-of-two sides) and its 2x2 box-averaged reductions."""
    level = np.ascontiguousarray(image, dtype=np.float32)
    h, w = level.shape
    if h & (h - 1) or w & (w - 1):
        raise ValueError(f"texture sides must be powers of two, got {w}x{h}")
    out = [level]
    while min(level.shape) >= 2 * MIN_LEVEL_SIZE:
        h, w = level.shape
        level = level.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3), dtype=np.float32)
        out.append(level)
    return out


def build_atlas(images: list[np.ndarray]) -> TextureAtlas:
    """One atlas from grey images (values 0..255, power-of-two sides)."""
    pyramids = [mip_pyramid(img) for img in images]
    n_max = max(len(p) for p in pyramids)
    levels = np.zeros((len(pyramids), n_max, 3), dtype=np.int64)
    chunks, offset = [], 0
    for t, pyramid in enumerate(pyramids):
        for lv, img in enumerate(pyramid):
            levels[t, lv] = (offset, img.shape[1], img.shape[0])
            chunks.append(img.ravel())
            offset += img.size
    n_levels = np.array([len(p) for p in pyramids], dtype=np.int64)
    return TextureAtlas(np.concatenate(chunks), levels, n_levels)


def _octave_noise(rng: np.random.Generator, size: int, octaves: int) -> np.ndarray:
    """Sum of smooth random fields at every scale from size/2 down to 2 texels (1/f spectrum)."""
    out = np.zeros((size, size), np.float32)
    for k in range(octaves):
        n = max(2, size >> (octaves - k))
        field = rng.standard_normal((n, n)).astype(np.float32)
        tiled = np.tile(field, (3, 3))  # wrap-consistent resize
        big = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
        out += big[size:2 * size, size:2 * size] * (0.6 ** (octaves - 1 - k))
    return out


def _dead_leaves(rng: np.random.Generator, size: int, shapes: int) -> np.ndarray:
    """Overlapping rectangles and discs of power-law sizes: sharp corners at every scale."""
    img = np.full((size, size), 128.0, np.float32)
    radii = np.clip(size / 6 * rng.random(shapes) ** 3, 1.5, None)
    for r in radii[np.argsort(-radii)]:
        x, y = rng.integers(0, size, 2)
        value = float(rng.uniform(10, 245))
        if rng.random() < 0.6:
            a, b = int(r), int(r * rng.uniform(0.3, 1.0))
            cv2.rectangle(img, (int(x) - a, int(y) - b), (int(x) + a, int(y) + b), value, -1)
        else:
            cv2.circle(img, (int(x), int(y)), int(r), value, -1, cv2.LINE_AA)
    return img


@functools.lru_cache(maxsize=16)
def procedural_texture(seed: int, size: int = 2048, shapes_per_mpx: int = 6000) -> np.ndarray:
    """A grey (size x size) texture with detail at every scale: dead-leaves shapes (corners,
    edges) modulated by 1/f noise (shading). Deterministic for `seed`; read-only result, kept
    on disk between runs (seconds to make at 2048 px)."""
    code = disk_cache.source_digest("synth").hex()[:16]
    key = f"procedural-{seed}-{size}-{shapes_per_mpx}-{code}"
    img = disk_cache.cached_array("textures", key,
                                  lambda: _procedural(seed, size, shapes_per_mpx))
    img.flags.writeable = False
    return img


def _procedural(seed: int, size: int, shapes_per_mpx: int) -> np.ndarray:
    """procedural_texture's image, made from scratch."""
    rng = np.random.default_rng(seed)
    shapes = int(shapes_per_mpx * size * size / 1e6)
    leaves = _dead_leaves(rng, size, shapes)
    octaves = int(np.log2(size)) - 1
    noise = _octave_noise(rng, size, octaves)
    img = leaves + 18.0 * noise / max(float(noise.std()), 1e-6)
    return np.clip(img, 0, 255).astype(np.float32)


def checker_texture(squares: int = 8, square_texels: int = 16) -> np.ndarray:
    """A black-and-white checkerboard (for exact-geometry tests): corners at multiples of
    `square_texels` texels."""
    n = squares * square_texels
    idx = np.arange(n) // square_texels
    return np.where((idx[:, None] + idx[None, :]) % 2 == 0, 40.0, 215.0).astype(np.float32)


def default_texture_dir() -> Path:
    """The shared data textures folder ($SDVL_DATA/textures or ../shared/data/textures)."""
    return shared_data_dir() / "textures"


def _power_of_two_below(n: int) -> int:
    return 1 << (int(n).bit_length() - 1)


def load_texture_image(path: Path, size: int | None = None) -> np.ndarray:
    """A grey photo without its top quarter (sky in aerial and street photos), resized to
    power-of-two sides (`size` square if given) and mirrored into a seamless 2x2 tile."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError("cannot read texture image", path)
    img = img[img.shape[0] // 4:]
    w = size or _power_of_two_below(img.shape[1])
    h = size or _power_of_two_below(img.shape[0])
    img = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32)
    top = np.hstack([img, img[:, ::-1]])
    return np.vstack([top, top[::-1]])


def photo_textures(source: str | Path | None) -> list[np.ndarray]:
    """Photos from a folder ('auto': the shared textures if present); [] for 'procedural'."""
    if source == "procedural":
        return []
    folder = default_texture_dir() if source in (None, "auto") else Path(source)
    if not folder.is_dir():
        if source in (None, "auto"):
            return []
        raise InputError("texture folder not found", folder)
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in TEXTURE_SUFFIXES)
    return [load_texture_image(p) for p in files]
