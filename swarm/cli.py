"""The `swarm` command. Thin: it parses flags into a SwarmConfig and calls into the packages.

Every error a person can cause (bad flags, bad config, unusable world, port in use) is one line on stderr
and a non-zero exit: 2 for bad input (flags, config), 1 for anything else that stopped the command.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn, get_args

from swarm.config import ConfigError, Strategy, SwarmConfig, Vec3, load_config, parse_override
from swarm.errors import SwarmError

EXIT_FAILED, EXIT_BAD_INPUT = 1, 2

# what a subcommand runs: registered on its parser with set_defaults(handler=...), called by main
Handler = Callable[[argparse.Namespace], int]


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}\n")


def _vec3(text: str) -> Vec3:
    parts = text.split(",")
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"'{text}' is not x,y,z in metres")
    return values  # type: ignore[return-value]


def _int_at_least(minimum: int, text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < minimum:
        raise argparse.ArgumentTypeError(f"must be at least {minimum} (got {value})")
    return value


def _positive_int(text: str) -> int:
    return _int_at_least(1, text)


def _non_negative_int(text: str) -> int:
    return _int_at_least(0, text)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _int_list(text: str) -> list[int]:
    return [_positive_int(p) for p in text.split(",")]


STRATEGIES: tuple[str, ...] = get_args(Strategy)


def _strategy_list(text: str) -> list[str]:
    names = [p.strip() for p in text.split(",")]
    unknown = [n for n in names if n not in STRATEGIES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"unknown strategy {', '.join(unknown) or text!r} (use {', '.join(STRATEGIES)})"
        )
    return names


def _percent_list(text: str) -> list[float]:
    try:
        values = [float(p) for p in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a list of percentages, e.g. 0,10,30,50") from None
    if any(not 0.0 <= v < 100.0 for v in values):
        raise argparse.ArgumentTypeError(f"loss levels are percentages in [0, 100) (got {text})")
    return [v / 100.0 for v in values]


def _add_config_flags(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="TOML file with [mission], [agent], [sim], [bus] tables")
    p.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        help="override one setting (repeatable), e.g. --set agent.altitude_m=2.0",
    )


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="swarm", description="Drone swarms that explore and map buildings together.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    run = sub.add_parser("run", help="fly a simulated swarm in a world and write a report")
    run.set_defaults(handler=_run)
    run.add_argument("--drones", type=_positive_int, help="number of drones (default 3)")
    run.add_argument(
        "--world",
        help="built-in world (office, warehouse, box, atrium, hall), gen:SEED[:options] or a .ply/.obj/.stl mesh",
    )
    run.add_argument("--start", type=_vec3, help="take-off area x,y,z in world metres")
    run.add_argument("--out", type=Path, help="run directory (default runs/<time>-<world>)")
    run.add_argument("--max-time", type=float, dest="max_time", help="mission time limit in seconds")
    run.add_argument("--seed", type=int)
    run.add_argument(
        "--strategy",
        choices=STRATEGIES,
        help="how drones choose where to go (default coordinated: the cluster leader assigns targets)",
    )
    run.add_argument("--no-live", action="store_true", help="plain progress lines instead of a live table")
    run.add_argument(
        "--network",
        choices=("loopback", "netns"),
        help="netns: each agent in its own network namespace on a virtual radio (root)",
    )
    run.add_argument("--links", type=Path, help="link scenario TOML applied during the mission (needs --network netns)")
    run.add_argument(
        "--fault",
        action="append",
        metavar="SPEC",
        help="inject a fault (repeatable): kill:agent=K@T, restart:agent=K@T[+D], freeze:agent=K@T+D, "
        "telemetry-loss:agent=K@T+D (T: seconds after take-off; D: seconds)",
    )
    run.add_argument(
        "--tls",
        action="store_true",
        default=None,
        help="mutual TLS with access control on every Zenoh session (certificates in OUT/certs)",
    )
    run.add_argument(
        "--record",
        action="store_true",
        default=None,
        help="every agent records the sensor streams it received (depth, camera info, odometry) to "
        "OUT/bags/agent-K (ROS 2 MCAP)",
    )
    run.add_argument(
        "--no-rrd",
        dest="rrd",
        action="store_false",
        default=None,
        help="do not record the run to OUT/run.rrd (Rerun); it is recorded by default",
    )
    run.add_argument(
        "--view",
        nargs="?",
        const="native",
        metavar="MODE",
        help="stream the recording live to a Rerun viewer while the swarm flies: native (a window, the default), "
        "web (the web viewer at http://127.0.0.1:--view-port) or a running viewer's rerun+http://HOST:PORT/proxy",
    )
    run.add_argument("--view-port", type=_positive_int, help="with --view web: the web viewer's port (9090)")
    run.add_argument(
        "--view-depth",
        action="store_true",
        default=None,
        help="record each drone's depth image too (once a second, OUT/cameras.rrd)",
    )
    _add_config_flags(run)

    view = sub.add_parser("view", help="open a finished run's recording (OUT/*.rrd) in the Rerun viewer")
    view.set_defaults(handler=_view)
    view.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a swarm run output directory")
    view.add_argument(
        "--web",
        action="store_true",
        help="serve the web viewer instead (for a machine without a display); runs until Ctrl-C",
    )
    view.add_argument("--port", type=_positive_int, default=9090, help="with --web: the web viewer's port")
    view.add_argument(
        "--screenshot",
        type=Path,
        metavar="PNG",
        help="write a picture of the web viewer showing the run, taken by headless Chromium (software WebGL), and exit",
    )
    view.add_argument(
        "--wait", type=_positive_float, default=45.0, help="with --screenshot: seconds to let the viewer load (45)"
    )

    export = sub.add_parser("export", help="export a finished run for other tools")
    export.set_defaults(handler=_export)
    export.add_argument("run_dir", type=Path, metavar="RUN_DIR", help="a swarm run output directory")
    export.add_argument(
        "--mcap",
        type=Path,
        required=True,
        metavar="OUT.mcap",
        help="write a ROS 2 bag (MCAP): poses as nav_msgs/Odometry, the map as sensor_msgs/PointCloud2, targets",
    )

    cameras = sub.add_parser("cameras", help="the simulated depth cameras as ROS 2 camera drivers over Zenoh")
    cameras.set_defaults(handler=_cameras)
    cameras.add_argument("--world", help="built-in world or mesh path")
    cameras.add_argument("--vehicles", type=_positive_int, help="number of vehicles (cameras /drone1 ... /droneN)")
    cameras.add_argument("--record", type=Path, help="write each drone's depth image once a second to this .rrd")
    cameras.add_argument("--recording-id", help="the run's recording id (with --record)")
    cameras.add_argument("--since", type=float, help="with --record: the Unix time the mission clock counts from")
    cameras.add_argument("--stream-to", metavar="URL", help="with --record: also stream to this Rerun viewer")
    _add_config_flags(cameras)

    bagmap = sub.add_parser("map", help="map recorded sensor bags offline (one drone per bag), fused into one map")
    bagmap.set_defaults(handler=_map)
    bagmap.add_argument("bags", nargs="+", type=Path, help="ROS 2 bag directories (MCAP or sqlite3) or ROS 1 .bag")
    bagmap.add_argument("--out", type=Path, required=True, help="where patches, map.ply and report.json go")
    bagmap.add_argument("--depth-topic", help="the sensor_msgs/Image topic (default: the bag's only one)")
    bagmap.add_argument("--info-topic", help="the sensor_msgs/CameraInfo topic (default: the bag's only one)")
    bagmap.add_argument("--pose-topic", help="the Odometry or PoseStamped topic (default: the bag's only one)")
    _add_config_flags(bagmap)

    sim = sub.add_parser("sim", help="run the simulated vehicles alone (MAVLink over UDP)")
    sim.set_defaults(handler=_sim)
    sim.add_argument("--world", help="built-in world or mesh path")
    sim.add_argument("--vehicles", type=_positive_int, help="number of vehicles")
    sim.add_argument("--start", type=_vec3, help="take-off area x,y,z")
    _add_config_flags(sim)

    world = sub.add_parser("world", help="load or generate a world: size, storeys, start, triangles; write its mesh")
    world.set_defaults(handler=_world)
    world.add_argument(
        "spec", help="built-in world, gen:SEED[:size=WxD,storeys=N,rooms=N,furniture=0|1,doors=MIN-MAX] or mesh"
    )
    world.add_argument("--out", type=Path, help="write the mesh to this .ply/.obj/.stl file")

    agent = sub.add_parser("agent", help="run one drone's agent (next to a real or simulated autopilot)")
    agent.set_defaults(handler=_agent)
    agent.add_argument("--id", type=_positive_int, help="drone id (also its MAVLink system id)")
    agent.add_argument("--autopilot", help="MAVSDK connection URL, e.g. udpin://0.0.0.0:14540")
    agent.add_argument(
        "--check",
        action="store_true",
        help="connect, read the vehicle's health and failsafe parameters, say whether the agent would fly, "
        "and exit (0 ready, 1 not) without arming or writing anything",
    )
    _add_config_flags(agent)

    observe = sub.add_parser("observe", help="follow a swarm on the bus and write its status")
    observe.set_defaults(handler=_observe)
    observe.add_argument("--status", type=Path, required=True, help="status JSON to (re)write")
    observe.add_argument("--patches", type=Path, help="directory of sealed patches to fuse into the swarm's map")
    observe.add_argument("--map", type=Path, help="where to write the swarm's fused mesh (.ply) at the end")
    observe.add_argument("--since", type=float, help="the Unix time its clock counts from (default: its start)")
    observe.add_argument("--record", type=Path, help="write a Rerun recording (.rrd) of what it observes there")
    observe.add_argument("--recording-id", help="the run's recording id (with --record)")
    observe.add_argument("--stream-to", metavar="URL", help="with --record: also stream to this Rerun viewer")
    _add_config_flags(observe)

    node = sub.add_parser("mapnode", help="a map-sharing node without a vehicle (sync experiments and tests)")
    node.set_defaults(handler=_mapnode)
    node.add_argument("--id", type=_positive_int, help="node id (as a drone id)")
    node.add_argument("--status", type=Path, required=True, help="status JSON to (re)write")
    node.add_argument("--patches", type=_non_negative_int, default=3, help="patches to seal (default 3)")
    node.add_argument("--period", type=float, default=0.5, help="seconds between seals (default 0.5)")
    node.add_argument("--delay", type=float, default=0.0, help="seconds before the first seal")
    node.add_argument("--position", type=_vec3, help="position to announce, x,y,z (default: the camera's)")
    _add_config_flags(node)

    bench = sub.add_parser("bench", help="benchmarks that print their figures")
    bench_sub = bench.add_subparsers(dest="bench", required=True, parser_class=_Parser)
    flight = bench_sub.add_parser("flight", help="CPU and memory per process for swarms of several sizes")
    flight.set_defaults(handler=_bench_flight)
    flight.add_argument("--drones", type=_int_list, default=[1, 3, 5], help="swarm sizes, e.g. 1,3,5")
    flight.add_argument("--world", default="office")
    flight.add_argument("--out", type=Path, help="where to keep the runs (default a temp dir)")
    _add_config_flags(flight)
    mapping = bench_sub.add_parser("mapping", help="mapping costs on one core, and frame rates of N agents at once")
    mapping.set_defaults(handler=_bench_mapping)
    mapping.add_argument("--drones", type=_positive_int, default=5, help="agents mapping at once (default 5)")
    mapping.add_argument("--world", default="office")
    mapping.add_argument("--out", type=Path, help="where to keep the figures (default a temp dir)")
    _add_config_flags(mapping)
    sync = bench_sub.add_parser("sync", help="patch sharing: seal-to-everyone latency, heal convergence, bandwidth")
    sync.set_defaults(handler=_bench_sync)
    sync.add_argument("--drones", type=_int_list, default=[3, 5], help="swarm sizes, e.g. 3,5")
    sync.add_argument("--world", default="office")
    sync.add_argument("--no-mission", action="store_true", help="skip the bandwidth missions (swarm run)")
    sync.add_argument("--out", type=Path, help="where to keep the runs (default a temp dir)")
    _add_config_flags(sync)
    fleet = bench_sub.add_parser(
        "fleet", help="exploring swarms of growing size: CPU, memory, camera rate and stage costs of every agent"
    )
    fleet.set_defaults(handler=_bench_fleet)
    fleet.add_argument("--drones", type=_int_list, default=[5, 8, 10, 12], help="swarm sizes, e.g. 5,8,10,12")
    fleet.add_argument("--world", default="office")
    fleet.add_argument("--profile", action="store_true", help="a py-spy profile of agent 1 in each run's directory")
    fleet.add_argument("--out", type=Path, help="where to keep the runs (default a temp dir)")
    _add_config_flags(fleet)
    explore = bench_sub.add_parser("explore", help="time to 95 %% with 1..N drones, coordinated vs uncoordinated")
    explore.set_defaults(handler=_bench_explore)
    explore.add_argument("--drones", type=_int_list, default=[1, 2, 3], help="swarm sizes, e.g. 1,2,3,5")
    explore.add_argument(
        "--strategies",
        type=_strategy_list,
        default=["coordinated", "uncoordinated"],
        help="comma-separated, e.g. coordinated,uncoordinated,frontier-only",
    )
    explore.add_argument("--world", help="one world (default office)")
    explore.add_argument(
        "--worlds",
        help="several: SPEC[,SPEC...], a spec a built-in name, a mesh file or "
        "gen:A..B[:options] (generated worlds A to B)",
    )
    explore.add_argument(
        "--repeat",
        type=_positive_int,
        default=1,
        help="missions per strategy and size (the table gives medians and ranges; default 1)",
    )
    explore.add_argument("--out", type=Path, help="where to keep the runs (default a temp dir)")
    explore.add_argument(
        "--resume",
        action="store_true",
        help="keep the missions already flown to their end in "
        "--out (same world, drones, strategy and seed) and fly only the rest",
    )
    _add_config_flags(explore)

    experiment = sub.add_parser("experiment", help="several missions compared, with a table and figures")
    experiment_sub = experiment.add_subparsers(dest="experiment", required=True, parser_class=_Parser)
    dropout = experiment_sub.add_parser(
        "dropout", help="the same netns mission at several link loss levels and with a cut-and-heal (root)"
    )
    dropout.set_defaults(handler=_experiment_dropout)
    dropout.add_argument(
        "--levels",
        type=_percent_list,
        default=[0.0, 0.1, 0.3, 0.5],
        help="loss on every link in %%, e.g. 0,10,30,50 (0, the baseline, is always run)",
    )
    dropout.add_argument("--no-cut", action="store_true", help="skip the cut-and-heal")
    dropout.add_argument(
        "--cut-at",
        type=float,
        default=20.0,
        help="seconds after take-off the highest-numbered drone is cut off (default 20)",
    )
    dropout.add_argument(
        "--heal-at", type=float, default=50.0, help="seconds after take-off its links come back (default 50)"
    )
    dropout.add_argument("--drones", type=_positive_int, help="swarm size (default 3)")
    dropout.add_argument("--world", default="office")
    dropout.add_argument("--out", type=Path, help="where to keep the runs (default a temp dir)")
    _add_config_flags(dropout)

    soak = sub.add_parser("soak", help="missions back to back with random faults and loss: memory, fds, patches lost")
    soak.set_defaults(handler=_soak)
    soak.add_argument("--minutes", type=float, required=True, help="wall time to keep starting missions")
    soak.add_argument("--drones", type=_positive_int, help="drones per mission (default 3)")
    soak.add_argument("--world", default="box", help="built-in world or mesh (default box)")
    soak.add_argument("--out", type=Path, help="where to keep the missions and soak.json (default runs/soak-<time>)")
    soak.add_argument("--seed", type=int, default=0, help="seed of the random faults and loss levels")
    _add_config_flags(soak)

    deploy = sub.add_parser("deploy", help="the simulated swarm as containers, Docker or Podman (docs/deploy.md)")
    deploy_sub = deploy.add_subparsers(dest="deploy", required=True, parser_class=_Parser)
    compose = deploy_sub.add_parser("compose", help="write a docker-compose file: simulator, N agents, observer")
    compose.set_defaults(handler=_deploy_compose)
    compose.add_argument("--drones", type=_positive_int, help="number of agents, 1 to 16 (default 3)")
    compose.add_argument(
        "--loss", type=float, default=0.0, help="radio loss on every link, each way, as a fraction 0..1 (default 0)"
    )
    compose.add_argument(
        "--out",
        type=Path,
        default=Path("swarm-compose"),
        help="directory to write, new or empty (default swarm-compose)",
    )
    compose.add_argument("--world", help="built-in world or a .ply/.obj/.stl mesh (copied next to the configs)")
    compose.add_argument(
        "--image", default="swarm-agent", help="the image built by swarm deploy image (or from deploy/Dockerfile)"
    )
    compose.add_argument(
        "--build-context",
        type=Path,
        dest="build_context",
        help="the swarm repository: docker compose builds the image itself",
    )
    compose.add_argument(
        "--tls",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="mutual TLS with access control on every Zenoh session (the default; --no-tls for plain TCP): "
        "certificates in OUT/certs, each container mounts only its own key",
    )
    _add_config_flags(compose)
    image = deploy_sub.add_parser("image", help="build the swarm image from Debian packages and PyPI (no registry)")
    image.set_defaults(handler=_deploy_image)
    image.add_argument(
        "--engine", choices=("auto", "podman", "docker"), default="auto", help="default: podman if present"
    )
    image.add_argument("--tag", default="swarm-agent", help="image name (default swarm-agent)")
    image.add_argument("--repo", type=Path, default=Path("."), help="the swarm repository (default: here)")
    image.add_argument("--force", action="store_true", help="rebuild even when the image holds these sources")
    image.add_argument(
        "--ca-bundle",
        type=Path,
        dest="ca_bundle",
        help="CA bundle pip trusts during the build (default $PIP_CERT, else $SSL_CERT_FILE, else none)",
    )
    mission = deploy_sub.add_parser(
        "mission", help="in the observer container: observe, end with the agents, write report.json"
    )
    mission.set_defaults(handler=_deploy_mission)
    mission.add_argument("--config", type=Path, required=True, help="the observer's config (observer.toml)")
    mission.add_argument("--results", type=Path, required=True, help="the results directory shared by all")
    wait_sim = deploy_sub.add_parser("wait-sim", help="in a container: wait until the simulator says it is ready")
    wait_sim.set_defaults(handler=_deploy_wait_sim)
    wait_sim.add_argument("--status", type=Path, required=True, help="the simulator's status file (sim.json)")
    wait_sim.add_argument("--timeout", type=float, default=300.0, help="seconds (default 300)")
    certs = deploy_sub.add_parser("certs", help="a CA and per-drone certificates for mutual TLS (bus.tls_dir)")
    certs.set_defaults(handler=_deploy_certs)
    certs.add_argument("--drones", type=_positive_int, required=True, help="certificates for drones 1..N")
    certs.add_argument(
        "--out",
        type=Path,
        default=Path("swarm-certs"),
        help="directory to write; must not hold a CA yet (default swarm-certs)",
    )
    certs.add_argument("--days", type=_positive_int, default=365, help="validity in days (default 365)")
    radio = deploy_sub.add_parser("netem", help="impair this container's radio interface with tc netem")
    radio.set_defaults(handler=_deploy_netem)
    radio.add_argument("--address", required=True, help="IP address of the radio interface")
    radio.add_argument("--loss", type=float, default=0.0, help="loss fraction 0..1 on egress (default 0)")
    radio.add_argument("--delay-ms", type=float, default=0.0, dest="delay_ms", help="added delay (default 0)")
    radio.add_argument("--jitter-ms", type=float, default=0.0, dest="jitter_ms", help="delay jitter (default 0)")
    radio.add_argument(
        "--backend",
        default="auto",
        choices=("auto", "netem", "nftables"),
        help="auto (default): tc netem, nftables (loss only) where the kernel has no sch_netem",
    )
    radio.add_argument("--record", type=Path, help="write what was applied here (JSON)")

    netem = sub.add_parser("netem", help="a virtual swarm radio kept up by hand: namespaces + nftables (root)")
    netem_sub = netem.add_subparsers(dest="netem", required=True, parser_class=_Parser)
    n_up = netem_sub.add_parser("up", help="create a network that stays until `swarm netem down`")
    n_up.set_defaults(handler=_netem_up)
    n_up.add_argument("--nodes", type=_positive_int, required=True, help="number of nodes (1 to 200)")
    n_up.add_argument("--name", default="default", help="network name (default: default)")
    n_show = netem_sub.add_parser("show", help="nodes, addresses, impairments in force and nft rules")
    n_show.set_defaults(handler=_netem_show)
    n_show.add_argument("--name", default="default", help="network name (default: default)")
    n_apply = netem_sub.add_parser("apply", help="impair or restore links, or apply a scenario's state at a time")
    n_apply.set_defaults(handler=_netem_apply)
    n_apply.add_argument("link", nargs="?", help='"a-b" (one pair), "k" (all links of node k) or "all"')
    n_apply.add_argument("--name", default="default", help="network name (default: default)")
    n_apply.add_argument("--loss", help="drop probability each way: a fraction (0.3) or a percentage (30%%)")
    n_apply.add_argument("--cut", action="store_true", help="drop everything")
    n_apply.add_argument(
        "--rate-kbit",
        dest="rate_kbit",
        type=_non_negative_int,
        help="rate limit in kbit/s each way (a node or all; not a pair)",
    )
    n_apply.add_argument("--delay-ms", dest="delay_ms", type=float, help="refused: needs sch_netem")
    n_apply.add_argument("--jitter-ms", dest="jitter_ms", type=float, help="refused: needs sch_netem")
    n_apply.add_argument(
        "--restore", action="store_true", help="remove LINK's own profile (all: every profile, all links clean)"
    )
    n_apply.add_argument("--scenario", type=Path, help="scenario TOML: make its state at --at T the whole table")
    n_apply.add_argument("--at", type=float, metavar="T", help="seconds after take-off (with --scenario)")
    n_down = netem_sub.add_parser("down", help="remove a network: processes inside, namespaces, links, state file")
    n_down.set_defaults(handler=_netem_down)
    n_target = n_down.add_mutually_exclusive_group()
    n_target.add_argument("--name", default="default", help="network name (default: default)")
    n_target.add_argument("--all", action="store_true", help="every manual network, orphans included")
    return parser


def _config_from(args: argparse.Namespace, flags: dict[str, Any]) -> SwarmConfig:
    overrides: dict[str, Any] = dict(parse_override(o) for o in args.overrides)
    overrides.update({k: v for k, v in flags.items() if v is not None})
    return load_config(args.config, overrides)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # SIGTERM ends a command as Ctrl-C does, so missions land their drones and take their network namespaces
    # down (an agent installs its own handlers later)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, signal.default_int_handler)
    handler: Handler = args.handler
    try:
        return handler(args)
    except ConfigError as exc:
        print(f"swarm {args.command}: config error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SwarmError as exc:
        print(f"swarm {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        return 130


def _run(args: argparse.Namespace) -> int:
    config = _config_from(
        args,
        {
            "mission.drones": args.drones,
            "mission.world": args.world,
            "mission.start": args.start,
            "mission.out": str(args.out) if args.out else None,
            "mission.max_time_s": args.max_time,
            "mission.seed": args.seed,
            "explore.strategy": args.strategy,
            "mission.network": args.network,
            "mission.links": str(args.links) if args.links else None,
            "mission.faults": args.fault,
            "mission.tls": args.tls,
            "mission.record": args.record,
            "mission.rrd": args.rrd,
            "mission.view": args.view,
            "mission.view_port": args.view_port,
            "mission.view_depth": args.view_depth,
        },
    )
    if config.mission.view and not config.mission.rrd:
        raise ConfigError("--view needs the recording (drop --no-rrd or mission.rrd = false)")
    from swarm.mission.run import run_mission
    from swarm.mission.viewer import LiveViewer

    viewer = LiveViewer(config.mission.view, config.mission.view_port) if config.mission.view else None
    try:
        if viewer is not None:
            viewer.start()
        report = run_mission(
            config, live=False if args.no_live else None, stream_to=viewer.url if viewer is not None else None
        )
        _print_summary(report)
        if viewer is not None:
            viewer.wait()  # the mission's outcome decides the exit code, not the viewer
    finally:
        if viewer is not None:
            viewer.close()
    return 0 if report["status"] == "complete" else EXIT_FAILED


def _view(args: argparse.Namespace) -> int:
    from swarm.mission.viewer import screenshot_run, serve_run, view_run

    if args.screenshot is not None:
        print(f"{screenshot_run(args.run_dir, args.screenshot, args.wait)}: the web viewer after {args.wait:g} s")
        return 0
    code = serve_run(args.run_dir, args.port) if args.web else view_run(args.run_dir)
    return EXIT_FAILED if code else 0


def _export(args: argparse.Namespace) -> int:
    from swarm.mission.export import export_mcap

    counts = export_mcap(args.run_dir, args.mcap)
    print(f"{args.mcap}: " + ", ".join(f"{topic} {n}" for topic, n in sorted(counts.items())))
    return 0


def _map(args: argparse.Namespace) -> int:
    from swarm.agent.bagmap import map_bags

    report = map_bags(
        _config_from(args, {}),
        args.bags,
        args.out,
        {"depth": args.depth_topic, "info": args.info_topic, "pose": args.pose_topic},
    )
    for bag in report["bags"]:
        dropped = ", ".join(f"{n} {why}" for why, n in bag["dropped"].items()) or "none dropped"
        print(f"{bag['bag']}: {bag['frames']} frames, {bag['patches']} patches ({dropped})")
    print(
        f"map: {args.out / 'map.ply'} ({report['mesh']['vertices']} vertices, {report['known_voxels']} known "
        f"voxels); report: {args.out / 'report.json'}"
    )
    return 0


def _cameras(args: argparse.Namespace) -> int:
    from swarm.sim.sensors import cameras_command

    config = _config_from(args, {"mission.world": args.world, "mission.drones": args.vehicles})
    if args.record is None:
        return cameras_command(config)
    from swarm.mission.recording import DepthRecording
    from swarm.sim.camera import intrinsics  # Rerun's convention too: pixel centres at +0.5

    camera = config.camera
    since = args.since if args.since is not None else time.time()
    recording_id = args.recording_id or f"{args.record.stem}-{round(since * 1000)}"
    recording = DepthRecording(
        args.record, recording_id, since, intrinsics(camera), (camera.width, camera.height), args.stream_to
    )
    try:
        return cameras_command(config, on_frame=recording.frame)
    finally:
        recording.close()


def _sim(args: argparse.Namespace) -> int:
    config = _config_from(
        args, {"mission.world": args.world, "mission.drones": args.vehicles, "mission.start": args.start}
    )
    from swarm.sim.server import sim_command

    return sim_command(config)


def _world(args: argparse.Namespace) -> int:
    from swarm.sim.worlds import world_command

    return world_command(args.spec, args.out)


def _agent(args: argparse.Namespace) -> int:
    config = _config_from(args, {"agent.id": args.id, "agent.autopilot": args.autopilot})
    if args.check:
        from swarm.agent.preflight import preflight_command

        return preflight_command(config)
    from swarm.agent.main import agent_command

    return agent_command(config)


def _observe(args: argparse.Namespace) -> int:
    from swarm.mission.observer import observe_command

    return observe_command(
        _config_from(args, {}),
        args.status,
        args.patches,
        args.map,
        args.since,
        args.record,
        args.recording_id,
        args.stream_to,
    )


def _mapnode(args: argparse.Namespace) -> int:
    if args.period <= 0 or args.delay < 0:
        raise ConfigError("--period must be positive and --delay not negative")
    from swarm.mission.mapnode import NodePlan, mapnode_command

    config = _config_from(args, {"agent.id": args.id})
    plan = NodePlan(args.patches, args.period, args.delay, args.position)
    return mapnode_command(config, plan, args.status)


def _bench_flight(args: argparse.Namespace) -> int:
    from swarm.mission.bench import bench_flight

    return bench_flight(_config_from(args, {"mission.world": args.world}), args.drones, args.out)


def _bench_mapping(args: argparse.Namespace) -> int:
    from swarm.mission.bench import bench_mapping_swarm
    from swarm.mission.bench_mapping import bench_mapping

    config = _config_from(args, {"mission.world": args.world})
    single = bench_mapping(config, args.out)
    return bench_mapping_swarm(config, args.drones, args.out) or single


def _bench_sync(args: argparse.Namespace) -> int:
    from swarm.mission.bench_sync import bench_sync

    config = _config_from(args, {"mission.world": args.world})
    return bench_sync(config, args.drones, args.out, mission=not args.no_mission)


def _bench_fleet(args: argparse.Namespace) -> int:
    from swarm.mission.bench_fleet import bench_fleet

    return bench_fleet(_config_from(args, {"mission.world": args.world}), args.drones, args.out, profile=args.profile)


def _bench_explore(args: argparse.Namespace) -> int:
    from swarm.mission.bench_explore import bench_explore, expand_worlds

    if args.world and args.worlds:
        raise ConfigError("give --world or --worlds, not both")
    if args.resume and args.out is None:
        raise ConfigError("--resume needs the --out of the bench to resume")
    worlds = expand_worlds(args.worlds) if args.worlds else None
    config = _config_from(args, {"mission.world": args.world or (worlds[0] if worlds else None)})
    return bench_explore(
        config, args.drones, args.strategies, args.out, repeats=args.repeat, worlds=worlds, resume=args.resume
    )


def _experiment_dropout(args: argparse.Namespace) -> int:
    from swarm.mission.experiment import experiment_dropout

    config = _config_from(args, {"mission.world": args.world, "mission.drones": args.drones})
    return experiment_dropout(config, args.levels, not args.no_cut, args.out, args.cut_at, args.heal_at)


def _soak(args: argparse.Namespace) -> int:
    from swarm.mission.soak import soak_command

    config = _config_from(args, {"mission.world": args.world, "mission.drones": args.drones})
    return soak_command(config, args.minutes, args.out, args.seed)


def _deploy_compose(args: argparse.Namespace) -> int:
    from swarm.deploy.compose import deploy_compose_command

    config = _config_from(args, {"mission.world": args.world})
    drones = args.drones if args.drones is not None else config.mission.drones
    return deploy_compose_command(config, drones, args.loss, args.out, args.image, args.build_context, args.tls)


def _deploy_image(args: argparse.Namespace) -> int:
    from swarm.deploy.image import deploy_image_command

    return deploy_image_command(args.repo, args.tag, args.engine, args.force, args.ca_bundle)


def _deploy_wait_sim(args: argparse.Namespace) -> int:
    from swarm.deploy.mission import wait_sim_command

    return wait_sim_command(args.status, args.timeout)


def _deploy_mission(args: argparse.Namespace) -> int:
    from swarm.deploy.mission import deploy_mission_command

    return deploy_mission_command(load_config(args.config), args.config, args.results)


def _deploy_certs(args: argparse.Namespace) -> int:
    from swarm.deploy.certs import certs_command

    return certs_command(args.out, args.drones, args.days)


def _deploy_netem(args: argparse.Namespace) -> int:
    from swarm.deploy.radio import deploy_netem_command

    return deploy_netem_command(args.address, args.loss, args.delay_ms, args.jitter_ms, args.backend, args.record)


def _netem_up(args: argparse.Namespace) -> int:
    from swarm.netem.manual import netem_up

    return netem_up(args.nodes, args.name)


def _netem_show(args: argparse.Namespace) -> int:
    from swarm.netem.manual import netem_show

    return netem_show(args.name)


def _netem_apply(args: argparse.Namespace) -> int:
    from swarm.netem.manual import netem_apply

    return netem_apply(
        args.name,
        args.link,
        loss=args.loss,
        cut=args.cut,
        rate_kbit=args.rate_kbit,
        restore=args.restore,
        delay_ms=args.delay_ms,
        jitter_ms=args.jitter_ms,
        scenario=args.scenario,
        at=args.at,
    )


def _netem_down(args: argparse.Namespace) -> int:
    from swarm.netem.manual import netem_down

    return netem_down(args.name, args.all)


def _print_summary(report: dict[str, Any]) -> None:
    agents = report["agents"]
    landed = sum(1 for a in agents if a["landed"])
    print(
        f"{report['status']}: {report['drones']} drones in '{report['world']}' for {report['duration_s']:.1f} s, "
        f"collisions {report['collisions']}, landed {landed}/{len(agents)}, "
        f"explored {100 * report['explored_fraction']:.1f} % — {report['reason']}"
    )
    for a in agents:
        print(
            f"  drone {a['id']}: flew {a['distance_m']:.1f} m, {a['patches_sealed']} patches sealed, "
            f"{a['patches_held']} held, sent {a['bytes_sent']} B, received {a['bytes_received']} B, {a['phase']}"
        )
    t95 = report.get("time_to", {}).get("0.95")
    print(
        f"exploration: {report.get('mission', {}).get('strategy', '?')}, 95 % explored "
        f"{f'at {t95:.1f} s' if t95 is not None else 'never'}, overlap {report.get('overlap_fraction', 0.0):.2f}, "
        f"{len(report.get('leaders', []))} leader timeline entries; "
        f"figures in {report.get('report_page') or 'report.json'}"
    )
    bandwidth = report["bandwidth"]
    print(
        f"map sharing: converged {'yes' if report['converged'] else 'NO'}, "
        f"{bandwidth['bytes_per_agent_s'] / 1000:.1f} kB per agent-second "
        f"(whole-map baseline every {bandwidth['baseline_loop_s']} s: "
        f"{bandwidth['whole_map_baseline_bytes_per_agent_s'] / 1000:.1f} kB, ratio {bandwidth['baseline_ratio']})"
    )
    if report.get("map"):
        phantoms = report.get("phantoms") or {}
        check = (
            (
                f" ({phantoms['vertices']} vertices; {phantoms['phantoms']} phantom obstacles along the flown paths, "
                f"of {phantoms['near_paths']} vertices near them)"
            )
            if phantoms
            else ""
        )
        print(f"map: {Path(report['run_dir']) / report['map']}{check}")
    print(f"report: {Path(report['run_dir']) / 'report.json'}")
