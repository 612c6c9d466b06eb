"""Reading the project's YAML files (scenes, stage files, schemas) strictly.

PyYAML's ``safe_load`` lets a repeated key silently replace the first (the last wins):
a scene with two ``camera:`` blocks, or a material with two ``specular:`` lines, would
bake something other than what its author reads first. :func:`load_yaml` refuses that,
naming the key and both lines.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import PrtError


class _DuplicateKey(yaml.YAMLError):
    def __init__(self, key: Any, line: int, first: int) -> None:
        super().__init__()
        self.message = f"line {line}: duplicate key {key!r} (first at line {first})"


class _StrictLoader(yaml.SafeLoader):
    """A SafeLoader whose mappings refuse a key given twice."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        first: dict[Any, int] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=True)
            line = key_node.start_mark.line + 1
            try:
                if key in first:
                    raise _DuplicateKey(key, line, first[key])
            except TypeError:  # an unhashable key; construct_mapping reports it
                continue
            first[key] = line
        return super().construct_mapping(node, deep)


def load_yaml(path: Path, text: str | None = None) -> Any:
    """The document of the YAML file ``path`` (or of ``text`` read from it); PrtError
    naming the file for malformed YAML (with line and column), a key repeated within one
    mapping, or a file that is not text."""
    try:
        text = path.read_text(encoding="utf-8") if text is None else text
        return yaml.load(text, Loader=_StrictLoader)
    except _DuplicateKey as exc:
        raise PrtError(path, exc.message) from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise PrtError(path, f"malformed YAML: {where}{problem}") from None
    except UnicodeDecodeError as exc:
        raw = exc.object[:exc.start]
        line = raw.count(b"\n") + 1
        column = exc.start - (raw.rfind(b"\n") + 1) + 1
        binary = b"\0" in exc.object[:4096]
        raise PrtError(path, "not a text file" if binary else
                       f"not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at line {line}, "
                       f"column {column}): save it as UTF-8") from None
