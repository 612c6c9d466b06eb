"""Content keys: canonical JSON hashing and seeds derived from keys (code versions:
pipeline/engine/codeversion.py)."""

from __future__ import annotations

import hashlib
import json
from typing import Any


def canonical_json(value: Any) -> str:
    """JSON with sorted keys and no whitespace: equal values give equal strings."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)


def digest(value: Any) -> str:
    """SHA-256 (hex) of the canonical JSON of ``value``."""
    return hashlib.sha256(canonical_json(value).encode()).hexdigest()


def seed_from_key(key: str) -> int:
    """A 64-bit generator seed determined by a (chunk) key."""
    return int(hashlib.sha256(f"seed:{key}".encode()).hexdigest()[:16], 16)
