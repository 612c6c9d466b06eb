"""``python -m pipeline`` is ``prt``."""

from pipeline.cli import main

main()
