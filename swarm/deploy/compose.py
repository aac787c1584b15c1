"""`swarm deploy compose`: the simulated swarm of `swarm run` as a docker-compose file, one container a process.

What it writes into OUT (which must be empty or new):

    docker-compose.yml        the simulator, the observer and agent-1..N; the networks below
    config/sim.toml, observer.toml, agent-K.toml
                              each process's exact configuration, as `swarm run` writes it (mounted read-only
                              at /etc/swarm); a world given as a mesh file is copied to config/worlds/
    certs/                    with TLS (the default): the CA and one certificate per drone and the observer,
                              and each drone's patch signing certificate (`swarm deploy certs`); a container
                              mounts ca.pem and its own pairs only, at /etc/swarm-tls, so a drone never holds
                              another drone's key nor the CA's
    keys/                     without TLS: a signing authority of the deployment's own and each drone's patch
                              signing pair (swarm.patches.signing); a drone mounts ca.pem and its own pair at
                              /etc/swarm-keys
    results/                  mounted at /results: report.json (the observer's `swarm deploy mission`),
                              sim.json, observer.json, map.ply, agents/agent-K.json|ply, agents/radio-K.json
                              (what loss each radio got, and by which backend), agents/patches/,
                              agents/state/agent-K/ (the agent's own sealed patches and epoch: a restart reloads)

Engines: written for `docker compose` and `podman-compose` (>= 1.1: static addresses and subnets). Podman
before 4.6 cannot wait for a healthcheck, so podman-compose ignores `condition: service_healthy` there; each
agent and the cameras therefore also wait for the simulator's status file themselves (SIM_WAIT).

Networks (fixed subnets, static addresses, both `internal`: nothing reaches outside, so nothing goes around):
- `radio` RADIO_SUBNET: Zenoh between agents, and the only impaired network. Agent k's command first runs
  `swarm deploy netem --address <its radio address> --loss P` (NET_ADMIN, see swarm/deploy/radio.py), then
  execs the agent under `timeout` (mission.max_time_s, as `swarm run --max-time`: SIGTERM lands the drone).
- `control` CONTROL_SUBNET: never impaired. MAVLink between the simulator and each agent, and the observer's
  measurement path. Agent k's Zenoh session listens on its radio AND its control address, connects to the
  radio addresses of lower ids only (one connection per pair, as `swarm run`), and the observer connects to
  every agent's control address in `peer` mode: a peer never relays, so the observer cannot bridge a broken
  radio link, while it still hears every agent whatever the radio does.
- With TLS (the CLI's default; --no-tls turns it off) every endpoint is `tls/` and each session checks its
  peers' certificates against the CA, under the access control of `swarm run --tls` (swarm/bus/session.py:
  drone-K speaks only as agent K).

MAVLink: the simulator binds 0.0.0.0 in its container; agent k uses `udpout://<sim>:<vehicle_port(k)>` (the
simulated vehicle answers whoever last sent it MAVLink), so no agent address needs to be known in advance.
"""

from __future__ import annotations

import ipaddress
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import tomli_w
from pydantic import ValidationError

from swarm.config import TLS_OBSERVER_NAME, Box, ConfigError, SwarmConfig, dump_config, tls_drone_name, vehicle_port
from swarm.deploy import yamltext
from swarm.deploy.certs import CA_NAME, make_certs, make_signing_authority
from swarm.errors import SwarmError, validation_problem
from swarm.patches.signing import signing_cert_path, signing_key_path
from swarm.sim.worlds import is_mesh_file, load_world, mission_time_limit_s, mission_volume, spawn_points

