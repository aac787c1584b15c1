"""Link-loss scenarios: TOML loading and its one-line errors, link specs, the timeline of profiles, the radio model
(no network, no root)."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from swarm.config import ConfigError
from swarm.netem import LinkProfile
from swarm.netem import scenario as scenario_module
from swarm.netem.scenario import (
    LinkState,
    RadioModel,
    Scenario,
    ScenarioEvent,
    combine,
    load_scenario,
    radio_profile,
    resolve_links,
    timeline,
)


def _docstring_example() -> str:
    """The example at the top of swarm.netem.scenario's docstring (so the documented file is the tested one)."""
    block = scenario_module.__doc__.split("\n\n")[1]
    return textwrap.dedent(block) + "\n"


CUT_AND_HEAL = _docstring_example()

CLEAN = LinkProfile()
CUT = LinkProfile(cut=True)


def write(tmp_path: Path, text: str, name: str = "scenario.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def scenario(*events: dict[str, object]) -> Scenario:
    return Scenario.model_validate({"name": "test", "event": list(events)})


# ----- loading -----


def test_example_loads_with_its_fields(tmp_path: Path) -> None:
    loaded = load_scenario(write(tmp_path, CUT_AND_HEAL))
    assert loaded.name == "cut-and-heal"
    assert [(e.at, e.link) for e in loaded.events] == [(30.0, "1-2"), (60.0, "3"), (100.0, "3")]
    first, second, third = loaded.events
    assert first.loss == 0.3 and first.cut is None and not first.restore
    assert first.profile() == LinkProfile(loss=0.3)
    assert second.cut is True and second.profile() == CUT
    assert third.restore and third.impairments() == [] and third.profile() == CLEAN
    assert loaded.radio == RadioModel(range_m=15.0, loss_at_range=0.5)


def test_events_are_sorted_by_time_keeping_file_order(tmp_path: Path) -> None:
    text = """\
name = "shuffled"
[[event]]
at = 50
link = "all"
loss = 0.1
[[event]]
at = 5
link = "1-2"
cut = true
[[event]]
at = 50
link = "2"
restore = true
"""
    loaded = load_scenario(write(tmp_path, text))
    assert [(e.at, e.link) for e in loaded.events] == [(5.0, "1-2"), (50.0, "all"), (50.0, "2")]
    assert loaded.radio is None


def test_a_scenario_may_have_no_events(tmp_path: Path) -> None:
    loaded = load_scenario(write(tmp_path, 'name = "radio only"\n[radio]\nrange_m = 20\nloss_at_range = 0.2\n'))
    assert loaded.events == [] and loaded.radio == RadioModel(range_m=20.0, loss_at_range=0.2)


EVENT = '[[event]]\nat = 1\nlink = "1-2"\n'


@pytest.mark.parametrize(
    ("body", "where"),
    [
        (f'name = "x"\n{EVENT}loss = 0.1\n[[event]]\nat = 2\nlink = "1-2"\nloss = 1.5\n', "event[1].loss"),
        ('name = "x"\n[[event]]\nat = -1\nlink = "1-2"\nloss = 0.1\n', "event[0].at"),
        ('name = "x"\n[[event]]\nat = "soon"\nlink = "1-2"\nloss = 0.1\n', "event[0].at"),
        ('name = "x"\n[[event]]\nat = 1\nlink = "1-1"\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nat = 1\nlink = "0"\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nat = 1\nlink = "0-3"\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nat = 1\nlink = "1-2-3"\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nat = 1\nlink = "everyone"\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nat = 1\nlink = 3\nloss = 0.1\n', "event[0].link"),
        ('name = "x"\n[[event]]\nlink = "1-2"\nloss = 0.1\n', "event[0].at"),
        (f'name = "x"\n{EVENT}rate_kbit = 10.5\n', "event[0].rate_kbit"),
        (f'name = "x"\n{EVENT}delay_ms = -3\n', "event[0].delay_ms"),
        (f'name = "x"\n{EVENT}los = 0.3\n', "event[0].los"),
        (f'name = "x"\n{EVENT}restore = true\nloss = 0.3\n', "event[0]: restore = true cannot be combined with loss"),
        (f'name = "x"\n{EVENT}restore = true\ncut = true\n', "event[0]: restore = true cannot be combined with cut"),
        (f'name = "x"\n{EVENT}', "event[0]: an event needs restore = true or at least one of"),
        (f'name = "x"\n{EVENT}restore = false\n', "event[0]: an event needs restore = true"),
        ('name = "x"\n[radio]\nrange_m = 0\n', "radio.range_m"),
        ('name = "x"\n[radio]\nrange_m = 10\nloss_at_range = 1.5\n', "radio.loss_at_range"),
        ('name = "x"\n[radio]\nrange = 10\n', "radio.range"),
        ('name = ""\n', "name: must not be empty"),
        (f"{EVENT}loss = 0.1\n", "name: Field required"),
        ('name = "x"\nduration = 10\n', "duration: unknown field"),
    ],
)
def test_invalid_scenarios_are_one_line_naming_file_and_field(tmp_path: Path, body: str, where: str) -> None:
    path = write(tmp_path, body, name="bad-scenario.toml")
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert where in message


def test_out_of_range_value_is_reported_as_in_the_issue(tmp_path: Path) -> None:
    path = write(tmp_path, f'name = "x"\n{EVENT}loss = 0.1\n[[event]]\nat = 2\nlink = "1-2"\nloss = 1.5\n')
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert str(info.value) == f"{path}: event[1].loss: Input should be less than or equal to 1 (got 1.5)"


def test_missing_file_and_bad_toml_are_one_line(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.toml"
    with pytest.raises(ConfigError) as info:
        load_scenario(missing)
    assert str(info.value) == f"scenario file {missing} does not exist"

    broken = write(tmp_path, 'name = "x"\n[[event]\nat = 1\n', name="broken.toml")
    with pytest.raises(ConfigError) as info:
        load_scenario(broken)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"scenario file {broken} is not valid TOML: ")


def test_check_drones_refuses_ids_beyond_the_swarm() -> None:
    loaded = scenario(
        {"at": 1, "link": "1-4", "loss": 0.2},
        {"at": 2, "link": "3", "cut": True},
        {"at": 3, "link": "all", "restore": True},
    )
    loaded.check_drones(4)
    with pytest.raises(ConfigError) as info:
        loaded.check_drones(3)
    message = str(info.value)
    assert "\n" not in message
    assert "drone 4" in message and "1-4" in message and "3 drones" in message
    with pytest.raises(ConfigError, match='link "3" names drone 3, but the swarm has 2 drones'):
        scenario({"at": 2, "link": "3", "cut": True}).check_drones(2)


# ----- link specs -----


def test_resolve_links_for_a_pair_a_drone_and_all() -> None:
    assert resolve_links("1-2", 4) == [(1, 2)]
    assert resolve_links("3-1", 4) == [(1, 3)]
    assert resolve_links("2", 4) == [(1, 2), (2, 3), (2, 4)]
    assert resolve_links("4", 4) == [(1, 4), (2, 4), (3, 4)]
    assert resolve_links("all", 4) == [(1, 2), (1, 3), (1, 4), (2, 3), (2, 4), (3, 4)]
    assert resolve_links("all", 1) == []


@pytest.mark.parametrize("link", ["1-5", "5", "2-2", "0", "x", ""])
def test_resolve_links_refuses_bad_or_absent_drones(link: str) -> None:
    with pytest.raises(ValueError):
        resolve_links(link, 4)


# ----- timeline -----


def expected(drones: int, **impaired: LinkProfile) -> dict[tuple[int, int], LinkProfile]:
    """Every pair clean except those given as p<a><b>=profile."""
    profiles = dict.fromkeys(resolve_links("all", drones), CLEAN)
    for key, profile in impaired.items():
        profiles[(int(key[1]), int(key[2]))] = profile
    return profiles


def test_cut_and_heal_timeline(tmp_path: Path) -> None:
    steps = timeline(load_scenario(write(tmp_path, CUT_AND_HEAL)), drones=4)
    lossy = LinkProfile(loss=0.3)
    assert steps == [
        (30.0, expected(4, p12=lossy)),
        (60.0, expected(4, p12=lossy, p13=CUT, p23=CUT, p34=CUT)),
        (100.0, expected(4, p12=lossy)),
    ]


def test_an_event_replaces_the_profile_rather_than_merging() -> None:
    steps = timeline(
        scenario(
            {"at": 1, "link": "1-2", "loss": 0.3, "rate_kbit": 100},
            {"at": 2, "link": "1-2", "cut": True},
            {"at": 3, "link": "2-1", "delay_ms": 20.0},
        ),
        drones=2,
    )
    assert [profiles[(1, 2)] for _, profiles in steps] == [
        LinkProfile(loss=0.3, rate_kbit=100),
        CUT,
        LinkProfile(delay_ms=20.0),
    ]


def test_node_and_all_events_override_pairs_and_restore_cleans() -> None:
    steps = timeline(
        scenario(
            {"at": 1, "link": "all", "loss": 0.1},
            {"at": 2, "link": "1-2", "cut": True},
            {"at": 3, "link": "2", "restore": True},
        ),
        drones=3,
    )
    light = LinkProfile(loss=0.1)
    assert steps[0][1] == expected(3, p12=light, p13=light, p23=light)
    assert steps[1][1] == expected(3, p12=CUT, p13=light, p23=light)
    assert steps[2][1] == expected(3, p13=light)


@pytest.mark.parametrize(("restore_first", "result"), [(True, CUT), (False, CLEAN)])
def test_events_at_the_same_time_are_one_step_in_file_order(restore_first: bool, result: LinkProfile) -> None:
    cut_all = {"at": 5, "link": "all", "cut": True}
    restore_pair = {"at": 5, "link": "1-2", "restore": True}
    events = [restore_pair, cut_all] if restore_first else [cut_all, restore_pair]
    steps = timeline(scenario(*events), drones=3)
    assert len(steps) == 1 and steps[0][0] == 5.0
    assert steps[0][1][(1, 2)] == result and steps[0][1][(1, 3)] == CUT


def test_timeline_refuses_drones_beyond_the_swarm() -> None:
    with pytest.raises(ConfigError, match="drone 3"):
        timeline(scenario({"at": 1, "link": "3", "cut": True}), drones=2)


def test_link_state_steps_are_independent_copies() -> None:
    state = LinkState(3)
    before = state.profiles()
    state.apply(ScenarioEvent(at=0, link="1-3", loss=0.5))
    assert before[(1, 3)] == CLEAN
    assert state.profile(3, 1) == LinkProfile(loss=0.5) and state.profile(1, 2) == CLEAN


# ----- radio -----


def test_radio_profile_grows_quadratically_then_cuts() -> None:
    radio = RadioModel(range_m=20.0, loss_at_range=0.4)
    assert radio_profile(radio, 0.0) == CLEAN
    assert radio_profile(radio, 10.0).loss == pytest.approx(0.4 / 4)
    assert not radio_profile(radio, 10.0).cut
    at_range = radio_profile(radio, 20.0)
    assert at_range.loss == pytest.approx(0.4) and not at_range.cut
    assert radio_profile(radio, 20.01).cut
    assert RadioModel(range_m=10.0).loss_at_range == 0.5
    with pytest.raises(ValueError):
        radio_profile(radio, -1.0)


def test_combine() -> None:
    assert combine(CLEAN, CLEAN) == CLEAN
    assert combine(LinkProfile(loss=0.5), LinkProfile(loss=0.5)).loss == pytest.approx(0.75)
    assert combine(LinkProfile(loss=0.2), CLEAN).loss == pytest.approx(0.2)
    assert combine(CUT, LinkProfile(loss=0.1)).cut and combine(CLEAN, CUT).cut
    assert combine(LinkProfile(rate_kbit=100), CLEAN).rate_kbit == 100
    assert combine(CLEAN, LinkProfile(rate_kbit=100)).rate_kbit == 100
    assert combine(LinkProfile(rate_kbit=100), LinkProfile(rate_kbit=50)).rate_kbit == 50
    both = combine(LinkProfile(delay_ms=10.0, jitter_ms=2.0), LinkProfile(delay_ms=5.0, jitter_ms=1.0))
    assert (both.delay_ms, both.jitter_ms) == (15.0, 3.0)
