"""`swarm deploy compose`: the generated docker-compose file passes Docker's own parser and wires the swarm as
designed (radio impaired, control never, observer a peer off the radio); bad input is one line, nothing written.

Docker cannot run here, so nothing is started: the netns swarm (tests/netem, tests/mission) is the tested
equivalent of the running deployment.
"""

from __future__ import annotations

import ipaddress
import json
from pathlib import Path
from typing import Any

import pytest

from swarm.config import ConfigError, SwarmConfig, load_config, vehicle_port
from swarm.deploy.compose import (
    CONTROL_SUBNET,
    DEFAULT_IMAGE,
    RADIO_SUBNET,
    SIM_WAIT,
    Deployment,
    cameras_address,
    control_address,
    deploy_compose_command,
    observer_address,
    plan,
    radio_address,
    sim_address,
)
from swarm.errors import SwarmError, WorldError
from tests.deploy.parser import compose_config, read_yaml

DRONES = 3
LOSS = 0.2
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Deployment]:
    out = tmp_path_factory.mktemp("deploy") / "swarm"
    config = load_config(None, {"mission.world": "box"})
    assert deploy_compose_command(config, DRONES, LOSS, out, DEFAULT_IMAGE) == 0
    return out, plan(config, DRONES, LOSS)


@pytest.fixture(scope="module")
def compose(generated: tuple[Path, Deployment]) -> dict[str, Any]:
    out, _ = generated
    return read_yaml((out / "docker-compose.yml").read_text())


def agents(compose: dict[str, Any]) -> dict[int, dict[str, Any]]:
    return {int(name.split("-")[1]): s for name, s in compose["services"].items() if name.startswith("agent-")}


def in_subnet(address: str, subnet: ipaddress.IPv4Network) -> bool:
    return ipaddress.ip_address(address) in subnet


# ----- Docker's parser --------------------------------------------------------------------------------------------


@pytest.mark.sim
def test_docker_compose_parser_accepts_the_file(generated: tuple[Path, Deployment]) -> None:
    out, _ = generated
    done = compose_config(out / "docker-compose.yml", "-q")
    assert done.returncode == 0, done.stderr
    services = compose_config(out / "docker-compose.yml", "--services")
    assert services.returncode == 0, services.stderr
    assert sorted(services.stdout.split()) == sorted(
        ["sim", "cameras", "observer", *(f"agent-{k}" for k in range(1, DRONES + 1))]
    )


@pytest.mark.sim
def test_parser_sees_what_we_mean(generated: tuple[Path, Deployment]) -> None:
    """The parser's normalised view: capabilities, addresses, and the config mount resolved next to the file."""
    out, _ = generated
    done = compose_config(out / "docker-compose.yml")
    assert done.returncode == 0, done.stderr
    view = read_yaml(done.stdout)
    agent = view["services"]["agent-2"]
    assert agent["cap_add"] == ["NET_ADMIN"]
    assert agent["networks"]["radio"]["ipv4_address"] == radio_address(2)
    assert view["networks"]["radio"]["internal"] is True
    volumes = json.dumps(agent["volumes"])
    assert str(out / "config") in volumes and "/etc/swarm" in volumes


@pytest.mark.sim
def test_parser_rejects_a_broken_file(tmp_path: Path, generated: tuple[Path, Deployment]) -> None:
    """The parser really validates (so the passing test above means something)."""
    out, _ = generated
    broken = tmp_path / "docker-compose.yml"
    broken.write_text((out / "docker-compose.yml").read_text().replace("cap_add:", "cap_addd:", 1))
    done = compose_config(broken, "-q")
    assert done.returncode != 0 and "cap_addd" in done.stderr


def test_yaml_reads_back_exactly_as_planned(generated: tuple[Path, Deployment], compose: dict[str, Any]) -> None:
    _, deployment = generated
    assert compose == json.loads(json.dumps(deployment.compose))


# ----- structure --------------------------------------------------------------------------------------------------


def test_services_and_networks(compose: dict[str, Any]) -> None:
    assert set(compose["services"]) == {"sim", "cameras", "observer", *(f"agent-{k}" for k in range(1, DRONES + 1))}
    subnets = {name: net["ipam"]["config"][0]["subnet"] for name, net in compose["networks"].items()}
    assert subnets == {"radio": str(RADIO_SUBNET), "control": str(CONTROL_SUBNET)}
    assert all(net["internal"] for net in compose["networks"].values())
    for service in compose["services"].values():
        assert service["image"] == DEFAULT_IMAGE and service["pull_policy"] == "never"
        assert "./config:/etc/swarm:ro" in service["volumes"]


