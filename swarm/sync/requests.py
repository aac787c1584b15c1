"""The selector of a pull request: which patches, and who asks.

``swarm/<m>/agent/<holder>/store?ids=<p>.<e>.<s>,<p>.<e>.<s>;from=<requester>``. Parameters arrive from any
peer, so `parse_request` accepts only canonical decimal ids, at most `MAX_IDS_PER_REQUEST` of them, and raises
ValueError on anything else.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

from swarm.bus.keys import check_agent_id
from swarm.patches.patch import PatchId

MAX_IDS_PER_REQUEST = 64
_NUMBER = r"(0|[1-9][0-9]{0,18})"
_ID_RE = re.compile(rf"^{_NUMBER}\.{_NUMBER}\.{_NUMBER}$")
_MAX_COUNTER = 2**63 - 1


def request_parameters(ids: Iterable[PatchId], requester: int) -> str:
    """``ids=...;from=...`` for a selector."""
    text = ",".join(f"{pid.producer}.{pid.epoch}.{pid.seq}" for pid in ids)
    return f"ids={text};from={requester}"


def parse_request(parameters: Mapping[str, str]) -> tuple[list[PatchId], int | None]:
    """(the ids asked for, in order and without repeats; the requester's id, or None if not given)."""
    raw = parameters.get("ids")
    if not isinstance(raw, str) or not raw:
        raise ValueError("no ids")
    parts = raw.split(",")
    if len(parts) > MAX_IDS_PER_REQUEST:
        raise ValueError(f"more than {MAX_IDS_PER_REQUEST} ids")
    ids: list[PatchId] = []
    for part in parts:
        match = _ID_RE.fullmatch(part)  # (match: `$` also matches before a trailing newline)
        if match is None:
            raise ValueError(f"bad patch id {part[:40]!r}")
        producer, epoch, seq = (int(g) for g in match.groups())
        if max(epoch, seq) > _MAX_COUNTER:
            raise ValueError(f"patch id {part[:40]!r} out of range")
        pid = PatchId(check_agent_id(producer), epoch, seq)
        if pid not in ids:
            ids.append(pid)
    requester: int | None = None
    if "from" in parameters:
        text = parameters["from"]
        if not isinstance(text, str) or not re.fullmatch(r"[1-9][0-9]{0,2}", text):
            raise ValueError("bad requester")
        requester = check_agent_id(int(text))
    return ids, requester
