"""`swarm deploy netem` (swarm/deploy/radio.py): which interface is the radio, the exact commands, the errors.

The commands are also run for real in a throwaway network namespace: tc must parse every one of them (exit 1
is tc's usage error; 2 is the kernel refusing, e.g. this kernel lacks sch_netem). A kernel without sch_netem
must give one clear line; with it, the qdiscs must be in place.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator

import pytest

from swarm.config import ConfigError
from swarm.deploy import radio
from swarm.deploy.radio import NFT_TABLE, apply_radio_netem, check_values, find_interface, netem_commands
from swarm.netem import commands
from swarm.netem.commands import NetemUnavailable, tool
from swarm.netem.profile import kernel_has_netem

# `ip -j addr` inside an agent container: Docker decides which of the two networks is eth0
IP_ADDR = [
    {
        "ifindex": 1,
        "ifname": "lo",
        "addr_info": [
            {"family": "inet", "local": "127.0.0.1", "prefixlen": 8},
            {"family": "inet6", "local": "::1", "prefixlen": 128},
        ],
    },
    {
        "ifindex": 40,
        "ifname": "eth0",
        "link_index": 41,
        "addr_info": [{"family": "inet", "local": "10.77.2.12", "prefixlen": 24}],
    },
    {
        "ifindex": 42,
        "ifname": "eth1",
        "link_index": 43,
        "addr_info": [
            {"family": "inet", "local": "10.77.1.12", "prefixlen": 24},
            {"family": "inet6", "local": "fd00:77::12", "prefixlen": 64},
        ],
    },
    {"ifindex": 44, "ifname": "tunl0", "addr_info": []},
]


def test_the_radio_is_found_by_its_address() -> None:
    assert find_interface("10.77.1.12", IP_ADDR) == "eth1"
    assert find_interface("10.77.2.12", IP_ADDR) == "eth0"
    assert find_interface("fd00:0077:0::12", IP_ADDR) == "eth1"  # compared as addresses, not as text


def test_an_address_nobody_holds_is_one_line_naming_what_exists() -> None:
    with pytest.raises(NetemUnavailable) as info:
        find_interface("10.77.1.13", IP_ADDR)
    message = str(info.value)
    assert "\n" not in message and "10.77.1.13" in message and "eth1 10.77.1.12" in message


def test_clean_radio_is_no_command_at_all() -> None:
    assert netem_commands("eth1", 0.0) == []


def test_loss_commands() -> None:
    assert netem_commands("eth1", 0.3) == [
        ["ip", "link", "set", "dev", "eth1", "gso_max_segs", "1", "gso_max_size", "1500"],
        ["tc", "qdisc", "replace", "dev", "eth1", "root", "handle", "1:", "prio", "bands", "4"],
        ["tc", "qdisc", "replace", "dev", "eth1", "parent", "1:4", "handle", "40:", "netem", "loss", "30%"],
        "tc filter add dev eth1 parent 1: protocol ip prio 1 u32 match ip dst 0.0.0.0/0 flowid 1:4".split(),
    ]


def test_delay_jitter_and_small_losses() -> None:
    netem = netem_commands("eth0", 0.001, delay_ms=20, jitter_ms=5)[2]
    assert netem[netem.index("netem") :] == ["netem", "loss", "0.1%", "delay", "20ms", "5ms"]
    netem = netem_commands("eth0", 0.0, delay_ms=12.5)[2]
    assert netem[netem.index("netem") :] == ["netem", "delay", "12.5ms"]


@pytest.mark.parametrize(
    ("address", "loss", "delay", "jitter", "words"),
    [
        ("10.77.1.300", 0.1, 0, 0, "--address"),
        ("radio", 0.1, 0, 0, "--address"),
        ("10.77.1.11", 1.5, 0, 0, "--loss"),
        ("10.77.1.11", -0.1, 0, 0, "--loss"),
        ("10.77.1.11", 0.1, -1, 0, "--delay-ms"),
        ("10.77.1.11", 0.1, 0, 5, "--jitter-ms"),
    ],
)
def test_bad_values_are_one_line(address: str, loss: float, delay: float, jitter: float, words: str) -> None:
    with pytest.raises(ConfigError) as info:
        check_values(address, loss, delay, jitter)
    assert "\n" not in str(info.value) and words in str(info.value)


def test_loss_zero_runs_nothing(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def no_commands(*args: object, **kwargs: object) -> None:
        raise AssertionError("a clean radio must not run any command")

    monkeypatch.setattr(commands.subprocess, "run", no_commands)  # every command goes through commands.run
    assert apply_radio_netem("10.77.1.99", 0.0) == ("", [])  # not even looked up: no such address here
    assert radio.deploy_netem_command("10.77.1.99", 0.0, 0.0, 0.0) == 0
    assert "nothing applied" in capsys.readouterr().out


def test_commands_are_run_on_the_interface_found(monkeypatch: pytest.MonkeyPatch) -> None:
    ran: list[list[str]] = []
    monkeypatch.setattr(radio, "interface_of", lambda address: find_interface(address, IP_ADDR))
    monkeypatch.setattr(radio, "_run", lambda argv, doing: ran.append(argv) or "")
    ifname, shown = apply_radio_netem("10.77.1.12", 0.25)
    assert ifname == "eth1" and ran == netem_commands("eth1", 0.25)
    assert shown[2].endswith("netem loss 25%")


# ----- for real, in a throwaway network namespace -----------------------------------------------------------------


def _netns_problem() -> str | None:
    if os.geteuid() != 0:
        return "needs root (network namespaces)"
    try:
        tool("ip"), tool("tc")
    except NetemUnavailable as exc:
        return str(exc)
    return None


netns = pytest.mark.skipif(_netns_problem() is not None, reason=_netns_problem() or "")


@pytest.fixture
def namespace() -> Iterator[str]:
    name = f"swd-{os.getpid()}"
    subprocess.run([tool("ip"), "netns", "add", name], check=True, capture_output=True)
    try:
        subprocess.run([tool("ip"), "-n", name, "link", "set", "lo", "up"], check=True, capture_output=True)
        yield name
    finally:
        subprocess.run([tool("ip"), "netns", "del", name], check=False, capture_output=True)


def in_namespace(name: str, argv: list[str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [tool("ip"), "netns", "exec", name, *argv], check=False, capture_output=True, text=True, timeout=60
    )


@netns
@pytest.mark.netns
def test_tc_parses_every_command(namespace: str) -> None:
    for argv in netem_commands("lo", 0.1, delay_ms=20, jitter_ms=5):
        done = in_namespace(namespace, [tool(argv[0]), *argv[1:]])
        if argv[0] == "ip":
            assert done.returncode == 0, done.stderr
        else:
            assert done.returncode in (0, 2), f"{' '.join(argv)}: {done.stderr}"  # never 1, a usage error


NETEM_SCRIPT = """
import sys
from swarm.deploy.radio import deploy_netem_command
from swarm.errors import SwarmError
try:
    deploy_netem_command("127.0.0.1", 0.1, 0.0, 0.0, sys.argv[1])
