"""prt view's tone map by table against the float64 curve it replaces, exhaustively.

Run from the project root:  python studies/tone_map_table_exhaustive.py [EV ...]
(default exposures 0 -1.7 2.3; about 20–80 s each on one core). For each exposure:
every positive float32 bit pattern from 0 up to one bucket past saturation
(x · 2^EV ≥ 1: every larger value maps to 255 in both), and 10^7 random bit patterns of
every sign (NaN left out: no frame holds one), through pipeline/view/encode.py
``tone_map`` (the table) and ``tone_map_reference`` (the previews' float64 curve);
prints how many differ (decision 0043's addendum: none).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from pipeline.view.encode import tone_map, tone_map_reference


def main(exposures: list[float]) -> None:
    rng = np.random.default_rng(1)
    for ev in exposures:
        t0 = time.time()
        top = int(np.array([2.0 ** -ev], np.float32).view(np.uint32)[0]) + (1 << 16)
        chunk = 1 << 23
        bad = 0
        for start in range(0, top, chunk):
            bits = np.arange(start, min(start + chunk, top), dtype=np.uint32)
            x = bits.view(np.float32)
            bad += int(np.count_nonzero(tone_map(x, ev) != tone_map_reference(x, ev)))
        bits = rng.integers(0, 2**32, 10_000_000, dtype=np.uint64).astype(np.uint32)
        x = bits.view(np.float32)
        x = x[~np.isnan(x)]
        with np.errstate(over="ignore", invalid="ignore"):
            bad_random = int(np.count_nonzero(tone_map(x, ev) != tone_map_reference(x, ev)))
        print(f"exposure {ev}: {top} patterns from 0, {bad} differ; {len(x)} random "
              f"patterns, {bad_random} differ ({time.time() - t0:.0f} s)", flush=True)


if __name__ == "__main__":
    main([float(a) for a in sys.argv[1:]] or [0.0, -1.7, 2.3])
