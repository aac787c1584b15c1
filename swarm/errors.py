"""Errors meant for a person: each message is one line, and the CLI prints it and exits non-zero."""

from __future__ import annotations

from pydantic import ValidationError


class SwarmError(Exception):
    """Base of every user-facing error (bad input, unusable world, port in use...)."""


class WorldError(SwarmError):
    """A world that cannot be loaded or used (unknown name, unreadable or empty mesh, bad start point)."""


class PortInUseError(SwarmError):
    """A UDP/TCP port the swarm needs is already taken by another process."""


class BusError(SwarmError):
    """The Zenoh session cannot be opened or used."""


def validation_problem(
    exc: ValidationError, *, echo_input: bool = True, unknown: str = "unknown field", nowhere: str = ""
) -> str:
    """The first problem pydantic found, as one line a person reads: where (``event[1].loss``), and what.

    `echo_input` appends the offending value (``(got 7)``); leave it off for hostile input (network messages),
    whose values must not reach a log. An unknown key reads as `unknown`; an error at the top is placed at
    `nowhere`. pydantic's "Value error, " prefix is dropped, and the message is folded onto one line.
    """
    first = exc.errors(include_url=False, include_input=echo_input)[0]
    if first["type"] == "json_invalid":
        return f"not JSON ({' '.join(str(first['msg']).split())})"
    message = unknown if first["type"] == "extra_forbidden" else str(first["msg"]).removeprefix("Value error, ")
    given = first.get("input")
    if echo_input and first["type"] != "missing" and given is not None and not isinstance(given, dict):
        shown = repr(given)
        message += f" (got {shown if len(shown) <= 60 else shown[:57] + '...'})"
    message = " ".join(message.split())
    where = _location(first["loc"]) or nowhere
    return f"{where}: {message}" if where else message


def _location(loc: tuple[int | str, ...]) -> str:
    """("event", 1, "loss") -> "event[1].loss"."""
    text = ""
    for part in loc:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else part
    return text
