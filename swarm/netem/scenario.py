"""Link-loss experiment scenarios: which links of the swarm degrade, when, and how, read from a TOML file.

    name = "cut-and-heal"
    [[event]]
    at = 30            # seconds after take-off
    link = "1-2"       # a pair, one drone ("2": all its links) or "all"
    loss = 0.3
    [[event]]
    at = 60
    link = "3"
    cut = true
    [[event]]
    at = 100
    link = "3"
    restore = true
    [radio]            # optional: links degrade with distance and break beyond range_m
    range_m = 15

Events. Each `[[event]]` table happens `at` seconds after take-off, to the links named by `link`:
- "a-b": the link between drones a and b (order does not matter);
- "k": every link of drone k (as if its radio were impaired);
- "all": every link of the swarm.
An event either sets an impairment (any of `loss`, `cut`, `delay_ms`, `jitter_ms`, `rate_kbit`, with the
meaning of `LinkProfile`) or has `restore = true`, never both. An impairment REPLACES the profile of each link it
covers (fields it does not give are clean: `loss = 0.3` after `cut = true` un-cuts the link); a restore makes the
covered links clean. So the state of a link is simply set by the last event that covered it. Events are sorted by
`at` on load; events at the same time are applied together, in file order. `timeline()` gives the profile of
every pair after each event time.

Radio. With a `[radio]` table, a link also degrades with the distance d between its two drones: loss grows
quadratically from 0 at d = 0 to `loss_at_range` (default 0.5) at d = `range_m`, and the link is cut beyond
`range_m` (`radio_profile()`). The profile in force is the scripted one combined with the radio one
(`combine()`): both losses apply independently, and either can cut.

Errors: a file that is missing, is not TOML or does not validate (unknown keys included, so typos are caught) is a
`ConfigError` of one line naming the file and the first problem, e.g.
`scenario.toml: event[1].loss: Input should be less than or equal to 1 (got 1.5)`; `event[1]` is the second
`[[event]]` table of the file, counted from 0. Drone ids are checked against the swarm's size by `check_drones()`.
"""

from __future__ import annotations

import re
from itertools import groupby
from operator import attrgetter
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from swarm.config import ConfigError, read_toml
from swarm.errors import validation_problem
from swarm.netem.profile import LinkProfile

Pair = tuple[int, int]
Profiles = dict[Pair, LinkProfile]

CLEAN = LinkProfile()
_IMPAIRMENTS = ("loss", "cut", "delay_ms", "jitter_ms", "rate_kbit")
_PAIR_RE = re.compile(r"^(\d+)-(\d+)$")
_NODE_RE = re.compile(r"^(\d+)$")
_LINK_HELP = 'must be "a-b" (the link between drones a and b), "k" (every link of drone k) or "all"'


def _named_drones(link: str) -> tuple[int, ...]:
    """The drone ids a link spec names: two for a pair, one for a drone, none for "all"; ValueError if malformed."""
    if link == "all":
        return ()
    match = _PAIR_RE.match(link) or _NODE_RE.match(link)
    if match is None:
        raise ValueError(_LINK_HELP)
    ids = tuple(int(group) for group in match.groups())
    if min(ids) < 1:
        raise ValueError("drone ids start at 1")
    if len(ids) == 2 and ids[0] == ids[1]:
        raise ValueError(f"a pair needs two different drones, not {ids[0]} and {ids[1]}")
    return ids


class ScenarioEvent(BaseModel):
    """One change of the links named by `link`, `at` seconds after take-off: an impairment or a restore."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    at: float = Field(..., ge=0.0, allow_inf_nan=False, description="seconds after take-off")
    link: str = Field(..., description='"a-b" (one pair), "k" (every link of drone k) or "all"')
    loss: float | None = Field(None, ge=0.0, le=1.0, description="probability that a frame is dropped")
    cut: bool | None = Field(None, description="drop everything")
    delay_ms: float | None = Field(None, ge=0.0, description="one-way delay (needs sch_netem)")
    jitter_ms: float | None = Field(None, ge=0.0, description="delay variation (needs sch_netem)")
    rate_kbit: int | None = Field(None, ge=0, description="rate limit in kbit/s, 0 = unlimited")
    restore: bool = Field(False, description="make the covered links clean again")

    @field_validator("link")
    @classmethod
    def _valid_link(cls, v: str) -> str:
        _named_drones(v)
        return v

    @model_validator(mode="after")
    def _restore_or_impair(self) -> ScenarioEvent:
        given = self.impairments()
        if self.restore and given:
            raise ValueError(f"restore = true cannot be combined with {', '.join(given)}")
        if not self.restore and not given:
            raise ValueError(f"an event needs restore = true or at least one of {', '.join(_IMPAIRMENTS)}")
        return self

    def impairments(self) -> list[str]:
        """The impairment fields this event gives."""
        return [name for name in _IMPAIRMENTS if getattr(self, name) is not None]

    def drones(self) -> tuple[int, ...]:
        """The drone ids `link` names (none for "all")."""
        return _named_drones(self.link)

    def profile(self) -> LinkProfile:
        """The profile the covered links get: the given fields, the others clean (clean for a restore)."""
        return LinkProfile(**{name: getattr(self, name) for name in self.impairments()})


class RadioModel(BaseModel):
    """Distance-dependent degradation: loss grows quadratically with distance, and the link breaks beyond range."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    range_m: float = Field(..., gt=0.0, allow_inf_nan=False, description="links are cut beyond this distance")
    loss_at_range: float = Field(0.5, ge=0.0, le=1.0, description="loss at exactly range_m (0 at distance 0)")