except SwarmError as exc:
    print(f"swarm deploy: error: {exc}", file=sys.stderr)
    sys.exit(1)
"""

# 2000 datagrams over the impaired loopback: how many arrive
UDP_SCRIPT = """
import socket
rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); rx.bind(("127.0.0.1", 0)); rx.settimeout(0.05)
tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
got = 0
for batch in range(40):  # 50 at a time, drained each time: the receive buffer never overflows
    for i in range(50):
        tx.sendto(b"x", rx.getsockname())
    try:
        while True:
            rx.recv(16); got += 1
    except socket.timeout:
        pass
print(got)
"""


@netns
@pytest.mark.netns
def test_netem_on_loopback_works_or_says_why_in_one_line(namespace: str) -> None:
    done = in_namespace(namespace, [sys.executable, "-c", NETEM_SCRIPT, "netem"])
    assert "Traceback" not in done.stderr, done.stderr
    if done.returncode == 0:  # a kernel with sch_netem (and sch_prio): the impairment is in place
        assert "loss 10 % of IPv4 on egress by tc netem" in done.stdout
        qdiscs = in_namespace(namespace, [tool("tc"), "qdisc", "show", "dev", "lo"]).stdout
        assert "prio 1:" in qdiscs and "netem 40:" in qdiscs and "loss 10%" in qdiscs
        return
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert "cannot impair the radio lo (127.0.0.1)" in lines[0]
    if kernel_has_netem() is False:
        assert "this kernel lacks sch_netem" in lines[0]


@netns
@pytest.mark.netns
def test_auto_backend_loses_what_it_says(namespace: str) -> None:
    """auto: tc netem, or nftables where the kernel has none; either way about 10 % of datagrams are lost."""
    done = in_namespace(namespace, [sys.executable, "-c", NETEM_SCRIPT, "auto"])
    assert done.returncode == 0, done.stderr
    if kernel_has_netem() is False:
        assert "on ingress by nftables (no sch_netem here)" in done.stdout
        qdiscs = in_namespace(namespace, [tool("tc"), "qdisc", "show", "dev", "lo"]).stdout
        assert "prio" not in qdiscs  # the root netem would have hung from is gone again
        rules = in_namespace(namespace, [tool("nft"), "list", "table", "ip", NFT_TABLE]).stdout
        assert 'iifname "lo"' in rules and "numgen random mod 1000000 < 100000" in rules
    got = int(in_namespace(namespace, [sys.executable, "-c", UDP_SCRIPT]).stdout)
    assert 1700 <= got <= 1900, got  # 2000 at 10 %: 1800 +- 4.5 sigma
