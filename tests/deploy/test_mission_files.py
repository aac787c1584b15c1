"""The ground station's file side (swarm/deploy/mission.py, swarm/deploy/image.py): what the report says about
the radios, from the records the agents' `swarm deploy netem --record` wrote; what makes the image stale."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from swarm.deploy.image import sources_hash
from swarm.deploy.mission import link_report, radio_record_path, wait_for_simulator
from swarm.deploy.radio import RadioImpairment, nft_ruleset
from swarm.errors import SwarmError

REPO = Path(__file__).resolve().parents[2]


def _record(results: Path, k: int, backend: str | None, loss: float) -> None:
    path = radio_record_path(results, k)
    path.parent.mkdir(parents=True, exist_ok=True)
    radio = RadioImpairment(
        address=f"10.77.1.{10 + k}", interface="eth0" if backend else "", backend=backend, loss=loss
    )  # type: ignore[arg-type]
    path.write_text(radio.model_dump_json())


def test_link_report_names_each_radio_and_the_backend(tmp_path: Path) -> None:
    for k in (1, 2):
        _record(tmp_path, k, "nftables", 0.2)
    links = link_report(tmp_path, 3)
    assert links["scenario"]["backend"] == "nftables"
    assert links["scenario"]["unrecorded_radios"] == [3]  # never claimed: agent 3 wrote no record
    assert [(i["link"], i["profile"], i["backend"]) for i in links["impairments"]] == [
        ("radio-1", "loss 0.2", "nftables"),
        ("radio-2", "loss 0.2", "nftables"),
    ]


def test_clean_radios_claim_no_backend(tmp_path: Path) -> None:
    _record(tmp_path, 1, None, 0.0)
    links = link_report(tmp_path, 1)
    assert links["scenario"]["backend"] is None and links["impairments"] == []


def test_nft_ruleset_drops_on_arrival_at_the_loss() -> None:
    script = nft_ruleset("eth1", 0.25)
    assert "hook prerouting" in script and 'iifname "eth1"' in script
    assert "numgen random mod 1000000 < 250000 counter drop" in script
    assert script.startswith("table ip swradio\ndelete table ip swradio\n")  # atomic replace, never stacked


def test_wait_for_simulator_gives_up_in_one_line(tmp_path: Path) -> None:
    with pytest.raises(SwarmError) as info:
        wait_for_simulator(tmp_path / "sim.json", 0.2)
    assert "\n" not in str(info.value) and "did not say ready" in str(info.value)


def test_sources_hash_follows_the_sources_only(tmp_path: Path) -> None:
    repo = tmp_path / "repo"
    (repo / "deploy").mkdir(parents=True)
    for name in ("pyproject.toml", "README.md", "deploy/Containerfile"):
        shutil.copy(REPO / name, repo / name)
    (repo / "swarm").mkdir()
    (repo / "swarm" / "a.py").write_text("x = 1\n")
    before = sources_hash(repo)
    (repo / "swarm" / "__pycache__").mkdir()
    (repo / "swarm" / "__pycache__" / "a.pyc").write_bytes(b"cache")
    (repo / "tests").mkdir()
    (repo / "tests" / "t.py").write_text("")
    assert sources_hash(repo) == before  # caches and tests are not in the image
    (repo / "swarm" / "a.py").write_text("x = 2\n")
    assert sources_hash(repo) != before
