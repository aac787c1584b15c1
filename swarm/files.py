"""Files other processes read while they are being written: always replaced whole, never seen half-written."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any


def write_atomic(path: Path, data: bytes) -> None:
    """Write to a hidden temp file beside `path`, then rename it over `path` (atomic on one file system)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")  # hidden: globs like *.patch never see it
    tmp.write_bytes(data)
    os.replace(tmp, path)


def write_json_atomic(path: Path, value: Any, indent: int | None = None) -> None:
    write_atomic(path, json.dumps(value, indent=indent).encode())