def test_each_agent_impairs_its_own_radio_then_runs(compose: dict[str, Any]) -> None:
    found = agents(compose)
    assert sorted(found) == list(range(1, DRONES + 1))
    radios = set()
    for k, service in found.items():
        assert service["cap_add"] == ["NET_ADMIN"]
        radio = service["networks"]["radio"]["ipv4_address"]
        control = service["networks"]["control"]["ipv4_address"]
        assert in_subnet(radio, RADIO_SUBNET) and in_subnet(control, CONTROL_SUBNET)
        radios.add(radio)
        assert service["entrypoint"] == ["/bin/sh", "-c"]
        (script,) = service["command"]
        wait, netem, rest = script.split(" && ", 2)
        assert wait == SIM_WAIT  # podman-compose on Podman < 4.6 ignores service_healthy: the agent waits itself
        assert netem == f"swarm deploy netem --address {radio} --loss {LOSS:g} --record /results/agents/radio-{k}.json"
        assert rest.startswith("exec ")
        agent = rest.removeprefix("exec ")
        assert agent.endswith(f"swarm agent --config /etc/swarm/agent-{k}.toml")
        # mission.max_time_s, as swarm run --max-time: unset, the default for the box and three drones
        assert agent.startswith("timeout --signal=TERM --kill-after=") and " 420 swarm agent" in agent
        assert service["depends_on"]["sim"] == {"condition": "service_healthy"}
        assert service["depends_on"]["cameras"] == {"condition": "service_started"}
    assert len(radios) == DRONES


def test_simulator_and_observer_are_off_the_radio(compose: dict[str, Any]) -> None:
    for name, address in (("sim", sim_address()), ("cameras", cameras_address()), ("observer", observer_address())):
        service = compose["services"][name]
        assert set(service["networks"]) == {"control"}
        assert service["networks"]["control"]["ipv4_address"] == address
        assert "cap_add" not in service
    assert compose["services"]["sim"]["healthcheck"]["test"][0] == "CMD"


# ----- the configs ------------------------------------------------------------------------------------------------


def configs(out: Path) -> dict[str, SwarmConfig]:
    return {path.stem: load_config(path) for path in sorted((out / "config").glob("*.toml"))}


def test_configs_load_and_wire_the_bus(generated: tuple[Path, Deployment]) -> None:
    out, _ = generated
    loaded = configs(out)
    assert set(loaded) == {"sim", "cameras", "observer", *(f"agent-{k}" for k in range(1, DRONES + 1))}
    for config in loaded.values():
        assert config.mission.drones == DRONES and config.mission.world == "box"
        assert config.mission.max_time_s == 420.0  # the default, resolved for the containers' own timeout
    for k in range(1, DRONES + 1):
        agent = loaded[f"agent-{k}"]
        assert agent.agent.id == k
        assert agent.agent.autopilot == f"udpout://{sim_address()}:{vehicle_port(agent.sim, k)}"
        assert str(agent.agent.out_dir) == "/results/agents"
        assert str(agent.agent.state_dir) == f"/results/agents/state/agent-{k}"  # each its own: a restart reloads
        assert agent.bus.mode == "router"
        assert agent.bus.listen == [f"tcp/{radio_address(k)}:7447", f"tcp/{control_address(k)}:7447"]
        # lower ids only, on the radio: one connection per pair, all of them over the impaired network
        assert agent.bus.connect == [f"tcp/{radio_address(j)}:7447" for j in range(1, k)]
        # it maps from its simulated camera through the simulator's sensor router, told the volume, not the world
        assert agent.camera.source == "sim" and agent.camera.stream.connect == [f"tcp/{sim_address()}:7447"]
        assert agent.mission.volume is not None and agent.mission.volume.max[0] == 8.0
    observer = loaded["observer"]
    assert observer.bus.mode == "peer"  # a peer never relays: it cannot bridge a broken radio link
    assert observer.bus.listen == [f"tcp/{observer_address()}:7447"]
    assert observer.bus.connect == [f"tcp/{control_address(k)}:7447" for k in range(1, DRONES + 1)]
    assert not any(in_subnet(e.split("/")[1].rsplit(":", 1)[0], RADIO_SUBNET) for e in observer.bus.connect)
    sim = loaded["sim"]
    assert sim.sim.host == "0.0.0.0" and str(sim.sim.status_path) == "/results/sim.json"
    assert len(sim.sim.spawns) == DRONES
    assert sim.sim.sensor_listen == [f"tcp/{sim_address()}:7447"]
    assert loaded["cameras"].camera.stream.connect == sim.sim.sensor_listen