RADIO_SUBNET = ipaddress.ip_network("10.77.1.0/24")
CONTROL_SUBNET = ipaddress.ip_network("10.77.2.0/24")
ZENOH_PORT = 7447
HOST_OFFSET = 10  # agent k is .10+k on both networks; .1 Docker's bridge, .2 the simulator, .3 the observer,
# .4 the cameras
MAX_DRONES = 16  # as mission.drones
CONFIG_DIR = "/etc/swarm"
TLS_DIR = "/etc/swarm-tls"  # not under CONFIG_DIR: a read-only mount cannot hold the mount points of the keys
SIGNING_DIR = "/etc/swarm-keys"  # without TLS: the signing authority's certificate and the drone's signing pair
RESULTS_DIR = "/results"
SIM_READY_TIMEOUT_S = 300
SIM_WAIT = f"swarm deploy wait-sim --status {RESULTS_DIR}/sim.json --timeout {SIM_READY_TIMEOUT_S}"
DEFAULT_IMAGE = "swarm-agent"  # not "swarm": Docker Hub has an unrelated official image of that name
DOCKERFILE = "deploy/Dockerfile"
AGENT_STOP_GRACE_S = 60  # SIGTERM makes an airborne agent land first (as swarm run's LANDING_GRACE_S)
_IMAGE_RE = re.compile(  # [registry[:port]/]name[/name...][:tag], as `docker build -t` takes it
    r"[a-z0-9][a-z0-9._-]*(:[0-9]+)?(/[a-z0-9][a-z0-9._-]*)*(:[A-Za-z0-9_][A-Za-z0-9._-]{0,127})?"
)

_SIM_HEALTH = (
    "import json, os, sys, time; p = '/results/sim.json'; s = json.load(open(p)); "
    "sys.exit(0 if s.get('ready') and not s.get('done') and time.time() - os.path.getmtime(p) < 5 else 1)"
)


def sim_address() -> str:
    return str(CONTROL_SUBNET[2])


def observer_address() -> str:
    return str(CONTROL_SUBNET[3])


def radio_address(k: int) -> str:
    return str(RADIO_SUBNET[HOST_OFFSET + k])


def cameras_address() -> str:
    return str(CONTROL_SUBNET[4])


def control_address(k: int) -> str:
    return str(CONTROL_SUBNET[HOST_OFFSET + k])


def _zenoh(address: str, tls: bool = False) -> str:
    return f"{'tls' if tls else 'tcp'}/{address}:{ZENOH_PORT}"


def _tls_bus(tls: bool, name: str) -> dict[str, Any]:
    return {"tls_dir": TLS_DIR, "tls_name": name} if tls else {}


@dataclass
class Deployment:
    """Everything `write()` puts on disk: the compose document, each process's config, world files to copy."""

    compose: dict[str, Any]
    configs: dict[str, SwarmConfig]
    worlds: list[Path] = field(default_factory=list)
    header: str = ""
    tls_names: list[str] = field(default_factory=list)  # certificates to write into OUT/certs
    signing_drones: int = 0  # without TLS: drones given a signing pair in OUT/keys

    def write(self, out: Path) -> list[Path]:
        """Write every file under `out`; returns the files written (worlds and results dirs included)."""
        written: list[Path] = []
        config_dir = out / "config"
        config_dir.mkdir(parents=True, exist_ok=True)
        for name, config in self.configs.items():
            path = config_dir / f"{name}.toml"
            path.write_text(tomli_w.dumps(dump_config(config)))
            written.append(path)
        for world in self.worlds:
            (config_dir / "worlds").mkdir(exist_ok=True)
            written.append(Path(shutil.copy2(world, config_dir / "worlds" / world.name)))
        if self.tls_names:
            drones = sum(1 for name in self.tls_names if name != TLS_OBSERVER_NAME)
            make_certs(out / "certs", drones)
            written.append(out / "certs")
        elif self.signing_drones:
            make_signing_authority(out / "keys", self.signing_drones)
            written.append(out / "keys")
        patches = out / "results" / "agents" / "patches"
        patches.mkdir(parents=True, exist_ok=True)  # the observer reads it from the start
        path = out / "docker-compose.yml"
        path.write_text(yamltext.dumps(self.compose, self.header))
        written.append(path)
        return written


def check_inputs(drones: int, loss: float, out: Path, image: str, build_context: Path | None) -> None:
    """ConfigError / SwarmError (one line) for anything that would make a file that cannot run."""
    if not 1 <= drones <= MAX_DRONES:
        raise ConfigError(f"--drones must be between 1 and {MAX_DRONES} (got {drones})")
    if not 0.0 <= loss <= 1.0:
        raise ConfigError(f"--loss must be a fraction between 0 and 1 (got {loss:g})")
    if not _IMAGE_RE.fullmatch(image):
        raise ConfigError(f"--image '{image}' is not a Docker image name (lower case, e.g. swarm-agent:latest)")
    if build_context is not None and not (build_context / DOCKERFILE).is_file():
        raise ConfigError(f"--build-context {build_context} has no {DOCKERFILE} (give the swarm repository)")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise SwarmError(f"output directory {out} is not empty")


