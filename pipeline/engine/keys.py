"""Content keys: canonical JSON hashing, code versions and seeds derived from keys."""

from __future__ import annotations

import hashlib
import importlib.util
import json
from functools import cache
from pathlib import Path
from typing import Any

from pipeline.errors import PrtError


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values give equal strings."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def digest(value: Any) -> str:
    """SHA-256 (hex) of the canonical JSON of ``value``."""
    return hashlib.sha256(canonical_json(value).encode()).hexdigest()


def seed_from_key(key: str) -> int:
    """A 64-bit generator seed determined by a (chunk) key."""
    return int(hashlib.sha256(f"seed:{key}".encode()).hexdigest()[:16], 16)


@cache
def module_source_hash(module: str) -> str:
    """SHA-256 of a module's source file, found without importing the module itself."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        spec = None
    if spec is None or spec.origin is None:
        raise PrtError(None, f"stage implementation module {module!r} not found")
    return hashlib.sha256(Path(spec.origin).read_bytes()).hexdigest()