class Scenario(BaseModel):
    """A named link-loss experiment: scripted events (sorted by time) and an optional radio model."""

    model_config = ConfigDict(frozen=True, extra="forbid", populate_by_name=True)

    name: str = Field(..., description="the scenario's name, for reports")
    events: list[ScenarioEvent] = Field(
        default_factory=list, alias="event", description="`[[event]]` tables; sorted by `at` on load"
    )
    radio: RadioModel | None = Field(None, description="distance-dependent degradation; none when unset")

    @field_validator("name")
    @classmethod
    def _not_blank(cls, v: str) -> str:
        if not v.strip():
            raise ValueError("must not be empty")
        return v

    @field_validator("events")
    @classmethod
    def _by_time(cls, v: list[ScenarioEvent]) -> list[ScenarioEvent]:
        return sorted(v, key=attrgetter("at"))  # stable: events at the same time keep their file order

    def check_drones(self, drones: int) -> None:
        """ConfigError (one line) if an event names a drone that a swarm of `drones` drones does not have."""
        for event in self.events:
            for k in event.drones():
                if k > drones:
                    raise ConfigError(
                        f"scenario '{self.name}': the event at {event.at:g} s on link \"{event.link}\" names "
                        f"drone {k}, but the swarm has {drones} drone{'s' if drones != 1 else ''}"
                    )


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario from a TOML file; ConfigError (one line naming the file) if it cannot be used."""
    tree = read_toml(path, "scenario file")
    try:
        return Scenario.model_validate(tree)
    except ValidationError as exc:
        raise ConfigError(f"{path}: {validation_problem(exc, nowhere='scenario')}") from None


def resolve_links(link: str, drones: int) -> list[Pair]:
    """The pairs (a, b), a < b, that a link spec covers in a swarm of drones 1..`drones`, in order.

    "1-2" -> [(1, 2)]; "2" -> every pair containing 2; "all" -> every pair. ValueError for a malformed spec or a
    drone the swarm does not have (`Scenario.check_drones` reports the latter as a ConfigError).
    """
    ids = _named_drones(link)
    if any(k > drones for k in ids):
        raise ValueError(f'link "{link}" names a drone the swarm does not have (drones are 1..{drones})')
    if len(ids) == 2:
        return [(min(ids), max(ids))]
    every = [(a, b) for a in range(1, drones + 1) for b in range(a + 1, drones + 1)]
    if ids:
        return [pair for pair in every if ids[0] in pair]
    return every


class LinkState:
    """The scripted profile of every pair of a swarm of drones 1..`drones`; all clean at first."""

    def __init__(self, drones: int) -> None:
        self.drones = drones
        self._profiles: Profiles = dict.fromkeys(resolve_links("all", drones), CLEAN)

    def apply(self, event: ScenarioEvent) -> None:
        """Set every pair the event covers to its profile (which replaces the previous one) or, for a restore, clean."""
        profile = event.profile()
        for pair in resolve_links(event.link, self.drones):
            self._profiles[pair] = profile

    def profile(self, a: int, b: int) -> LinkProfile:
        """The profile of the link between a and b (in either order)."""
        return self._profiles[(min(a, b), max(a, b))]

    def profiles(self) -> Profiles:
        """A copy of the pair -> profile map, every pair included."""
        return dict(self._profiles)


def timeline(scenario: Scenario, drones: int) -> list[tuple[float, Profiles]]:
    """The profile of every pair after each event time, in time order (events at the same time applied together).

    ConfigError if an event names a drone beyond `drones`.
    """
    scenario.check_drones(drones)
    state = LinkState(drones)
    steps: list[tuple[float, Profiles]] = []
    for at, events in groupby(scenario.events, key=attrgetter("at")):
        for event in events:
            state.apply(event)
        steps.append((at, state.profiles()))
    return steps


def radio_profile(radio: RadioModel, distance_m: float) -> LinkProfile:
    """The radio's profile for two drones `distance_m` apart: loss_at_range * (d / range)^2, cut beyond range."""
    if distance_m < 0.0:
        raise ValueError(f"a distance cannot be negative ({distance_m} m)")
    if distance_m > radio.range_m:
        return LinkProfile(cut=True)
    return LinkProfile(loss=radio.loss_at_range * (distance_m / radio.range_m) ** 2)


def combine(scripted: LinkProfile, radio: LinkProfile) -> LinkProfile:
    """Both profiles at once: cut if either cuts, independent losses, the tighter rate limit, summed delays."""
    fields: dict[str, Any] = {
        "cut": scripted.cut or radio.cut,
        "loss": 1.0 - (1.0 - scripted.loss) * (1.0 - radio.loss),  # a frame gets through only if both let it
        "rate_kbit": min((r for r in (scripted.rate_kbit, radio.rate_kbit) if r), default=0),
        "delay_ms": scripted.delay_ms + radio.delay_ms,
        "jitter_ms": scripted.jitter_ms + radio.jitter_ms,  # a sum: an upper bound, kept simple
    }
    return LinkProfile(**fields)
