"""`swarm deploy compose` and `swarm deploy netem` from the command line: files written, and bad input one line
on stderr with exit 2 (flags, values) or 1 (anything else that stopped the command)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from swarm.config import load_config
from tests.deploy.parser import compose_config

pytestmark = pytest.mark.sim


def swarm(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    # run from cwd (not the repository): `python -m` puts the working directory first on sys.path
    return subprocess.run(
        [sys.executable, "-m", "swarm", *args], cwd=cwd, check=False, capture_output=True, text=True, timeout=120
    )


def one_line(done: subprocess.CompletedProcess[str]) -> str:
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    return lines[0]


def test_compose_writes_a_valid_deployment(tmp_path: Path) -> None:
    done = swarm(tmp_path, "deploy", "compose", "--drones", "2", "--loss", "0.1", "--world", "box", "--out", "d")
    assert done.returncode == 0, done.stderr
    out = tmp_path / "d"
    assert "docker-compose.yml" in done.stdout
    assert sorted(p.name for p in (out / "config").iterdir()) == [
        "agent-1.toml",
        "agent-2.toml",
        "cameras.toml",
        "observer.toml",
        "sim.toml",
    ]
    assert compose_config(out / "docker-compose.yml", "-q").returncode == 0
    # secure by default: mutual TLS on every bus endpoint, a certificate per drone and the observer
    assert {p.name for p in (out / "certs").iterdir()} >= {"ca.pem", "drone-1.key", "drone-2.key", "observer.key"}
    bus = load_config(out / "config" / "agent-1.toml").bus
    assert bus.tls_name == "drone-1" and all(e.startswith("tls/") for e in bus.listen + bus.connect)


def test_compose_no_tls_writes_plain_tcp_and_no_keys(tmp_path: Path) -> None:
    done = swarm(tmp_path, "deploy", "compose", "--drones", "2", "--world", "box", "--out", "d", "--no-tls")
    assert done.returncode == 0, done.stderr
    out = tmp_path / "d"
    assert not (out / "certs").exists()
    bus = load_config(out / "config" / "agent-1.toml").bus
    assert bus.tls_dir is None and bus.listen and all(e.startswith("tcp/") for e in bus.listen + bus.connect)
    assert "--no-tls" in (out / "docker-compose.yml").read_text()  # the header says how it was made


def test_compose_takes_config_flags(tmp_path: Path) -> None:
    done = swarm(
        tmp_path,
        "deploy",
        "compose",
        "--world",
        "box",
        "--out",
        "d",
        "--set",
        "mission.drones=4",
        "--set",
        "mission.name=lab",
    )
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "d" / "config" / "agent-4.toml").exists()
    assert 'name = "lab"' in (tmp_path / "d" / "config" / "agent-1.toml").read_text()
    # the simulator's vehicles: the agents make offboard loss a Hold unless told otherwise
    assert 'px4_params = "set"' in (tmp_path / "d" / "config" / "agent-1.toml").read_text()
    done = swarm(tmp_path, "deploy", "compose", "--world", "box", "--out", "e", "--set", "agent.px4_params=check")
    assert done.returncode == 0, done.stderr
    assert 'px4_params = "check"' in (tmp_path / "e" / "config" / "agent-1.toml").read_text()


@pytest.mark.parametrize(
    ("args", "code", "words"),
    [
        (("--drones", "0"), 2, "--drones"),
        (("--drones", "17"), 2, "--drones"),
        (("--loss", "1.5"), 2, "--loss"),
        (("--loss", "lots"), 2, "--loss"),
        (("--image", "Not An Image"), 2, "--image"),
        (("--world", "atlantis"), 1, "atlantis"),
        (("--set", "agent.bogus=1"), 2, "agent.bogus"),
    ],
)
def test_bad_compose_input_is_one_line(tmp_path: Path, args: tuple[str, ...], code: int, words: str) -> None:
    done = swarm(tmp_path, "deploy", "compose", "--world", "box", "--out", "d", *args)
    assert done.returncode == code, done.stderr
    assert words in one_line(done)
    assert not (tmp_path / "d").exists()


def test_non_empty_out_is_one_line(tmp_path: Path) -> None:
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "mine.txt").write_text("keep")
    done = swarm(tmp_path, "deploy", "compose", "--world", "box", "--out", "d")
    assert done.returncode == 1 and "not empty" in one_line(done)


def test_netem_clean_radio_does_nothing(tmp_path: Path) -> None:
    done = swarm(tmp_path, "deploy", "netem", "--address", "192.0.2.250", "--loss", "0")
    assert done.returncode == 0, done.stderr
    assert "nothing applied" in done.stdout


@pytest.mark.parametrize(
    ("args", "code", "words"),
    [
        (("--address", "radio", "--loss", "0.1"), 2, "--address"),
        (("--address", "10.77.1.11", "--loss", "2"), 2, "--loss"),
        (("--address", "10.77.1.11", "--loss", "0.1", "--jitter-ms", "5"), 2, "--jitter-ms"),
        (("--loss", "0.1"), 2, "--address"),
        (("--address", "192.0.2.250", "--loss", "0.1"), 1, "no interface holds 192.0.2.250"),
    ],
)
def test_bad_netem_input_is_one_line(tmp_path: Path, args: tuple[str, ...], code: int, words: str) -> None:
    done = swarm(tmp_path, "deploy", "netem", *args)
    assert done.returncode == code, done.stderr
    assert words in one_line(done)
