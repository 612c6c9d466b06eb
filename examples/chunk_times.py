"""Example (pipeline.engine.inspect): the per-chunk bake times of one stage, as a bar chart.

    python examples/chunk_times.py WORKDIR STAGE [--out chunk_times.png]

WORKDIR a scene's work directory (``./.prt/<scene>``), STAGE an artifact in it (``prt
inspect WORKDIR`` lists them, e.g. ``sg.fit`` or ``d2i.transfer``). Reads only the
artifact's provenance record (``ds.attrs["prt"]["chunk_seconds"]``): one bar per chunk
in the stage's chunk order, seconds of one core; the title gives the stage's wall-clock
seconds and the chunks' sum (their ratio: how well the workers were kept busy).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
from _example import parser, write_figure

from pipeline.engine import inspect


def chunk_times_figure(workdir: Path, stage: str, out: Path) -> dict[str, float]:
    """Write the chart of ``stage``'s chunk seconds to ``out``; return them by chunk."""
    record = inspect.open_workdir(workdir).dataset(stage).attrs["prt"]
    order = record.get("chunks") or sorted(record["chunk_seconds"])
    seconds = {c: float(record["chunk_seconds"][c]) for c in order
               if c in record["chunk_seconds"]}
    fig, ax = plt.subplots(figsize=(max(4.0, 0.12 * len(seconds) + 2), 3.5))
    ax.bar(range(len(seconds)), list(seconds.values()), color="tab:blue")
    ax.set_xlabel(f"chunk (stage order; {len(seconds)} chunks)")
    ax.set_ylabel("seconds (one core)")
    ax.set_title(f"{stage}: {record.get('seconds', 0):.1f} s wall, "
                 f"{sum(seconds.values()):.1f} s summed over chunks")
    write_figure(fig, out, f"{len(seconds)} chunks")
    return seconds


def main() -> None:
    ap = parser(__doc__, "chunk_times.png")
    ap.add_argument("stage", help="an artifact of the work directory, e.g. sg.fit")
    args = ap.parse_args()
    chunk_times_figure(args.workdir, args.stage, args.out)


if __name__ == "__main__":
    main()
