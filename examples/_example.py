"""What the example scripts share: their command line (a work directory, ``--out``) and
how they write a figure (matplotlib without a display, 120 dpi, a line saying where)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def parser(doc: str, out: str) -> argparse.ArgumentParser:
    """A parser described by the docstring's first line, with the positional
    ``workdir`` and ``--out`` (default ``out``)."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("workdir", type=Path, help="a scene's work directory (./.prt/<scene>)")
    ap.add_argument("--out", type=Path, default=Path(out), help="the PNG to write")
    return ap


def write_figure(fig: Any, out: Path, what: str) -> None:
    """Lay out (unless the figure has its own layout engine), save and close ``fig``;
    print where it went and ``what`` it shows."""
    if fig.get_layout_engine() is None:
        fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    print(f"wrote {out} ({what})")
