"""`LinkProfile`: what to do to a link (loss, cut, rate; delay and jitter declared but not applied here).

The nftables backend can drop packets (probabilistic loss, cuts) and tbf can limit a node's rate, but nothing
here can delay packets: that needs the `sch_netem` qdisc (absent from this project's CI kernel) or a userspace
link emulator. A profile asking for delay or jitter is therefore refused with `NetemUnavailable`, never applied
partially: an experiment must not believe it ran with an impairment that was not there.
"""

from __future__ import annotations

import gzip
import os
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from swarm.netem.commands import NetemUnavailable


class LinkProfile(BaseModel):
    """An impairment of a link, applied in both directions. The default profile is a clean link."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    loss: float = Field(0.0, ge=0.0, le=1.0, description="probability that a frame is dropped, each direction")
    cut: bool = Field(False, description="drop everything (overrides loss)")
    delay_ms: float = Field(0.0, ge=0.0, description="one-way delay; needs sch_netem (not applied here)")
    jitter_ms: float = Field(0.0, ge=0.0, description="delay variation; needs sch_netem (not applied here)")
    rate_kbit: int = Field(0, ge=0, description="rate limit in kbit/s per direction (tbf), 0 = unlimited")

    @property
    def is_clean(self) -> bool:
        return not self.cut and self.loss == 0.0 and self.rate_kbit == 0 and not self.needs_netem

    @property
    def needs_netem(self) -> bool:
        return self.delay_ms > 0.0 or self.jitter_ms > 0.0

    @property
    def drops(self) -> bool:
        """Whether this profile adds a drop rule (a cut or a non-zero loss)."""
        return self.cut or self.loss > 0.0

    def describe(self) -> str:
        parts = ["cut"] if self.cut else ([f"loss {self.loss:g}"] if self.loss else [])
        if self.rate_kbit:
            parts.append(f"rate {self.rate_kbit} kbit")
        return ", ".join(parts) or "clean"


def kernel_has_netem() -> bool | None:
    """Whether the running kernel offers sch_netem (loaded, built in, or as a module); None when unknown."""
    if Path("/sys/module/sch_netem").exists():
        return True
    try:
        config = gzip.decompress(Path("/proc/config.gz").read_bytes()).decode(errors="replace")
    except OSError:
        return None
    if "CONFIG_NET_SCH_NETEM=y" in config:
        return True
    if "CONFIG_NET_SCH_NETEM=m" in config:
        return any(Path("/lib/modules", os.uname().release).rglob("sch_netem.ko*"))
    return False


def refuse_delay(profile: LinkProfile) -> None:
    """NetemUnavailable (one line) if the profile asks for delay or jitter, which this backend cannot apply."""
    if not profile.needs_netem:
        return
    has_netem = kernel_has_netem()
    if has_netem is False:
        why = "they need sch_netem, which this kernel lacks"
    elif has_netem:
        why = "they need sch_netem, which swarm.netem does not drive yet"
    else:
        why = "they need sch_netem, and this kernel's support for it is unknown"
    raise NetemUnavailable(
        f"delay/jitter ({profile.delay_ms:g} ms / {profile.jitter_ms:g} ms) cannot be applied: {why}; "
        "only loss, cut and rate are available"
    )
