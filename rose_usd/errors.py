"""The error hierarchy. Errors a user can fix carry the file and the fix, and print as one line.

The CLI prints any :class:`RoseError` as ``error: <where>: <what>. <fix>`` and exits 1; anything
else is a bug and prints a traceback (exit 2).
"""

from __future__ import annotations

import os


class RoseError(Exception):
    """Root of every error rose_usd raises on purpose.

    Args:
        message: what is wrong, one sentence without a trailing period.
        path: the file or folder concerned, if any.
        hint: what the user should do about it, one sentence.
    """

    def __init__(self, message: str, *, path: str | os.PathLike | None = None, hint: str | None = None):
        self.message = message
        self.path = None if path is None else os.fspath(path)
        self.hint = hint
        super().__init__(self.one_line())

    def __reduce__(self):
        # pickled whole (an isolated stage's error crosses to the parent process): the keyword
        # arguments are not in ``args``; attributes set on it come along as its state
        return (_rebuild, (type(self), self.message, self.path, self.hint), self.__dict__)

    def one_line(self) -> str:
        parts = []
        if self.path:
            parts.append(f"{self.path}: ")
        parts.append(self.message.rstrip("."))
        if self.hint:
            hint = self.hint.rstrip(".")
            parts.append(f". {hint}" + ("" if hint.endswith(("?", "!")) else "."))
        else:
            parts.append(".")
        return "".join(parts).replace("\n", " ")


class InputError(RoseError):
    """A case's input files are missing, unreadable or inconsistent."""


class ConfigError(RoseError):
    """A configuration value (rose.toml, command line) is invalid."""


class StageError(RoseError):
    """The USD stage is malformed: composition errors, layer ownership, missing prerequisites."""


class ValidationError(RoseError):
    """A written stage fails USD validation or does not load in Newton."""


class EnvironmentProblem(RoseError):
    """A system dependency (LLVM for Mitsuba, a library) is missing or broken."""


class MeshError(RoseError):
    """A mesh is unusable (empty, non-manifold where that matters, wrong units)."""


def _rebuild(cls: type, message: str, path: str | None, hint: str | None) -> RoseError:
    return cls(message, path=path, hint=hint)
