"""A chunk: one independent unit of a stage's work (see pipeline/engine/chunking.py for how
stages are cut into chunks). Kept apart so that stage modules, which receive chunks,
import nothing of the planning machinery: their code versions stay small."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Chunk:
    """One unit of a stage's work. ``id`` is stable across runs and names the chunk in
    records; ``kind`` is the stage's chunking; ``coords`` holds its coordinates as
    sorted (name, value) pairs (values are str, int or tuples of them)."""

    id: str
    kind: str = "none"
    coords: tuple[tuple[str, Any], ...] = ()

    def get(self, name: str) -> Any:
        """A coordinate, or None if the chunk has none of that name."""
        return dict(self.coords).get(name)

    @property
    def object(self) -> str | None:
        return self.get("object")

    @property
    def material(self) -> str | None:
        return self.get("material")

    @property
    def materials(self) -> tuple[str, ...] | None:
        """The scene materials this chunk reads (its own, or those its pixels see)."""
        own = self.get("material")
        return (own,) if own is not None else self.get("materials")

    @property
    def index(self) -> int | None:
        """The position of an object or material chunk in the scene's order."""
        return self.get("index")

    @property
    def region(self) -> tuple[int, int, int, int] | None:
        return self.get("region")

    @property
    def span(self) -> tuple[int, int] | None:
        return self.get("span")


def make_chunk(chunk_id: str, kind: str, **coords: Any) -> Chunk:
    return Chunk(chunk_id, kind, tuple(sorted(coords.items())))


ALL = Chunk("all")
