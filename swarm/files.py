"""Files between processes: always replaced whole (never seen half-written), and typed.

Every status or summary file one process writes and another reads is a `FileModel`, written with `write_model`
and read with `read_model` through the same class, as bus messages are `WireMessage`s. Unknown keys are
refused (`extra="forbid"`): writer and reader are the same class of the same installed version, so an unknown
key is a typo or a file from another version, and both deserve an error rather than a silently ignored field.
A file that does not validate raises `FileFormatError`, one line naming the file, the model and the first
problem, instead of the reader quietly using a default.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from swarm.errors import SwarmError, validation_problem


class FileFormatError(SwarmError):
    """A file that exists but is not what its model says (not JSON, a missing key, a wrong type)."""


class FileModel(BaseModel):
    """Base of every file model: no unknown keys; validated on read, written as JSON."""

    model_config = ConfigDict(extra="forbid")


M = TypeVar("M", bound=FileModel)


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a hidden temp file beside `path`, then rename it over `path` (atomic on one file system)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # hidden: globs like *.patch never see it
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_model(path: Path, model: FileModel, indent: int | None = 2) -> None:
    """Write `model` as JSON to `path` atomically."""
    write_atomic(Path(path), model.model_dump_json(indent=indent).encode())


def read_model(path: Path, model: type[M]) -> M:
    """The file at `path` validated as `model`.

    FileNotFoundError (and other OSErrors) pass through untouched, so a reader polling for a file another
    process has not written yet keeps telling "not there yet" apart from "there and wrong" (FileFormatError).
    """
    data = Path(path).read_bytes()
    try:
        return model.model_validate_json(data)
    except ValidationError as exc:
        raise FileFormatError(f"{path}: not a valid {model.__name__}: {validation_problem(exc)}") from None
