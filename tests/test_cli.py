"""The CLI's contract with a person: bad flags and bad config are one line on stderr and exit code 2."""

import subprocess
import sys

import pytest


def swarm(*args: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "swarm", *args], capture_output=True, text=True, timeout=timeout)


@pytest.mark.parametrize(
    "args",
    [
        ("run", "--drones", "0"),
        ("run", "--drones", "three"),
        ("run", "--start", "1,2"),
        ("run", "--set", "mission.drones=-4"),
        ("run", "--set", "agent.bogus=1"),
        ("run", "--config", "/nonexistent/swarm.toml"),
        ("agent", "--autopilot", "not-a-url"),
        ("frobnicate",),
        ("mapnode", "--status", "/tmp/n.json", "--period", "0"),
        ("mapnode", "--status", "/tmp/n.json", "--patches", "-1"),
        ("mapnode", "--status", "/tmp/n.json", "--set", "sync.chunk_bytes=10"),
        ("mapnode", "--status", "/tmp/n.json", "--set", "sync.backoff_max_s=0.1"),
        ("bench", "sync", "--drones", "x"),
        ("run", "--no-rrd", "--view"),
        ("export", "/tmp"),
    ],
)
@pytest.mark.sim
def test_bad_input_is_one_line_and_exit_2(args: tuple[str, ...]) -> None:
    result = swarm(*args)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "error" in lines[0]
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(
    "args",
    [
        ("view", "/nonexistent/run"),
        ("view", "--web", "/nonexistent/run"),
        ("export", "/nonexistent/run", "--mcap", "/nonexistent/bag"),
    ],
)
@pytest.mark.sim
def test_a_run_directory_that_is_not_there_is_one_line_and_exit_1(args: tuple[str, ...]) -> None:
    result = swarm(*args)
    assert result.returncode == 1, result.stderr
    assert result.stderr.strip() == f"swarm {args[0]}: error: /nonexistent/run: " + (
        "no such run directory"
        if args[0] == "view"
        else "no report.json (not a finished swarm run, or recorded with --no-rrd)"
    )


@pytest.mark.sim
def test_help_lists_every_command() -> None:
    result = swarm("--help")
    assert result.returncode == 0
    for command in ("run", "sim", "agent", "observe", "mapnode", "bench", "view", "export"):
        assert command in result.stdout


def _parsers(parser):
    """`parser` and every sub-command parser under it."""
    import argparse

    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_every_command_has_a_help_page() -> None:
    from swarm.cli import build_parser

    pages = [p.format_help() for p in _parsers(build_parser())]  # a stray % in a help text raises here
    assert len(pages) > 10 and all("usage:" in page for page in pages)


def test_every_command_has_a_handler() -> None:
    import argparse

    from swarm.cli import build_parser

    def has_subcommands(parser: argparse.ArgumentParser) -> bool:
        return any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)

    leaves = [p for p in _parsers(build_parser()) if not has_subcommands(p)]
    assert len(leaves) > 10
    for leaf in leaves:
        assert callable(leaf.get_default("handler")), leaf.prog
