"""The compose file's YAML writer: whatever it writes, PyYAML (YAML 1.1, as docker-compose) reads back the same."""

from __future__ import annotations

import pytest

from swarm.deploy import yamltext
from tests.deploy.parser import read_yaml

TRICKY = [
    "yes",
    "No",
    "on",
    "OFF",
    "y",
    "n",
    "true",
    "null",
    "~",
    "",
    " ",
    "1",
    "1.5",
    "0x1f",
    "1e3",
    "10.77.1.11",
    "1s",
    "-c",
    "--config",
    "- item",
    "a: b",
    "a:b",
    "key:",
    "#comment",
    "x #y",
    "'quoted'",
    '"double"',
    "tab\there",
    "line\nbreak",
    "ünïcode",
    "*alias",
    "&anchor",
    "!tag",
    "%percent",
    "@at",
    "`tick`",
    "{}",
    "[]",
    "a, b",
    "./config:/etc/swarm:ro",
    "/etc/swarm/agent-1.toml",
    "udpout://10.77.2.2:14580",
    "$VAR",
]


@pytest.mark.sim
def test_tricky_strings_read_back_unchanged() -> None:
    doc = {"strings": TRICKY, "keys": {s: s for s in TRICKY if s}}
    assert read_yaml(yamltext.dumps(doc)) == doc


@pytest.mark.sim
def test_nesting_numbers_booleans_and_empties() -> None:
    doc = {
        "a": {"b": {"c": [1, 2.5, -3, True, False, None]}},
        "list_of_maps": [{"x": 1, "y": [{"z": "deep"}]}, {"w": {}}],
        "list_of_lists": [[1, 2], [], ["a"]],
        "empty_map": {},
        "empty_list": [],
    }
    assert read_yaml(yamltext.dumps(doc)) == doc


@pytest.mark.sim
def test_header_is_comments_only() -> None:
    text = yamltext.dumps({"k": "v"}, header="first line\nsecond")
    assert text.startswith("# first line\n# second\n")
    assert read_yaml(text) == {"k": "v"}


def test_plain_where_safe_quoted_otherwise() -> None:
    assert yamltext.scalar("swarm-agent") == "swarm-agent"
    assert yamltext.scalar("/etc/swarm/sim.toml") == "/etc/swarm/sim.toml"
    assert yamltext.scalar("no") == '"no"'  # a YAML 1.1 boolean
    assert yamltext.scalar("10.77.1.11") == '"10.77.1.11"'
