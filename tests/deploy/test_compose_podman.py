"""The compose deployment, run for real under rootful Podman: image built from Debian's packages and PyPI,
3 drones, 20 % radio loss, mutual TLS; the mission ends on its own and `down` leaves nothing behind.

Skipped only where containers cannot run: no `podman`, or a probe container of the base image fails (the
reason is in the skip message). Everything else that is missing (debootstrap, podman-compose >= 1.1) is a
failure: ./bootstrap.sh installs it. The image is rebuilt only when its sources changed (`swarm deploy
image`: the org.swarm.sources label), so a second run costs the mission alone.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarm.config import load_config
from swarm.deploy.image import BASE_IMAGE, build_base, build_image, ca_bundle_of, image_exists

pytestmark = [pytest.mark.timeout(1800), pytest.mark.mission, pytest.mark.containers]

REPO = Path(__file__).resolve().parents[2]
IMAGE = "localhost/swarm-agent"
DRONES = 3
LOSS = 0.2
WORLD = "box"  # as the other end-to-end missions: the smallest built-in world
PROJECT = f"swarmpodtest{os.getpid()}"  # every container, network and volume carries this project label
LABEL = f"label=io.podman.compose.project={PROJECT}"


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.setdefault("CONTAINERS_CONF", str(REPO / "deploy" / "containers.conf"))  # runc, no default ulimits
    return env


def _podman(*args: str, check: bool = True, timeout: float = 1200) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["podman", *args], capture_output=True, text=True, check=check, env=_env(), timeout=timeout)


def _podman_compose() -> list[str]:
    """podman-compose next to this interpreter (bootstrap's .venv), else on PATH; it must place static addresses."""
    beside = Path(sys.executable).parent / "podman-compose"
    found = str(beside) if beside.exists() else shutil.which("podman-compose")
    assert found, "podman-compose is not installed (./bootstrap.sh installs it with the test extras)"
    version = subprocess.run([found, "--version"], capture_output=True, text=True, env=_env()).stdout
    line = next((ln for ln in version.splitlines() if ln.startswith("podman-compose version")), "")
    major, minor = (int(x) for x in line.split()[-1].split(".")[:2])
    assert (major, minor) >= (1, 1), f"{found}: {line}: 1.0 ignores the subnets and static addresses"
    return [found]


@pytest.fixture(scope="module")
def image() -> Iterator[str]:
    if shutil.which("podman") is None:
        pytest.skip("containers cannot run here: podman is not installed")
    with pytest.MonkeyPatch.context() as env:  # the engine settings for the builds below, this module only
        env.setenv("CONTAINERS_CONF", _env()["CONTAINERS_CONF"])
        if not image_exists("podman", BASE_IMAGE):
            build_base("podman")
        probe = _podman("run", "--rm", "--network", "none", BASE_IMAGE, "true", check=False)
        if probe.returncode != 0:
            pytest.skip(f"containers cannot run here: podman run {BASE_IMAGE} true: {probe.stderr.strip()[-300:]}")
        build_image(REPO, IMAGE, "podman", ca_bundle=ca_bundle_of(None))
        yield IMAGE


def _leftovers() -> dict[str, list[str]]:
    return {
        "containers": _podman("ps", "-a", "-q", "--filter", LABEL).stdout.split(),
        "networks": _podman("network", "ls", "-q", "--filter", LABEL).stdout.split(),
        "volumes": _podman("volume", "ls", "-q", "--filter", LABEL).stdout.split(),
    }


@pytest.fixture
def project(tmp_path: Path, image: str) -> Iterator[Path]:
    out = tmp_path / PROJECT
    done = subprocess.run(
        [sys.executable, "-m", "swarm", "deploy", "compose", "--drones", str(DRONES), "--loss", str(LOSS)]
        + ["--world", WORLD, "--tls", "--image", image, "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    tables_before = _nft_tables()
    try:
        yield out
    finally:  # whatever happened: down, then remove by label anything down left
        subprocess.run([*_podman_compose(), "-p", PROJECT, "down"], cwd=out, capture_output=True, env=_env())
        left = _leftovers()
        if left["containers"]:
            _podman("rm", "-f", *left["containers"], check=False)
        if left["networks"]:
            _podman("network", "rm", "-f", *left["networks"], check=False)
        if left["volumes"]:
            _podman("volume", "rm", "-f", *left["volumes"], check=False)
        # Podman's CNI backend puts its base chains (CNI-FORWARD, CNI-ADMIN) in iptables-nft tables it creates
        # (ip filter, ip nat) and never removes them; tables that were not there before the swarm came up go
        for family, name in sorted(_nft_tables() - tables_before):
            subprocess.run(["nft", "delete", "table", family, name], capture_output=True)


def _nft_tables() -> set[tuple[str, str]]:
    listed = subprocess.run(["nft", "list", "tables"], capture_output=True, text=True).stdout
    return {(words[1], words[2]) for words in (line.split() for line in listed.splitlines()) if len(words) == 3}


def test_three_drones_with_loss_and_tls_run_to_the_end_and_leave_nothing(project: Path) -> None:
    compose = _podman_compose()
    # detached, then wait for the ground station alone: `up --exit-code-from observer` would stop the swarm
    # when the first agent lands and exits, while the others still linger to finish their patch exchange
    up = subprocess.run(
        [*compose, "-p", PROJECT, "up", "-d"], cwd=project, capture_output=True, text=True, env=_env(), timeout=600
    )
    assert up.returncode == 0, up.stderr[-3000:]
    observer = f"{PROJECT}_observer_1"
    waited = _podman("wait", observer, check=False)
    log = _podman("logs", "--tail", "40", observer, check=False).stdout
    report_path = project / "results" / "report.json"
    assert report_path.exists(), log
    report = json.loads(report_path.read_text())
    assert report["status"] == "complete", (report["reason"], log)
    assert waited.stdout.strip() == "0", log  # the observer's exit code: the mission's verdict
    assert report["explored_fraction"] >= 0.95
    assert report["converged"] is True
    assert report["collisions"] == 0, report["collision_events"]
    assert report["network"] == "compose"
    assert report["scenario"]["backend"] in ("netem", "nftables")
    assert [(i["link"], i["profile"]) for i in report["impairments"]] == [
        (f"radio-{k}", f"loss {LOSS:g}") for k in range(1, DRONES + 1)
    ]
    assert (project / "results" / "map.ply").stat().st_size > 0

    # TLS: every agent's bus is tls/ only, and its container holds the CA certificate and its own pairs (TLS and
    # patch signing), no more
    for k in range(1, DRONES + 1):
        bus = load_config(project / "config" / f"agent-{k}.toml").bus
        assert bus.listen and all(e.startswith("tls/") for e in bus.listen + bus.connect), bus
        assert (str(bus.tls_dir), bus.tls_name) == ("/etc/swarm-tls", f"drone-{k}")
        mounts = json.loads(_podman("inspect", "--format", "{{json .Mounts}}", f"{PROJECT}_agent-{k}_1").stdout)
        tls = sorted(Path(m["Destination"]).name for m in mounts if m["Destination"].startswith("/etc/swarm-tls"))
        own = ["ca.pem", f"drone-{k}.pem", f"drone-{k}.key", f"drone-{k}.sign.pem", f"drone-{k}.sign.key"]
        assert tls == sorted(own)

    down = subprocess.run([*compose, "-p", PROJECT, "down"], cwd=project, capture_output=True, text=True, env=_env())
    assert down.returncode == 0, down.stderr
    assert _leftovers() == {"containers": [], "networks": [], "volumes": []}
