import pytest

from swarm.bus.keys import Keys


def test_layout() -> None:
    keys = Keys("office-1")
    assert keys.root == "swarm/office-1"
    assert keys.state(3) == "swarm/office-1/agent/3/state"
    assert keys.all_states == "swarm/office-1/agent/*/state"
    assert keys.alive(250) == "swarm/office-1/alive/250"
    assert keys.all_alive == "swarm/office-1/alive/*"


@pytest.mark.parametrize("agent_id", [1, 7, 42, 250])
def test_agent_id_round_trips(agent_id: int) -> None:
    keys = Keys("m")
    assert keys.agent_id_of(keys.state(agent_id)) == agent_id
    assert keys.agent_id_of(keys.alive(agent_id)) == agent_id


@pytest.mark.parametrize(
    "key",
    [
        "swarm/other/agent/3/state",  # another mission
        "swarm/m/agent/03/state",  # not canonical
        "swarm/m/agent/0/state",
        "swarm/m/agent/251/state",
        "swarm/m/agent/-1/state",
        "swarm/m/agent/+1/state",
        "swarm/m/agent/1000/state",
        "swarm/m/agent/abc/state",
        "swarm/m/agent/*/state",
        "swarm/m/agent/3/state/x",
        "swarm/m/agent/3",
        "swarm/m/alive/3/x",
        "swarm/m/alive/",
        "swarm/m/agent/3/bogus",  # an agent key of no known kind
        "xswarm/m/alive/3",
        "",
    ],
)
def test_agent_id_of_rejects_malformed_keys(key: str) -> None:
    assert Keys("m").agent_id_of(key) is None


def test_agent_id_of_non_string() -> None:
    assert Keys("m").agent_id_of(None) is None  # type: ignore[arg-type]


@pytest.mark.parametrize("name", ["", "a/b", "a*", "**", "a b", "x" * 65, "é", "a$", None, 3])
def test_invalid_mission_names_rejected(name: object) -> None:
    with pytest.raises(ValueError):
        Keys(name)  # type: ignore[arg-type]


@pytest.mark.parametrize("agent_id", [0, 251, -1, True, "1", 1.0])
def test_invalid_ids_rejected(agent_id: object) -> None:
    keys = Keys("m")
    with pytest.raises(ValueError):
        keys.state(agent_id)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        keys.alive(agent_id)  # type: ignore[arg-type]