def test_results_directory_is_ready(generated: tuple[Path, Deployment]) -> None:
    out, _ = generated
    assert (out / "results" / "agents" / "patches").is_dir()


@pytest.mark.sim
def test_loss_zero_still_runs_the_netem_step(tmp_path: Path) -> None:
    out = tmp_path / "clean"
    deploy_compose_command(load_config(None, {"mission.world": "box"}), 1, 0.0, out, DEFAULT_IMAGE)
    compose = read_yaml((out / "docker-compose.yml").read_text())
    (script,) = compose["services"]["agent-1"]["command"]
    assert f" && swarm deploy netem --address {radio_address(1)} --loss 0 --record " in script
    assert compose_config(out / "docker-compose.yml", "-q").returncode == 0


def test_mesh_world_is_copied_next_to_the_configs(tmp_path: Path) -> None:
    from swarm.sim.worlds import load_world

    mesh = tmp_path / "room.ply"
    load_world("box").save(mesh)
    out = tmp_path / "mesh"
    deploy_compose_command(load_config(None, {"mission.world": str(mesh)}), 2, 0.0, out, DEFAULT_IMAGE)
    assert (out / "config" / "worlds" / "room.ply").read_bytes() == mesh.read_bytes()
    assert all(c.mission.world == "/etc/swarm/worlds/room.ply" for c in configs(out).values())


def test_scripted_strategy_gets_its_routes(tmp_path: Path) -> None:
    out = tmp_path / "scripted"
    config = load_config(None, {"mission.world": "box", "explore.strategy": "scripted"})
    deploy_compose_command(config, 2, 0.0, out, DEFAULT_IMAGE)
    for k in (1, 2):
        assert load_config(out / "config" / f"agent-{k}.toml").agent.waypoints


@pytest.mark.sim
def test_build_context_lets_compose_build_the_image(tmp_path: Path) -> None:
    out = tmp_path / "build"
    deploy_compose_command(load_config(None, {"mission.world": "box"}), 1, 0.1, out, "swarm-test:dev", REPO)
    compose = read_yaml((out / "docker-compose.yml").read_text())
    for service in compose["services"].values():
        assert service["build"] == {"context": str(REPO), "dockerfile": "deploy/Dockerfile"}
        assert service["image"] == "swarm-test:dev" and "pull_policy" not in service
    done = compose_config(out / "docker-compose.yml", "-q")
    assert done.returncode == 0, done.stderr


# ----- bad input --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("drones", "loss", "image", "error", "words"),
    [
        (0, 0.1, DEFAULT_IMAGE, ConfigError, "--drones"),
        (17, 0.1, DEFAULT_IMAGE, ConfigError, "--drones"),
        (3, -0.1, DEFAULT_IMAGE, ConfigError, "--loss"),
        (3, 1.5, DEFAULT_IMAGE, ConfigError, "--loss"),
        (3, 0.1, "Not An Image", ConfigError, "--image"),
    ],
)
def test_bad_values_are_one_line_and_write_nothing(
    tmp_path: Path, drones: int, loss: float, image: str, error: type[Exception], words: str
) -> None:
    out = tmp_path / "out"
    with pytest.raises(error) as info:
        deploy_compose_command(load_config(None, {"mission.world": "box"}), drones, loss, out, image)
    message = str(info.value)
    assert "\n" not in message and words in message
    assert not out.exists()


def test_non_empty_output_directory_is_refused(tmp_path: Path) -> None:
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(SwarmError, match="not empty") as info:
        deploy_compose_command(load_config(None, {"mission.world": "box"}), 2, 0.1, tmp_path, DEFAULT_IMAGE)
    assert "\n" not in str(info.value)
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]


def test_a_generated_world_is_built_by_the_containers_not_copied(tmp_path: Path) -> None:
    out = tmp_path / "gen"
    spec = "gen:3:size=20x15"
    deploy_compose_command(load_config(None, {"mission.world": spec}), 2, 0.0, out, DEFAULT_IMAGE)
    assert not (out / "config" / "worlds").exists()
    assert all(c.mission.world == spec for c in configs(out).values())


def test_unknown_world_is_one_line(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with pytest.raises(WorldError) as info:
        deploy_compose_command(load_config(None, {"mission.world": "atlantis"}), 2, 0.1, out, DEFAULT_IMAGE)
    assert "\n" not in str(info.value) and "atlantis" in str(info.value)
    assert not out.exists()


def test_build_context_without_dockerfile_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="deploy/Dockerfile"):
        deploy_compose_command(load_config(None, {"mission.world": "box"}), 1, 0.1, tmp_path / "o", "x", tmp_path)


