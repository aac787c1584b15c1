"""`validation_problem`: the one way a pydantic error becomes the one line a person reads (config files, link
scenarios, process files, generated deployments, and the reason a network message was dropped)."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from swarm.errors import validation_problem

pytestmark = pytest.mark.unit


class Event(BaseModel):
    model_config = ConfigDict(extra="forbid")
    loss: float
    name: str = "x"

    @field_validator("name")
    @classmethod
    def _short(cls, value: str) -> str:
        if len(value) > 3:
            raise ValueError("a name has at most 3 letters")
        return value


class Scenario(BaseModel):
    model_config = ConfigDict(extra="forbid")
    event: list[Event]


def _problem(data: object, **options: object) -> str:
    with pytest.raises(ValidationError) as caught:
        Scenario.model_validate(data)
    return validation_problem(caught.value, **options)  # type: ignore[arg-type]


def test_a_problem_says_where_in_the_file_and_what() -> None:
    assert _problem({"event": [{"loss": 0.1}, {"loss": "half"}]}) == (
        "event[1].loss: Input should be a valid number, unable to parse string as a number (got 'half')"
    )
    assert (
        _problem({"event": [{"loss": 0.1, "name": "long"}]})
        == "event[0].name: a name has at most 3 letters (got 'long')"
    )
    assert _problem({"event": [], "duration": 3}) == "duration: unknown field (got 3)"
    assert _problem({"event": [], "duration": 3}, unknown="unknown setting").startswith("duration: unknown setting")
    assert _problem({}) == "event: Field required"  # a missing value has nothing to echo


def test_hostile_input_is_never_echoed_and_a_long_value_is_cut() -> None:
    secret = "x" * 500
    assert secret not in _problem({"event": [{"loss": secret}]}, echo_input=False)
    assert "(got" not in _problem({"event": [{"loss": secret}]}, echo_input=False)
    echoed = _problem({"event": [{"loss": secret}]})
    assert echoed.endswith("...)") and len(echoed) < 200


def test_a_problem_at_the_top_is_placed_and_not_json_is_said_so() -> None:
    with pytest.raises(ValidationError) as caught:
        Scenario.model_validate([1, 2])
    assert validation_problem(caught.value, nowhere="scenario").startswith("scenario: Input should be")
    with pytest.raises(ValidationError) as caught:
        Scenario.model_validate_json('{"event": [')
    assert validation_problem(caught.value).startswith("not JSON (")
    assert "\n" not in validation_problem(caught.value)
