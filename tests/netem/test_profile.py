"""LinkProfile validation and the impairments refused before anything is touched (no root needed)."""

from __future__ import annotations

import pydantic
import pytest

from swarm.errors import SwarmError
from swarm.netem import LinkProfile, NetemUnavailable, SwarmNetwork
from swarm.netem.commands import run, tool
from swarm.netem.impair import Impairments, ruleset
from swarm.netem.topology import NetworkLayout


@pytest.mark.parametrize(
    "fields",
    [{"loss": 1.5}, {"loss": -0.1}, {"rate_kbit": -1}, {"delay_ms": -5.0}, {"jitter_ms": -1.0}, {"loss_pct": 30}],
)
def test_invalid_profiles_are_rejected(fields: dict[str, float]) -> None:
    with pytest.raises(pydantic.ValidationError):
        LinkProfile(**fields)


def test_profile_is_frozen_and_describes_itself() -> None:
    profile = LinkProfile(loss=0.3)
    with pytest.raises(pydantic.ValidationError):
        profile.loss = 0.5  # type: ignore[misc]
    assert profile.describe() == "loss 0.3"
    assert LinkProfile(cut=True, loss=0.2).describe() == "cut"
    assert LinkProfile().is_clean and LinkProfile().describe() == "clean"
    assert LinkProfile(loss=1.0).drops and not LinkProfile(rate_kbit=100).drops


@pytest.mark.parametrize("profile", [LinkProfile(delay_ms=20.0), LinkProfile(loss=0.1, jitter_ms=5.0)])
def test_delay_and_jitter_are_refused_in_one_line(profile: LinkProfile) -> None:
    net = SwarmNetwork(nodes=2)  # never brought up: the refusal comes before any command
    for impair in (
        lambda: net.impair_pair(1, 2, profile),
        lambda: net.impair_node(1, profile),
        lambda: net.impair_all(profile),
    ):
        with pytest.raises(NetemUnavailable) as info:
            impair()
        message = str(info.value)
        assert "\n" not in message and "delay/jitter" in message and "sch_netem" in message
        assert isinstance(info.value, SwarmError)
    assert net.applied() == Impairments()


def test_pair_rate_is_refused_not_ignored() -> None:
    with pytest.raises(NetemUnavailable, match="per-pair rate"):
        SwarmNetwork(nodes=2).impair_pair(1, 2, LinkProfile(rate_kbit=1000))


def test_bad_node_ids() -> None:
    net = SwarmNetwork(nodes=3)
    with pytest.raises(ValueError, match="node 4 does not exist"):
        net.impair_node(4, LinkProfile(loss=0.1))
    with pytest.raises(ValueError, match="two different nodes"):
        net.cut_pair(2, 2)
    with pytest.raises(ValueError):
        SwarmNetwork(nodes=0)


def test_ruleset_text() -> None:
    layout = NetworkLayout(tag="5b03", pid=42, nodes=3)
    imp = Impairments(
        all=LinkProfile(loss=0.05), nodes={3: LinkProfile(cut=True)}, pairs={(1, 2): LinkProfile(loss=0.3)}
    )
    text = ruleset(layout, imp)
    assert text.startswith("table bridge swimp\ndelete table bridge swimp\ntable bridge swimp {\n")
    assert "chain links {" in text  # not "fwd": a reserved word in nft
    assert 'numgen random mod 1000000 < 50000 counter drop comment "all: loss 0.05"' in text
    assert 'iifname "v3" counter drop comment "node 3: cut"' in text
    assert 'oifname "v3" counter drop comment "node 3: cut"' in text
    assert 'iifname "v1" oifname "v2" numgen random mod 1000000 < 300000 counter drop' in text
    assert 'iifname "v2" oifname "v1" numgen random mod 1000000 < 300000 counter drop' in text
    assert layout.address(2) == "10.91.3.12" and layout.subnet == "10.91.3.0/24"
    assert layout.namespace(2) == "swn-5b03-42-n2" and layout.hub == "swn-5b03-42-hub"


@pytest.mark.netns
def test_missing_tool_and_failing_command_are_one_line() -> None:
    with pytest.raises(NetemUnavailable, match="'no-such-tool-x' command is missing"):
        tool("no-such-tool-x")
    with pytest.raises(NetemUnavailable) as info:
        run(["ip", "link", "show", "dev", "swn-nope0"])
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("'ip link show dev swn-nope0' failed: ") and "swn-nope0" in message.split("failed:")[1]