def test_link_scenario_is_refused_not_dropped(tmp_path: Path) -> None:
    config = load_config(None, {"mission.world": "box", "mission.network": "netns", "mission.links": "cut.toml"})
    with pytest.raises(ConfigError, match="mission.links") as info:
        deploy_compose_command(config, 2, 0.1, tmp_path / "out", DEFAULT_IMAGE)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("image", ["swarm-agent", "swarm-agent:dev", "localhost:5000/lab/swarm-agent:1.2"])
@pytest.mark.sim
def test_image_names_docker_takes(tmp_path: Path, image: str) -> None:
    deploy_compose_command(load_config(None, {"mission.world": "box"}), 1, 0.0, tmp_path / "o", image)
    compose = read_yaml((tmp_path / "o" / "docker-compose.yml").read_text())
    assert {s["image"] for s in compose["services"].values()} == {image}


def test_without_tls_each_drone_signs_with_its_own_key_from_the_deployments_authority(
    generated: tuple[Path, Deployment], compose: dict[str, Any]
) -> None:
    out, _ = generated
    assert {p.name for p in (out / "keys").iterdir()} == {"ca.pem", "ca.key"} | {
        f"drone-{k}.sign.{ext}" for k in range(1, DRONES + 1) for ext in ("pem", "key")
    }
    for k, service in agents(compose).items():
        mounted = sorted(v.split(":")[0] for v in service["volumes"] if v.startswith("./keys/"))
        assert mounted == sorted(["./keys/ca.pem", f"./keys/drone-{k}.sign.key", f"./keys/drone-{k}.sign.pem"])
        config = load_config(out / "config" / f"agent-{k}.toml")
        assert str(config.signing_dir()) == "/etc/swarm-keys"
    for name in ("sim", "observer"):
        assert not [v for v in compose["services"][name]["volumes"] if v.startswith("./keys/")], name


# ----- --tls ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def with_tls(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("deploy-tls") / "swarm"
    config = load_config(None, {"mission.world": "box"})
    assert deploy_compose_command(config, DRONES, LOSS, out, DEFAULT_IMAGE, tls=True) == 0
    return out


@pytest.fixture(scope="module")
def tls_compose() -> dict[str, Any]:
    return plan(load_config(None, {"mission.world": "box"}), DRONES, LOSS, tls=True).compose


def test_tls_each_container_mounts_only_its_own_key(with_tls: Path, tls_compose: dict[str, Any]) -> None:
    compose = tls_compose
    expected = {f"agent-{k}": f"drone-{k}" for k in range(1, DRONES + 1)} | {"observer": "observer"}
    for name, service in compose["services"].items():
        keys = sorted(v.split(":")[0] for v in service["volumes"] if v.startswith("./certs/"))
        if name in expected:
            who = expected[name]
            own = [f"./certs/{who}.key", f"./certs/{who}.pem", "./certs/ca.pem"]
            if who.startswith("drone-"):  # and its patch signing pair
                own += [f"./certs/{who}.sign.key", f"./certs/{who}.sign.pem"]
            assert keys == sorted(own), name
        else:
            assert keys == [], name  # the simulator and the cameras are not on the swarm's bus
    assert {p.name for p in (with_tls / "certs").iterdir()} >= {"ca.key", *(f"drone-{k}.key" for k in (1, 2, 3))}


def test_tls_every_bus_endpoint_is_tls_with_its_own_certificate(with_tls: Path) -> None:
    for k in range(1, DRONES + 1):
        bus = load_config(with_tls / "config" / f"agent-{k}.toml").bus
        assert bus.listen and all(e.startswith("tls/") for e in bus.listen + bus.connect)
        assert (str(bus.tls_dir), bus.tls_name) == ("/etc/swarm-tls", f"drone-{k}")
    observer = load_config(with_tls / "config" / "observer.toml").bus
    assert all(e.startswith("tls/") for e in observer.listen + observer.connect)
    assert observer.tls_name == "observer"


def test_observer_is_the_ground_station(tls_compose: dict[str, Any]) -> None:
    observer = tls_compose["services"]["observer"]
    assert observer["command"] == ["deploy", "mission", "--config", "/etc/swarm/observer.toml", "--results", "/results"]


@pytest.mark.sim
def test_docker_compose_parser_accepts_the_tls_file(with_tls: Path) -> None:
    done = compose_config(with_tls / "docker-compose.yml", "-q")
    assert done.returncode == 0, done.stderr
