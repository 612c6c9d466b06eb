"""Make tests/ importable (for tests.helpers and the toy stages) and find toy schemas."""

from __future__ import annotations

import os
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent
sys.path.insert(0, str(TESTS))
os.environ["PRT_SCHEMA_PATH"] = str(TESTS / "toy" / "schema")
os.environ["PYTHONPATH"] = os.pathsep.join(
    p for p in (str(TESTS), os.environ.get("PYTHONPATH", "")) if p)
