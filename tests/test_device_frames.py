"""The same baked artifacts give the same frames on every working OpenCL implementation
here (PoCL, Intel's CPU runtime, a GPU), to float32 rounding: each method's tiny scene
baked once, its frames rendered by tests/device_frames.py in one process per
implementation (``PRT_CL_DEVICE``).

Tolerances, per pixel |a − b| ≤ rel·|b| + 1e-6·max|b| (the second term for near-black
pixels, where only absolute error is meaningful):

* direct, d2i, triple: rel = 1e-5. A pixel is a sum of at most a few hundred float32
  products; implementations may contract a·b + c into an FMA or not and vectorise the
  order of a sum differently, each term's rounding ≤ 2^-24 relative, so ~100 terms give
  ≤ 6e-6 of the sum's magnitude; their builtins (sqrt, exp, acos, atan2) are within the
  OpenCL full profile's 3–6 ulp of each other. Measured: ≤ 1.6e-7 (AMD EPYC, PoCL 3.0
  against Intel 2026.2).
* sg: rel = 1e-4. A lobe is exp(λ (μ·ω − 1)): the dot product's rounding (a few ulp of 1,
  ~2e-7) is multiplied by the sharpness λ (hundreds for glossy lobes) in the exponent.
  Measured: ≤ 1.3e-5.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from helpers import TESTS

RELATIVE = {"direct": 1e-5, "d2i": 1e-5, "d2i_gpu_layout": 1e-5, "triple": 1e-5, "sg": 1e-4}
PLATFORM = {"pocl": "Portable", "intel-cpu": "Intel", "nvidia": "NVIDIA"}  # PRT_CL_DEVICE


def working_implementations() -> list[str]:
    out = subprocess.run([sys.executable, "-m", "pipeline", "devices", "--json"],
                         capture_output=True, text=True, timeout=300,
                         env={k: v for k, v in os.environ.items() if k != "PRT_CL_DEVICE"})
    info = json.loads(out.stdout)
    return [d["implementation"] for d in info["devices"]
            if d["probe"]["ok"] and d["kind"] != "other" and d["implementation"] in PLATFORM]


def frames_on(implementation: str, work, out) -> dict[str, np.ndarray]:
    env = {**os.environ, "PRT_CL_DEVICE": PLATFORM[implementation]}
    subprocess.run([sys.executable, str(TESTS / "device_frames.py"), str(work), str(out)],
                   check=True, capture_output=True, env=env, timeout=900)
    data = np.load(out)
    assert str(data["impl"]) == implementation
    return {k: data[k] for k in data.files if k != "impl"}


def test_every_implementation_renders_the_same_frames(tmp_path):
    implementations = working_implementations()
    if len(implementations) < 2:
        pytest.skip(f"one working OpenCL implementation here ({implementations})")
    first, *others = implementations
    expected = frames_on(first, tmp_path / "work", tmp_path / f"{first}.npz")
    assert set(expected) == set(RELATIVE)
    for implementation in others:
        got = frames_on(implementation, tmp_path / "work", tmp_path / f"{implementation}.npz")
        for name, b in expected.items():
            a = got[name].astype(np.float64)
            b = b.astype(np.float64)
            assert np.isfinite(a).all() and b.max() > 0
            bound = RELATIVE[name] * np.abs(b) + 1e-6 * np.abs(b).max()
            worst = float(np.max(np.abs(a - b) - bound))
            assert worst <= 0, f"{name}: {implementation} against {first}, {worst:.3g} over"
