"""Frames as the viewer sends them: tone-mapped 8-bit sRGB (the PNG previews' mapping,
pipeline/images.py ``srgb_encode``, bit for bit) compressed as JPEG, WebP or PNG, or the
linear frame as float16 for tone mapping in the page (decision 0043 measures each)."""

from __future__ import annotations

import io
from collections import OrderedDict

import numpy as np

from pipeline.images import srgb_encode

FORMATS = {"jpeg": "image/jpeg", "webp": "image/webp", "png": "image/png",
           "f16": "application/octet-stream"}
DEFAULT_FORMAT = "jpeg"
QUALITY = {"jpeg": 90, "webp": 85}


def tone_map_reference(rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear ``rgb`` × 2^``exposure`` as 8-bit sRGB uint8: the bytes of ``prt
    render``'s PNG preview with ``--exposure`` (pipeline/images.py ``srgb_encode``, as
    ``write_png`` rounds it), in float64 (≈ 10 ms a 512² frame on a free core)."""
    return np.round(srgb_encode(rgb, 2.0 ** exposure) * 255.0).astype(np.uint8)


BUCKET_SHIFT = 16  # a float32's sign, exponent and top 7 mantissa bits: 65,536 buckets
_TABLES: OrderedDict[float, tuple[np.ndarray, np.ndarray]] = OrderedDict()


def tone_table(exposure: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`tone_map_reference` at ``exposure`` as a table over a float32's bit
    pattern: per bucket of 2^16 consecutive patterns the 8-bit value of its first, and
    the first pattern of the bucket whose value is one more (2^32 − 1: none). The
    mapping is monotonic in a positive float's bits and climbs less than one step of
    255 within a bucket (x g'(x) ≤ 0.44 for the sRGB curve g: ≤ 0.88 steps over a
    bucket's 1/128 of x), so each bucket holds at most one step; each step's pattern
    is found by bisection on the reference itself and checked on both sides. Negative
    numbers map to 0 (the clip); NaN is not a frame's (the server refuses such frames)."""
    key = float(exposure)
    if key in _TABLES:
        _TABLES.move_to_end(key)
        return _TABLES[key]
    first = np.arange(1 << (32 - BUCKET_SHIFT), dtype=np.uint64) << BUCKET_SHIFT
    last = first | ((1 << BUCKET_SHIFT) - 1)

    def value(bits: np.ndarray) -> np.ndarray:
        x = bits.astype(np.uint32).view(np.float32)
        with np.errstate(invalid="ignore"):
            return tone_map_reference(np.where(np.isnan(x), 0, x), exposure).astype(np.int64)

    low, high = value(first), value(last)
    step = np.full(len(first), 0xFFFFFFFF, np.uint32)
    positive = first < 0x7F800000  # finite, not negative: the sign bit is clear
    climbs = np.flatnonzero(positive & (high != low))
    if np.any(high[climbs] - low[climbs] != 1):
        raise AssertionError("a tone-map bucket holds more than one step")
    lo, hi = first[climbs], last[climbs]  # value(lo) is low, value(hi) is low + 1
    for _ in range(BUCKET_SHIFT + 1):
        mid = (lo + hi) // 2
        up = value(mid) > low[climbs]
        hi, lo = np.where(up, mid, hi), np.where(up, lo, mid)
    if len(climbs) and not (np.all(value(hi) == low[climbs] + 1)
                            and np.all(value(hi - 1) == low[climbs])):
        raise AssertionError("a tone-map step is not where the bisection found it")
    step[climbs] = hi
    low[~positive & (first != 0x7F800000)] = 0  # negative (and NaN): 0; +inf keeps 255
    table = (low.astype(np.uint8), step)
    _TABLES[key] = table
    if len(_TABLES) > 8:
        _TABLES.popitem(last=False)
    return table


def tone_map(rgb: np.ndarray, exposure: float = 0.0) -> np.ndarray:
    """Linear ``rgb`` (H, W, 3) × 2^``exposure`` as 8-bit sRGB (H, W, 3) uint8: the
    bytes of ``prt render``'s PNG preview with ``--exposure`` (:func:`tone_map_reference`,
    the previews' function, bit for bit), by table (:func:`tone_table`): ≈ 5× less time
    than the float64 curve, the encoding's largest part."""
    bits = np.ascontiguousarray(rgb, np.float32).view(np.uint32)
    low, step = tone_table(exposure)
    bucket = bits >> BUCKET_SHIFT
    out = low[bucket]
    out += bits >= step[bucket]
    return out


def encode(rgb: np.ndarray, fmt: str, exposure: float = 0.0) -> bytes:
    """``rgb`` encoded as ``fmt`` (:data:`FORMATS`); float16 is linear, row-major RGB."""
    from PIL import Image

    if fmt == "f16":
        return np.ascontiguousarray(rgb, np.float16).tobytes()
    image = Image.fromarray(tone_map(rgb, exposure), "RGB")
    buffer = io.BytesIO()
    if fmt == "jpeg":
        image.save(buffer, format="JPEG", quality=QUALITY["jpeg"])
    elif fmt == "webp":
        image.save(buffer, format="WEBP", quality=QUALITY["webp"], method=0)
    elif fmt == "png":
        image.save(buffer, format="PNG", compress_level=1)
    else:
        raise ValueError(f"unknown frame format {fmt!r}")
    return buffer.getvalue()


def difference(rgb: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The relative difference per pixel |frame − reference| / (reference + 0.01 ×
    its mean), as a linear grey image where 1 (white) is 100 % (for the page's
    difference view; tone-mapped like a frame at exposure 0)."""
    lum = reference.mean(axis=2, keepdims=True)
    rel = np.abs(rgb - reference).mean(axis=2, keepdims=True) / (lum + 0.01 * lum.mean()
                                                                 + 1e-12)
    return np.repeat(np.clip(rel, 0, 1), 3, axis=2).astype(np.float32)
