"""Image files: linear RGB to OpenEXR, sRGB-encoded PNG previews, EXR and Radiance HDR
reading (heat maps with a colour bar: pipeline/evaluation/charts.py).

Images are (height, width, 3) float32 arrays of linear radiance, row 0 at the top.
Files are written to a temporary name and renamed, so a killed run never leaves a
truncated frame.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from pipeline.errors import PrtError


def srgb_encode(linear: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """sRGB-encoded values in [0, 1] (float64) of linear ``linear`` × ``exposure``: the
    sRGB transfer function (IEC 61966-2-1) of the values clipped to [0, 1]. The PNG
    previews and the PSNR metric (pipeline/evaluation/metrics.py) both use it."""
    x = np.clip(np.asarray(linear, np.float64) * exposure, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def _temporary(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


def check_writable(path: str | Path) -> None:
    """PrtError naming ``path`` unless an image can be written there: its folder exists
    (or is made now) and a file can be created in it. Called before any work, so that a
    read-only output folder is reported before a bake, not after."""
    path = Path(path)
    blocking = next((a for a in path.parents if a.exists() and not a.is_dir()), None)
    if blocking is not None:
        raise PrtError(path, f"cannot write an image here: {blocking} is a file, not a folder")
    if path.is_dir():
        raise PrtError(path, "cannot write an image here: a folder of that name exists")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        probe = _temporary(path)
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise PrtError(path, f"cannot write an image here ({exc.strerror or exc})") from None


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
    except RuntimeError as exc:  # OpenEXR's error for a file it cannot create
        raise PrtError(path, f"cannot write image ({exc})") from None


def write_png(path: str | Path, rgb: np.ndarray, exposure: float = 1.0) -> None:
    """Write an 8-bit sRGB preview of linear ``rgb`` × ``exposure``."""
    from PIL import Image

    path = Path(path)
    encoded = np.round(srgb_encode(rgb, exposure) * 255.0)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _temporary(path)
        Image.fromarray(encoded.astype(np.uint8), "RGB").save(tmp, format="PNG")
        os.replace(tmp, path)
    except OSError as exc:
        raise PrtError(path, f"cannot write image ({exc.strerror or exc})") from None


PREVIEW_GREY = 0.18  # the display value a preview's mean luminance is brought to


def exposure_note(rgb: np.ndarray, exposure: float) -> str | None:
    """A note when the PNG preview of linear ``rgb`` × 2^``exposure`` is far below the
    display range — mean luminance under 1/16 of middle grey (:data:`PREVIEW_GREY`), so
    that an sRGB preview is nearly black — saying which ``--exposure`` brings the mean to
    middle grey without pushing more than 1 % of the pixels past white; or that the frame
    is black. None when the preview is readable."""
    from pipeline.math.envmap import LUMINANCE

    luminance = np.asarray(rgb, np.float64).reshape(-1, 3) @ np.asarray(LUMINANCE)
    mean = float(luminance.mean()) if luminance.size else 0.0
    if mean <= 0.0:
        return "the frame is black (no pixel has any light)"
    better = readable_exposure(rgb, exposure)
    if better is None:
        return None
    return (f"the preview is dark (mean luminance {mean * 2.0 ** exposure:.2g} at "
            f"{exposure:+g} EV): --exposure {better} shows it")


def readable_exposure(rgb: np.ndarray, exposure: float = 0.0) -> int | None:
    """The ``--exposure`` (whole stops) that :func:`exposure_note` suggests for a dark
    preview of linear ``rgb`` × 2^``exposure``; None when it is readable, or black."""
    from pipeline.math.envmap import LUMINANCE

    luminance = np.asarray(rgb, np.float64).reshape(-1, 3) @ np.asarray(LUMINANCE)
    mean = float(luminance.mean()) if luminance.size else 0.0
    if mean <= 0.0 or mean * 2.0 ** exposure >= PREVIEW_GREY / 16:
        return None
    bright = float(np.percentile(luminance, 99))
    stops = min(math.log2(PREVIEW_GREY / mean), math.log2(1.0 / bright) if bright > 0
                else math.inf)
    return max(math.floor(stops), math.ceil(exposure) + 1)

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


def read_hdr(path: str | Path) -> np.ndarray:
    """Read a Radiance RGBE (.hdr) image as (height, width, 3) float32 (``-Y H +X W``
    orientation, flat or new-style run-length encoded scanlines)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PrtError(path, f"cannot read image ({exc.strerror or exc})") from None
    if not data.startswith((b"#?RADIANCE", b"#?RGBE")):
        raise PrtError(path, "not a Radiance HDR file (no #?RADIANCE header)")
    end = data.find(b"\n\n")
    line_end = data.find(b"\n", end + 2)
    if end < 0 or line_end < 0:
        raise PrtError(path, "truncated Radiance HDR header")
    if b"FORMAT=32-bit_rle_rgbe" not in data[:end]:
        raise PrtError(path, "unsupported Radiance HDR format (expected 32-bit_rle_rgbe)")
    size = data[end + 2:line_end].split()
    if len(size) != 4 or size[0] != b"-Y" or size[2] != b"+X":
        raise PrtError(path, f"unsupported HDR orientation {data[end + 2:line_end]!r}")
    height, width = int(size[1]), int(size[3])
    raw = np.frombuffer(data, np.uint8, offset=line_end + 1)
    rgbe = np.empty((height, width, 4), np.uint8)
    pos = 0
    try:
        for row in range(height):
            pos = _read_scanline(raw, pos, rgbe[row])
    except (IndexError, ValueError):
        raise PrtError(path, f"truncated or corrupt pixel data (scanline {row})") from None
    exponent = np.where(rgbe[..., 3] > 0, np.ldexp(1.0, rgbe[..., 3].astype(int) - 136), 0.0)
    return (rgbe[..., :3] * exponent[..., None]).astype(np.float32)


