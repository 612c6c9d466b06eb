"""Image files: linear RGB to OpenEXR, sRGB-encoded PNG previews, EXR reading.

Images are (height, width, 3) float32 arrays of linear radiance, row 0 at the top.
Files are written to a temporary name and renamed, so a killed run never leaves a
truncated frame.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pipeline.errors import PrtError


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1) of values clipped to [0, 1]."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def write_exr(path: str | Path, rgb: np.ndarray) -> None:
    """Write a linear float32 RGB EXR (ZIP compressed)."""
    import OpenEXR

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _temporary(path)
        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        channels = {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}
        with OpenEXR.File(header, channels) as exr:
            exr.write(str(tmp))
        os.replace(tmp, path)
    except OSError as exc:
        raise PrtError(path, f"cannot write image ({exc.strerror or exc})") from None


def write_png(path: str | Path, rgb: np.ndarray, exposure: float = 1.0) -> None:
    """Write an 8-bit sRGB preview of linear ``rgb`` × ``exposure``."""
    from PIL import Image

    path = Path(path)
    encoded = np.round(srgb_encode(np.asarray(rgb, np.float64) * exposure) * 255.0)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _temporary(path)
        Image.fromarray(encoded.astype(np.uint8), "RGB").save(tmp, format="PNG")
        os.replace(tmp, path)
    except OSError as exc:
        raise PrtError(path, f"cannot write image ({exc.strerror or exc})") from None


def read_exr(path: str | Path) -> np.ndarray:
    """Read the RGB channels of an EXR as (height, width, 3) float32."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as exr:
            channels = exr.channels()
            if "RGB" in channels:
                rgb = channels["RGB"].pixels
            else:
                rgb = np.stack([channels[c].pixels for c in "RGB"], axis=-1)
    except Exception as exc:
        raise PrtError(path, f"cannot read EXR ({exc})") from None
    return np.asarray(rgb, dtype=np.float32)