def plan(
    config: SwarmConfig,
    drones: int,
    loss: float,
    image: str = DEFAULT_IMAGE,
    build_context: Path | None = None,
    tls: bool = False,
) -> Deployment:
    """The deployment of `drones` agents; raises WorldError (one line) for an unusable world or start point."""
    m = config.mission
    if getattr(m, "links", None) is not None:
        raise ConfigError(
            f"mission.links ({m.links}) is a link scenario for swarm run --network netns; the compose deployment "
            "impairs every link alike (--loss, or edit each agent's netem command)"
        )
    world = load_world(m.world)
    spawns = spawn_points(world, m.start, drones, m.spawn_spacing_m)
    m = m.model_copy(update={"max_time_s": mission_time_limit_s(m.model_copy(update={"drones": drones}), world)})
    routes: dict[int, Any] = {}
    lo, hi = mission_volume(world, m.volume)  # the agents are told the volume: they load no world
    if config.explore.strategy == "scripted":
        from swarm.sim.routes import scripted_routes

        planned = scripted_routes(world, spawns, lo, hi, config.sim.drone_radius_m, config.agent.cruise_speed_m_s)
        routes = {route.drone_id: route for route in planned}

    worlds: list[Path] = []
    world_ref = m.world
    if is_mesh_file(m.world):  # the containers read their copy; built-in and generated worlds they build
        worlds.append(Path(m.world))
        world_ref = f"{CONFIG_DIR}/worlds/{Path(m.world).name}"
    base = config.model_copy(
        update={"mission": m.model_copy(update={"drones": drones, "world": world_ref, "out": None})}, deep=True
    )

    configs: dict[str, SwarmConfig] = {}
    # The simulator's odometry and `swarm cameras`' images meet on the simulator's sensor router (the robot
    # side's rmw_zenohd), on the control network: sensor streams are on board a real drone, never on the radio.
    sensors = base.camera.model_copy(
        update={"stream": base.camera.stream.model_copy(update={"connect": [_zenoh(sim_address())], "listen": []})}
    )
    sim = base.model_copy(update={"camera": sensors}, deep=True)
    sim.sim = base.sim.model_copy(
        update={
            "host": "0.0.0.0",
            "spawns": spawns,
            "status_path": f"{RESULTS_DIR}/sim.json",
            "sensor_listen": [_zenoh(sim_address())] if base.camera.source == "sim" else [],
        }
    )
    configs["sim"] = sim
    if base.camera.source == "sim":
        configs["cameras"] = base.model_copy(update={"camera": sensors}, deep=True)
    volume = Box(min=(float(lo[0]), float(lo[1]), float(lo[2])), max=(float(hi[0]), float(hi[1]), float(hi[2])))
    configs["observer"] = base.model_copy(
        update={
            "bus": base.bus.model_copy(
                update={
                    "mode": "peer",
                    "listen": [_zenoh(observer_address(), tls)],
                    "connect": [_zenoh(control_address(k), tls) for k in range(1, drones + 1)],
                    **_tls_bus(tls, TLS_OBSERVER_NAME),
                }
            )
        }
    )
    for k in range(1, drones + 1):
        agent_update: dict[str, Any] = {
            "id": k,
            "autopilot": f"udpout://{sim_address()}:{vehicle_port(base.sim, k)}",
            "out_dir": f"{RESULTS_DIR}/agents",
            # as swarm run: a restarted container reloads its own sealed patches (and its epoch counter) from here
            "state_dir": f"{RESULTS_DIR}/agents/state/agent-{k}",
        }
        if "px4_params" not in base.agent.model_fields_set:
            agent_update["px4_params"] = "set"  # the simulator's vehicles, as swarm run
        if k in routes:
            route = routes[k]
            agent_update |= {
                "altitude_m": route.altitude_m,
                "waypoints": route.waypoints,
                "start_delay_s": route.start_delay_s,
            }
        configs[f"agent-{k}"] = base.model_copy(
            update={
                "agent": base.agent.model_copy(update=agent_update),
                "mission": base.mission.model_copy(update={"volume": volume}),
                "camera": sensors,
                "bus": base.bus.model_copy(
                    update={
                        "listen": [_zenoh(radio_address(k), tls), _zenoh(control_address(k), tls)],
                        "connect": [_zenoh(radio_address(j), tls) for j in range(1, k)],
                        **_tls_bus(tls, tls_drone_name(k)),
                    }
                ),
                # with TLS the signing pair is beside the TLS pair, where signing_dir defaults to
                "sync": base.sync if tls else base.sync.model_copy(update={"signing_dir": Path(SIGNING_DIR)}),
            }
        )
    # the configs are checked as the processes will load them (validators run on load, not on model_copy)
    configs = {name: _revalidate(name, c) for name, c in configs.items()}

    compose = _compose(base, drones, loss, image, build_context, tls)
    build = (
        f"Build the image first, from the swarm repository: swarm deploy image --tag {image} "
        f"(or docker build -t {image} -f {DOCKERFILE} .)"
        if build_context is None
        else f"`docker compose build` builds the image from {build_context.resolve()}"
    )
    header = "\n".join(
        [
            f"Generated by `swarm deploy compose --drones {drones} --loss {loss:g}{'' if tls else ' --no-tls'}`: "
            "see docs/deploy.md.",
            build,
            "Run: docker compose up -d && docker compose wait observer (Podman: podman-compose up -d && podman wait "
            "<project>_observer_1); results/report.json at the end.",
            "Start each run with an empty results/ (the observer would fuse an earlier run's patches).",
            f"radio {RADIO_SUBNET}: Zenoh between agents, loss {loss:g} on each agent's egress (tc netem, or "
            f"nftables without sch_netem); control {CONTROL_SUBNET}: MAVLink and the observer, never impaired",
        ]
        + (
            ["TLS: certs/ holds the CA and every key; each container mounts ca.pem and its own pairs"]
            if tls
            else ["keys/ holds the patch signing authority and every drone's signing key; each drone mounts its own"]
        )
    )
    names = [tls_drone_name(k) for k in range(1, drones + 1)] + [TLS_OBSERVER_NAME] if tls else []
    return Deployment(compose, configs, worlds, header, names, 0 if tls else drones)


