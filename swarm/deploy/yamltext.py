"""A small YAML writer for the compose file: block style, so a person can read and edit what was generated.

Why not PyYAML: it is not a dependency of the package, and the compose file is made of plain dicts, lists,
strings, numbers and booleans only. Every string that YAML could read as something else (a number, a YAML 1.1
boolean such as `no` or `on`, null, or anything with spaces or special characters) is written as a JSON string,
which is also a valid YAML double-quoted scalar; the tests read the output back with PyYAML (YAML 1.1, as
docker-compose does) and compare.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from typing import Any

_PLAIN = re.compile(r"[A-Za-z_./][A-Za-z0-9_./:=@+-]*")
_RESERVED = frozenset({"y", "n", "yes", "no", "on", "off", "true", "false", "null", "~"})


def scalar(value: Any) -> str:
    """One scalar as YAML text (never spans lines)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return json.dumps(value)
    if isinstance(value, str):
        plain = _PLAIN.fullmatch(value) and value.lower() not in _RESERVED and not value.endswith(":")
        return value if plain else json.dumps(value)
    raise TypeError(f"cannot write {type(value).__name__} as YAML")


def _is_block(value: Any) -> bool:
    return isinstance(value, (Mapping, list, tuple)) and len(value) > 0


def _lines(value: Any, indent: int) -> list[str]:
    pad = " " * indent
    out: list[str] = []
    if isinstance(value, Mapping):
        for key, item in value.items():
            if _is_block(item):
                out.append(f"{pad}{scalar(str(key))}:")
                # a list under a key sits at the key's indentation (the usual compose style)
                out.extend(_lines(item, indent if isinstance(item, (list, tuple)) else indent + 2))
            else:
                out.append(f"{pad}{scalar(str(key))}: {_inline(item)}")
        return out
    for item in value:
        if _is_block(item):
            inner = _lines(item, indent + 2)
            out.append(f"{pad}- {inner[0][indent + 2 :]}")
            out.extend(inner[1:])
        else:
            out.append(f"{pad}- {_inline(item)}")
    return out


def _inline(value: Any) -> str:
    if isinstance(value, Mapping):
        return "{}"
    if isinstance(value, (list, tuple)):
        return "[]"
    return scalar(value)


def dumps(data: Mapping[str, Any] | Sequence[Any], header: str = "") -> str:
    """The document as YAML text; `header` lines become comments at the top."""
    comments = [f"# {line}".rstrip() for line in header.splitlines()]
    return "\n".join([*comments, *_lines(data, 0)]) + "\n"
