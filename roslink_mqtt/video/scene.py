"""The simulator's camera picture: a scene that moves with the robot, with its capture time written in it. Numpy only.

Why the time is in the picture twice: as digits for a person looking at the dashboard, and as a row of black and
white blocks (:func:`read_stamp`) that survives a low-bitrate encoder, so a bench reads each decoded picture's
capture time from the pixels themselves and measures glass to glass without trusting any header.
"""

from __future__ import annotations

import math
import time
from functools import lru_cache

import numpy as np

STAMP_BITS = 40  # ms since the epoch, modulo 2**40 (34 years)
CHECK_BITS = 8
BLOCKS = STAMP_BITS + CHECK_BITS
BAND = 1 / 12  # of the picture's height: the blocks' row at the top

# 3×5 digits, row by row (the time as people read it)
_FONT = {
    "0": "111101101101111", "1": "010110010010111", "2": "111001111100111", "3": "111001111001111",
    "4": "101101111001001", "5": "111100111001111", "6": "111100111101111", "7": "111001001001001",
    "8": "111101111101111", "9": "111101111001111", ":": "000010000010000", ".": "000000000000010",
}


# colours: floor tile dark, light; sky band dark, light; the floor far away (tiles too small to tell apart)
_PALETTE = np.array([[60, 90, 40], [200, 170, 120], [90, 140, 230], [120, 170, 230], [130, 130, 80]], np.uint8)
FAR = 8.0  # m: the floor beyond is haze


@lru_cache(maxsize=4)
def _rays(width: int, height: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
    """Per floor pixel, its distance ahead and to the side (m) from 0.5 m up; per column, where it looks."""
    horizon = height // 2
    v = (np.arange(horizon, height, dtype=np.float32) + 0.5) / height - 0.5
    u = (np.arange(width, dtype=np.float32) + 0.5) / width - 0.5
    depth = (0.5 / v)[:, None] * np.ones((1, width), np.float32)
    side = depth * (u * 1.6)[None, :]
    return depth, side, u, horizon, depth > FAR


def render(width: int, height: int, x: float, y: float, yaw: float, stamp: float) -> np.ndarray:
    """An RGB picture (height × width × 3, uint8) of what the robot at (x, y, yaw) sees at ``stamp``: a floor of
    1 m tiles that slide past as it drives and turn as it turns, a sky whose bands turn with it, the time."""
    depth, side, u, horizon, far = _rays(width, height)
    c, s = math.cos(yaw), math.sin(yaw)
    fx = np.floor(x + c * depth - s * side).astype(np.int32)
    fy = np.floor(y + s * depth + c * side).astype(np.int32)
    index = np.empty((height, width), np.uint8)
    floor = ((fx + fy) & 1).astype(np.uint8)
    floor[far] = 4
    index[horizon:] = floor
    index[:horizon] = (2 + ((u * 1.2 + yaw / (2 * math.pi) * 8) % 1.0 < 0.5)).astype(np.uint8)[None, :]
    image = _PALETTE[index]
    _write_stamp(image, stamp)
    _write_text(image, time.strftime("%H:%M:%S", time.gmtime(stamp)) + f".{int(stamp * 1000) % 1000:03d}")
    return image


def _bits(stamp: float) -> list[int]:
    ms = int(round(stamp * 1000)) % (1 << STAMP_BITS)
    check = sum((ms >> (8 * i)) & 0xFF for i in range(STAMP_BITS // 8)) & 0xFF
    return [(ms >> (STAMP_BITS - 1 - i)) & 1 for i in range(STAMP_BITS)] + \
        [(check >> (CHECK_BITS - 1 - i)) & 1 for i in range(CHECK_BITS)]


def _write_stamp(image: np.ndarray, stamp: float) -> None:
    height, width = image.shape[:2]
    band = max(4, int(height * BAND))
    for i, bit in enumerate(_bits(stamp)):
        image[:band, i * width // BLOCKS:(i + 1) * width // BLOCKS] = 255 if bit else 0


def read_stamp(image: np.ndarray) -> float | None:
    """The capture time written by :func:`render`, from a picture (RGB or luma, any size it was scaled to); None
    when the blocks do not check out (a picture from elsewhere, or too damaged to read)."""
    luma = image if image.ndim == 2 else image.mean(axis=2)
    height, width = luma.shape
    row = max(1, int(height * BAND / 2))
    bits = [1 if luma[row, (2 * i + 1) * width // (2 * BLOCKS)] > 127 else 0 for i in range(BLOCKS)]
    ms = int("".join(map(str, bits[:STAMP_BITS])), 2)
    check = int("".join(map(str, bits[STAMP_BITS:])), 2)
    if check != sum((ms >> (8 * i)) & 0xFF for i in range(STAMP_BITS // 8)) & 0xFF:
        return None
    now_ms = int(time.time() * 1000)
    base = now_ms - now_ms % (1 << STAMP_BITS)
    return (base + ms) / 1000.0


def _write_text(image: np.ndarray, text: str) -> None:
    height = image.shape[0]
    scale = max(1, height // 60)
    top = max(4, int(height * BAND)) + scale * 2
    left = scale * 2
    for n, char in enumerate(text):
        glyph = _FONT.get(char)
        if glyph is None:
            continue
        x0 = left + n * 4 * scale
        for i, on in enumerate(glyph):
            if on == "1":
                r, c = divmod(i, 3)
                image[top + r * scale:top + (r + 1) * scale, x0 + c * scale:x0 + (c + 1) * scale] = 255
