"""The one error type users see: a problem with a named file.

Every failure caused by input (scene files, meshes, artifacts, work directories) raises
:class:`PrtError`; the CLI prints it as one line ``error: <file>: <problem>`` and exits
with status 2. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class PrtError(Exception):
    """A user-facing error about ``path`` (a file, folder or artifact)."""

    def __init__(self, path: str | Path | None, problem: str) -> None:
        self.path = None if path is None else str(path)
        self.problem = problem
        super().__init__(self.one_line())

    def one_line(self) -> str:
        text = self.problem if self.path is None else f"{self.path}: {self.problem}"
        return " ".join(text.split())

    def __reduce__(self):  # keep (path, problem) and attributes across processes
        return (PrtError, (self.path, self.problem), self.__dict__)
