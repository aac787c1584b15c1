"""Measure what a SwarmNetwork really does to traffic: one-way UDP counts and TCP goodput between nodes.

Every measurement starts its processes inside the node namespaces (`net.exec_argv`) from traffic.py and kills
whatever is still running in a `finally`.
"""

from __future__ import annotations

import json
import select
import subprocess
import sys
import time
from pathlib import Path

from swarm.netem import NetemUnavailable, SwarmNetwork, check_prerequisites

TRAFFIC = str(Path(__file__).with_name("traffic.py"))
Flow = tuple[int, int]


def netem_problem() -> str | None:
    """Why swarm networks cannot be built here (not root, tools missing), or None."""
    try:
        check_prerequisites()
    except NetemUnavailable as exc:
        return str(exc)
    return None


def _start_receiver(net: SwarmNetwork, node: int, mode: str, port: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        net.exec_argv(node, [sys.executable, TRAFFIC, mode, str(port)]),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], 10.0)
    line = proc.stdout.readline() if ready else ""
    if line.strip() != "ready":
        proc.kill()
        raise AssertionError(f"{mode} receiver on node {node} did not start (got {line!r})")
    return proc


def _result(proc: subprocess.Popen[str], stop: bool) -> dict[str, float]:
    out, _ = proc.communicate("stop\n" if stop else None, timeout=30)
    return json.loads(out.strip().splitlines()[-1])


def _kill(procs: list[subprocess.Popen[str]]) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)


def udp_one_way(net: SwarmNetwork, flows: list[Flow], count: int) -> dict[Flow, int]:
    """Send `count` datagrams on every flow (src, dst) at once; return how many each destination received."""
    procs: list[subprocess.Popen[str]] = []
    try:
        receivers = {}
        for i, (src, dst) in enumerate(flows):
            receivers[(src, dst)] = _start_receiver(net, dst, "udp-recv", 9000 + i)
            procs.append(receivers[(src, dst)])
        senders = []
        for i, (src, dst) in enumerate(flows):
            argv = [sys.executable, TRAFFIC, "udp-send", net.address(dst), str(9000 + i), str(count)]
            senders.append(subprocess.Popen(net.exec_argv(src, argv)))
            procs.append(senders[-1])
        for sender in senders:
            assert sender.wait(timeout=30) == 0
        time.sleep(0.2)  # the last datagrams are still on their way
        return {flow: int(_result(proc, stop=True)["received"]) for flow, proc in receivers.items()}
    finally:
        _kill(procs)


def tcp_goodput_kbit(net: SwarmNetwork, flows: list[Flow], seconds: float) -> dict[Flow, float]:
    """Run one bulk TCP transfer per flow at once for `seconds`; return each receiver's goodput in kbit/s."""
    procs: list[subprocess.Popen[str]] = []
    try:
        receivers = {}
        for i, (src, dst) in enumerate(flows):
            receivers[(src, dst)] = _start_receiver(net, dst, "tcp-recv", 9100 + i)
            procs.append(receivers[(src, dst)])
        for i, (src, dst) in enumerate(flows):
            argv = [sys.executable, TRAFFIC, "tcp-send", net.address(dst), str(9100 + i), str(seconds)]
            procs.append(subprocess.Popen(net.exec_argv(src, argv)))
        rates = {}
        for flow, proc in receivers.items():
            result = _result(proc, stop=False)
            rates[flow] = result["bytes"] * 8 / 1000 / max(result["seconds"], 1e-6)
        return rates
    finally:
        _kill(procs)
