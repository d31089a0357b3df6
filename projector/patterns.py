"""Seeded multi-scale random patterns for the dome's projectors.

Why this design: SIFT detects blobs in a scale space and describes the gradients around them. A single-frequency
texture gives features at one scale only and repeats locally (ambiguous matches). Here each pattern is a sum of
band-pass noise octaves (difference of Gaussians of white noise, wavelengths from ~4 to ~64 projector pixels, equal
energy per octave), so blobs exist at every scale, every neighbourhood is unique, and the pattern stays
distinctive whether a camera sees a projector pixel as 0.6 VGA pixels or 1.3 HD pixels. The sum is then
contrast-normalised by its rank (a uniform histogram over the full 8-bit range): maximum contrast everywhere
without clipping, which keeps features well localised in the darker corners of the projection too.

Resolution: 1280x800 (WXGA), the native resolution of common short-throw projectors; at the dome's throw of
~2.7 m with a 1000 px focal length one projector pixel is ~2.7 mm on the tent, slightly finer than a VGA pixel
(~3.7 mm) and coarser than an HD pixel (~1.9 mm): the finest octave (4 px) still spans >= 2 VGA pixels.
"""
from __future__ import annotations

import zlib
from dataclasses import field
from pathlib import Path

import cv2
import numpy as np

from dome_calib.ownership import claim_file, claim_into, write_bytes
from dome_calib.options import AtLeast, options
from dome_calib.schema import NonNegFinite, PosFinite

PROJECTOR_NAMES = ("P1", "P2", "P3", "P4", "P5")


@options
class PatternOptions:
    """Pattern shape. ``wavelengths_px``: centre wavelength of each band-pass octave, projector pixels."""

    resolution: tuple[AtLeast(1), AtLeast(1)] = (1280, 800)  # (width_px, height_px)
    wavelengths_px: tuple[PosFinite, ...] = (4.0, 8.0, 16.0, 32.0, 64.0)
    octave_weights: tuple[NonNegFinite, ...] | None = None  # default: equal energy per octave
    extra: dict = field(default_factory=dict)


def _band(noise: np.ndarray, wavelength_px: float) -> np.ndarray:
    """Band-pass (difference of Gaussians one octave wide) centred near ``wavelength_px``, unit variance."""
    s = wavelength_px / (2.0 * np.pi) * 1.4
    fine = cv2.GaussianBlur(noise, (0, 0), s / np.sqrt(2.0), borderType=cv2.BORDER_REFLECT)
    coarse = cv2.GaussianBlur(noise, (0, 0), s * np.sqrt(2.0), borderType=cv2.BORDER_REFLECT)
    band = fine - coarse
    return band / (band.std() + 1e-12)


def _stable_order(values: np.ndarray) -> np.ndarray:
    """``np.argsort(values, axis=None, kind="stable")`` of a float32 array without NaNs, the same indices, about
    3x faster: each value's bits become an unsigned key in the floats' order (-0.0 made +0.0 first, so equal
    values tie), the flat index fills the low 32 bits, and one sort of the distinct 64-bit keys orders them."""
    bits = (np.ascontiguousarray(values, np.float32) + np.float32(0.0)).view(np.uint32).ravel()
    negative = (bits >> np.uint32(31)).astype(bool)
    key = np.where(negative, ~bits, bits | np.uint32(0x80000000)).astype(np.uint64) << np.uint64(32)
    key |= np.arange(bits.size, dtype=np.uint64)
    return (np.sort(key) & np.uint64(0xFFFFFFFF)).astype(np.intp)


def pattern_seed(seed: int, name: str) -> int:
    """A projector's own seed, derived from the capture seed and its name (stable across runs and platforms)."""
    return (int(seed) * 1_000_003 + zlib.crc32(name.encode())) % (2**32)


def make_pattern(seed: int, name: str = "P1", options: PatternOptions | None = None) -> np.ndarray:
    """One projector's pattern: (height, width) float32 in [0, 1], row 0 at the top of the projector image.

    Example:
        >>> p = make_pattern(0, "P3"); p.shape
        (800, 1280)
    """
    options = options or PatternOptions()
    w, h = options.resolution
    rng = np.random.default_rng(pattern_seed(seed, name))
    weights = options.octave_weights or (1.0,) * len(options.wavelengths_px)
    total = np.zeros((h, w), np.float32)
    for wavelength, weight in zip(options.wavelengths_px, weights):
        noise = rng.standard_normal((h, w)).astype(np.float32)
        total += np.float32(weight) * _band(noise, wavelength)
    # rank normalisation: uniform histogram over [0, 1]
    order = _stable_order(total)
    ranks = np.empty(order.size, np.float32)
    ranks[order] = np.linspace(0.0, 1.0, order.size, dtype=np.float32)
    return ranks.reshape(h, w)


def make_patterns(seed: int, names: tuple[str, ...] = PROJECTOR_NAMES,
                  options: PatternOptions | None = None) -> dict[str, np.ndarray]:
    """Patterns of several projectors keyed by name; each is distinct (own seed)."""
    return {n: make_pattern(seed, n, options) for n in names}


def pattern_to_uint8(pattern: np.ndarray) -> np.ndarray:
    """[0, 1] float pattern -> uint8 image for a projector."""
    return np.clip(np.rint(pattern * 255.0), 0, 255).astype(np.uint8)


def write_patterns(out_dir: str | Path, seed: int, names: tuple[str, ...] = PROJECTOR_NAMES,
                   options: PatternOptions | None = None) -> list[Path]:
    """Write ``<out_dir>/pattern_<name>.png`` (8-bit grayscale) for each projector, atomically; return the paths.
    Each replaces only a file dome-calib wrote (:mod:`dome_calib.ownership`), all checked before the first."""
    out = Path(out_dir)
    claim_into(out)
    for name in names:
        claim_file(out / f"pattern_{name}.png")
    paths = []
    for name, pattern in make_patterns(seed, names, options).items():
        ok, buf = cv2.imencode(".png", pattern_to_uint8(pattern))
        if not ok:
            raise OSError(f"{out}: could not encode pattern {name} as PNG")
        path = out / f"pattern_{name}.png"
        write_bytes(path, buf.tobytes())
        paths.append(path)
    return paths