def _revalidate(name: str, config: SwarmConfig) -> SwarmConfig:
    try:
        return SwarmConfig.model_validate(dump_config(config))
    except ValidationError as exc:
        raise ConfigError(f"the generated {name}.toml does not validate: {validation_problem(exc)}") from None


def _service(
    image: str, build_context: Path | None, tls_name: str | None = None, drone: int | None = None
) -> dict[str, Any]:
    """A service of the image; with `tls_name`, mounting the CA certificate and that name's pair, nothing else;
    for `drone`, its patch signing pair too (with TLS beside the TLS pair, else with the signing authority's
    certificate from keys/)."""
    service: dict[str, Any] = {"image": image}
    if build_context is None:
        service["pull_policy"] = "never"  # a missing image is an error, never a download of someone else's
    else:
        service["build"] = {"context": str(build_context.resolve()), "dockerfile": DOCKERFILE}
    volumes = [f"./config:{CONFIG_DIR}:ro", f"./results:{RESULTS_DIR}"]
    if tls_name is not None:
        volumes += [
            f"./certs/{file}:{TLS_DIR}/{file}:ro" for file in (f"{CA_NAME}.pem", f"{tls_name}.pem", f"{tls_name}.key")
        ]
    if drone is not None:
        signing = [signing_cert_path(Path(), drone).name, signing_key_path(Path(), drone).name]
        if tls_name is not None:
            volumes += [f"./certs/{file}:{TLS_DIR}/{file}:ro" for file in signing]
        else:
            volumes += [f"./keys/{file}:{SIGNING_DIR}/{file}:ro" for file in [f"{CA_NAME}.pem", *signing]]
    service |= {
        "init": True,  # a real PID 1 that forwards SIGTERM: `docker compose stop` lands the drones
        "volumes": volumes,
    }
    return service


