from pathlib import Path

import pytest

from swarm.config import ConfigError, SwarmConfig, dump_config, load_config, parse_override


def test_defaults_are_valid() -> None:
    config = load_config()
    assert config.mission.drones == 3
    assert config.agent.heartbeat_hz >= 5
    assert not config.bus.shared_memory and not config.bus.multicast_scouting


def test_toml_file_and_overrides_layer_in_order(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text('[mission]\ndrones = 5\nworld = "warehouse"\n[agent]\naltitude_m = 2.0\n')
    config = load_config(path, {"mission.drones": 2, "agent.waypoints": [[1, 2, 3]]})
    assert config.mission.drones == 2
    assert config.mission.world == "warehouse"
    assert config.agent.altitude_m == 2.0
    assert config.agent.waypoints == [(1.0, 2.0, 3.0)]


@pytest.mark.parametrize(
    ("overrides", "needle"),
    [
        ({"mission.drones": 0}, "mission.drones"),
        ({"agent.altitude_m": -1}, "agent.altitude_m"),
        ({"agent.nonsense": 1}, "agent.nonsense: unknown setting"),
        ({"mission.name": "has space"}, "mission.name"),
        ({"agent.autopilot": "bogus"}, "MAVSDK connection URL"),
        ({"mission.volume": {"min": [0, 0, 0], "max": [1, -1, 1]}}, "below max"),
        ({"agent.heartbeat_hz": 1}, "agent.heartbeat_hz"),
    ],
)
def test_invalid_values_are_one_line_naming_the_field(overrides: dict, needle: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_config(None, overrides)
    message = str(err.value)
    assert needle in message
    assert "\n" not in message


def test_bad_files_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[mission\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)


def test_parse_override_reads_toml_values_and_falls_back_to_strings() -> None:
    assert parse_override("mission.start=[1, 2, 0]") == ("mission.start", [1, 2, 0])
    assert parse_override("agent.altitude_m=2.5") == ("agent.altitude_m", 2.5)
    assert parse_override("mission.world=office") == ("mission.world", "office")
    with pytest.raises(ConfigError):
        parse_override("no-equals-sign")


def test_dump_round_trips() -> None:
    config = load_config(None, {"mission.start": [1, 2, 0], "agent.waypoints": [[0, 0, 1]]})
    assert SwarmConfig.model_validate(dump_config(config)) == config


def test_the_default_time_limit_grows_with_the_mission_volume_per_drone() -> None:
    from swarm.config import DEFAULT_MAX_TIME_S, MAX_TIME_S_PER_M3_PER_DRONE

    mission = load_config(overrides={"mission.drones": 1}).mission
    assert mission.max_time_s is None
    assert mission.time_limit_s(100.0) == DEFAULT_MAX_TIME_S  # small worlds: the floor
    assert mission.time_limit_s(6400.0) == 6400.0 * MAX_TIME_S_PER_M3_PER_DRONE
    three = load_config(overrides={"mission.drones": 3}).mission
    assert three.time_limit_s(6400.0) == pytest.approx(6400.0 * MAX_TIME_S_PER_M3_PER_DRONE / 3)
    given = load_config(overrides={"mission.drones": 1, "mission.max_time_s": 90.0}).mission
    assert given.time_limit_s(6400.0) == 90.0


def test_vec3_makes_three_plain_floats_of_any_three_numbers_and_refuses_another_count() -> None:
    import numpy as np

    from swarm.config import vec3

    made = vec3(np.array([1, 2, 3.5]))
    assert made == (1.0, 2.0, 3.5) and all(type(c) is float for c in made)
    assert vec3(c * 2 for c in (1, 2, 3)) == (2.0, 4.0, 6.0)
    with pytest.raises(ValueError):
        vec3([1.0, 2.0])