def _read_scanline(raw: np.ndarray, pos: int, out: np.ndarray) -> int:
    """Decode one scanline of ``out`` (width, 4) from ``raw`` at ``pos``; returns the new
    position."""
    width = len(out)
    rle = (8 <= width < 32768 and raw[pos] == 2 and raw[pos + 1] == 2
           and (int(raw[pos + 2]) << 8 | int(raw[pos + 3])) == width)
    if not rle:
        out[:] = raw[pos:pos + 4 * width].reshape(width, 4)
        return pos + 4 * width
    pos += 4
    for channel in range(4):
        x = 0
        while x < width:
            count = int(raw[pos])
            if count > 128:
                count -= 128
                out[x:x + count, channel] = raw[pos + 1]
                pos += 2
            else:
                if count == 0:
                    raise ValueError("zero-length run")
                out[x:x + count, channel] = raw[pos + 1:pos + 1 + count]
                pos += 1 + count
            x += count
    return pos


def read_image(path: str | Path) -> np.ndarray:
    """Read an EXR or Radiance HDR image as (height, width, 3) float32 linear RGB."""
    if Path(path).suffix.lower() == ".hdr":
        return read_hdr(path)
    return read_exr(path)


LARGEST_RADIANCE = 1e18
"""The largest environment texel accepted. Method triple selects a map's wavelet
coefficients by their float32 energies, whose sum is ∫ f² dω ≤ 4π M² for texels ≤ M:
finite only for M ≤ √(3.4e38 / 4π) ≈ 5e18; above that every row's energy is +inf."""


def read_environment(path: str | Path) -> np.ndarray:
    """An environment map: a latitude-longitude image (width = 2 × height), (height,
    width, 3) float32 linear radiance, every texel finite, non-negative and at most
    :data:`LARGEST_RADIANCE`. Raise
    PrtError naming the file and the first offending texel otherwise: a NaN, Inf or
    negative texel would light a whole scene with garbage."""
    if Path(path).suffix.lower() not in (".exr", ".hdr"):
        raise PrtError(path, "an environment map must be an OpenEXR (.exr) or Radiance "
                       "(.hdr) file of linear radiance (PNG or JPEG hold display values)")
    rgb = read_image(path)
    height, width = rgb.shape[:2]
    if width != 2 * height:
        raise PrtError(path, f"environment map is {width}x{height}: a latitude-longitude "
                       "map is twice as wide as it is high")
    if height < 2:
        raise PrtError(path, f"environment map is {width}x{height}: a latitude-longitude "
                       "map has at least 2 rows (its rows run from pole to pole)")
    for bad, what, hint in (
            (~np.isfinite(rgb), "not finite", ""), (rgb < 0, "negative", ""),
            (rgb > LARGEST_RADIANCE, f"above {LARGEST_RADIANCE:g}",
             ": beyond what float32 transport holds; scale the map down (and the preview up "
             "with --exposure)")):
        if bad.any():
            y, x, c = (int(i) for i in np.argwhere(bad)[0])
            raise PrtError(path, f"environment map texel (x {x}, y {y}) is {what} "
                           f"({rgb[y, x, c]:g} in channel {'RGB'[c]}; {int(bad.sum())} values "
                           f"in all){hint}")
    return rgb


def read_texture(path: str | Path) -> np.ndarray:
    """A scalar texture (height, width) float64 from a PNG or EXR file: 8- and 16-bit
    PNG values are read as linear fractions of their maximum (255, 65535; no sRGB
    decoding: masks and heights are data), EXR values as stored; colour images give the
    mean of R, G, B (alpha ignored). Raise PrtError naming the file when it cannot be
    read, is not PNG/EXR, or holds a NaN or Inf."""
    suffix = Path(path).suffix.lower()
    if suffix == ".exr":
        values = read_exr(path).astype(np.float64).mean(axis=2)
    elif suffix == ".png":
        from PIL import Image

        try:
            with Image.open(path) as image:
                image.load()
                pixels = np.asarray(image)
                mode = image.mode
        except Exception as exc:
            raise PrtError(path, f"cannot read PNG ({exc})") from None
        full = 255.0 if pixels.dtype == np.uint8 else 65535.0
        if mode not in ("L", "LA", "RGB", "RGBA", "I", "I;16", "I;16B"):
            raise PrtError(path, f"PNG mode {mode!r}: expected grey or RGB(A) values "
                           "(a palette image is not a texture of values)")
        pixels = pixels.astype(np.float64) / full
        if pixels.ndim == 3:
            pixels = pixels[..., :3].mean(axis=2) if pixels.shape[2] >= 3 else pixels[..., 0]
        values = pixels
    else:
        raise PrtError(path, f"texture file type {suffix or '(none)'!r}: expected .png or "
                       ".exr")
    if values.ndim != 2 or min(values.shape) < 1:
        raise PrtError(path, f"texture of shape {values.shape}: expected an image")
    bad = ~np.isfinite(values)
    if bad.any():
        y, x = (int(i) for i in np.argwhere(bad)[0])
        raise PrtError(path, f"texture texel (x {x}, y {y}) is not finite ({int(bad.sum())} "
                       "in all)")
    return values