def _compose(
    config: SwarmConfig, drones: int, loss: float, image: str, build_context: Path | None, tls: bool = False
) -> dict[str, Any]:
    services: dict[str, Any] = {}
    services["sim"] = _service(image, build_context) | {
        "command": ["sim", "--config", f"{CONFIG_DIR}/sim.toml"],
        "networks": {"control": {"ipv4_address": sim_address()}},
        "healthcheck": {
            "test": ["CMD", "python", "-c", _SIM_HEALTH],
            "interval": "1s",
            "timeout": "5s",
            "retries": 120,
        },
        "stop_grace_period": "10s",
    }
    if config.camera.source == "sim":
        services["cameras"] = _service(image, build_context) | {
            "entrypoint": ["/bin/sh", "-c"],
            "command": [f"{SIM_WAIT} && exec swarm cameras --config {CONFIG_DIR}/cameras.toml"],
            "networks": {"control": {"ipv4_address": cameras_address()}},
            "depends_on": {"sim": {"condition": "service_healthy"}},
            "stop_grace_period": "10s",
        }
    # the ground station: it runs the observer, ends with the agents and writes results/report.json
    services["observer"] = _service(image, build_context, TLS_OBSERVER_NAME if tls else None) | {
        "command": ["deploy", "mission", "--config", f"{CONFIG_DIR}/observer.toml", "--results", RESULTS_DIR],
        "networks": {"control": {"ipv4_address": observer_address()}},
        "stop_grace_period": "90s",
    }
    max_time = f"{config.mission.max_time_s:g}"
    for k in range(1, drones + 1):
        script = (
            f"{SIM_WAIT}"
            f" && swarm deploy netem --address {radio_address(k)} --loss {loss:g}"
            f" --record {RESULTS_DIR}/agents/radio-{k}.json"
            f" && exec timeout --signal=TERM --kill-after={AGENT_STOP_GRACE_S} {max_time}"
            f" swarm agent --config {CONFIG_DIR}/agent-{k}.toml"
        )
        services[f"agent-{k}"] = _service(image, build_context, tls_drone_name(k) if tls else None, k) | {
            "cap_add": ["NET_ADMIN"],
            "entrypoint": ["/bin/sh", "-c"],
            "command": [script],
            "depends_on": {
                "sim": {"condition": "service_healthy"},
                "observer": {"condition": "service_started"},
                **({"cameras": {"condition": "service_started"}} if "cameras" in services else {}),
            },
            "networks": {"radio": {"ipv4_address": radio_address(k)}, "control": {"ipv4_address": control_address(k)}},
            "stop_grace_period": f"{AGENT_STOP_GRACE_S}s",
        }
    networks = {
        name: {"driver": "bridge", "internal": True, "ipam": {"config": [{"subnet": str(subnet)}]}}
        for name, subnet in (("radio", RADIO_SUBNET), ("control", CONTROL_SUBNET))
    }
    return {"services": services, "networks": networks}


def deploy_compose_command(
    config: SwarmConfig,
    drones: int,
    loss: float,
    out: Path,
    image: str = DEFAULT_IMAGE,
    build_context: Path | None = None,
    tls: bool = False,
) -> int:
    """`swarm deploy compose`: validate, write OUT/docker-compose.yml, OUT/config/, OUT/results/; say what."""
    check_inputs(drones, loss, out, image, build_context)
    deployment = plan(config, drones, loss, image, build_context, tls)
    deployment.write(out)
    compose = out / "docker-compose.yml"
    cameras = ", cameras" if "cameras" in deployment.compose["services"] else ""
    print(
        f"wrote {compose}: sim{cameras}, observer and agent-1..{drones} ('{image}' image), "
        f"world {config.mission.world}, strategy {config.explore.strategy}"
    )
    print(
        f"  radio {RADIO_SUBNET}: agents at {radio_address(1)}..{radio_address(drones)}, "
        f"loss {loss:g} on every link each way (tc netem in each agent, nftables without sch_netem)"
    )
    print(
        f"  control {CONTROL_SUBNET}: simulator {sim_address()} (its sensor router too), cameras "
        f"{cameras_address()}, observer {observer_address()}, "
        f"agents at {control_address(1)}..{control_address(drones)} (never impaired)"
    )
    print(
        f"wrote {out / 'config'}: {', '.join(f'{name}.toml' for name in deployment.configs)}"
        + (f", worlds/{deployment.worlds[0].name}" if deployment.worlds else "")
    )
    if tls:
        print(f"wrote {out / 'certs'}: ca, drone-1..drone-{drones}, observer (each container mounts its own key)")
    print(f"results will appear in {out / 'results'} (report.json when the mission ends)")
    build = "docker compose build" if build_context else f"swarm deploy image --tag {image} (in the swarm repository)"
    print(f"next: {build}; then cd {out} && docker compose up -d && docker compose wait observer (docs/deploy.md)")
    return 0
