"""Running `ip`, `nft` and `tc` for swarm.netem: every failure becomes one line naming the command and its stderr.

All of these need root (CAP_NET_ADMIN and the right to create /run/netns entries). `check_prerequisites()` is
called before anything is created, so a missing tool or missing privilege is reported before any namespace
exists. The tools live in /usr/sbin on Debian, which is not always on PATH, so those directories are searched too.
"""

from __future__ import annotations

import os
import shutil
import subprocess

from swarm.errors import SwarmError

_SBIN_DIRS = ("/usr/sbin", "/sbin", "/usr/bin", "/bin")
_TIMEOUT_S = 20.0
_PACKAGE = {"ip": "iproute2", "tc": "iproute2", "nft": "nftables"}


class NetemUnavailable(SwarmError):
    """The virtual swarm network or an impairment cannot be set up here (not root, a tool missing, a command
    failed, or an impairment this kernel/backend cannot apply). The message is one line."""


def tool(name: str) -> str:
    """The absolute path of a networking tool, or NetemUnavailable."""
    search = os.pathsep.join([os.environ.get("PATH", ""), *_SBIN_DIRS])
    found = shutil.which(name, path=search)
    if found is None:
        raise NetemUnavailable(f"the '{name}' command is missing (Debian: apt-get install {_PACKAGE.get(name, name)})")
    return found


def check_prerequisites(tools: tuple[str, ...] = ("ip", "nft")) -> None:
    """Raise NetemUnavailable unless this process is root and the given tools exist."""
    if os.geteuid() != 0:
        raise NetemUnavailable("swarm.netem needs root (network namespaces and nftables); run as root")
    for name in tools:
        tool(name)


def _first_line(text: str) -> str:
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else "no error output"


def run(argv: list[str], stdin: str | None = None) -> str:
    """Run a command (its first element resolved with `tool()`), return its stdout; NetemUnavailable on failure."""
    full = [tool(argv[0]), *argv[1:]]
    shown = " ".join(argv)
    try:
        done = subprocess.run(full, input=stdin, capture_output=True, text=True, timeout=_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise NetemUnavailable(f"'{shown}' did not finish within {_TIMEOUT_S:.0f} s") from None
    except OSError as exc:
        raise NetemUnavailable(f"'{shown}' could not start: {exc.strerror}") from None
    if done.returncode != 0:
        raise NetemUnavailable(f"'{shown}' failed: {_first_line(done.stderr or done.stdout)}")
    return done.stdout


def run_in(namespace: str, argv: list[str], stdin: str | None = None) -> str:
    """Run a command inside a named network namespace (`ip netns exec`)."""
    return run(["ip", "netns", "exec", namespace, *argv], stdin)


def ip_batch(namespace: str, commands: list[str]) -> None:
    """Several `ip` commands in one process inside a namespace (`ip -n NS -batch -`); stops at the first error."""
    if commands:
        run(["ip", "-n", namespace, "-batch", "-"], "\n".join(commands) + "\n")


def namespaces() -> list[str]:
    """Names of the existing named network namespaces (`ip netns list`, without the "(id: N)" suffix)."""
    return [line.split()[0] for line in run(["ip", "netns", "list"]).splitlines() if line.strip()]


def namespace_pids(namespace: str) -> list[int]:
    """Pids of the processes whose network namespace is this one (empty if it is gone)."""
    try:
        out = run(["ip", "netns", "pids", namespace])
    except NetemUnavailable:
        return []
    return [int(word) for word in out.split() if word.isdigit()]


def delete_namespace(namespace: str) -> None:
    """Delete a named namespace; silently nothing if it is already gone. Its devices, bridge, qdiscs and nft
    tables go with it (the kernel frees it once no process is left inside)."""
    try:
        run(["ip", "netns", "delete", namespace])
    except NetemUnavailable:
        if namespace in namespaces():
            raise
