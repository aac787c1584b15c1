"""The exploration messages validate hostile input: shapes, finiteness, bounds, and who may be assigned."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.bus.codec import DecodeError, decode, encode
from swarm.roles.messages import MAX_CANDIDATES, FrontierReport, TargetAssignment, as_points


def _report(**fields: object) -> FrontierReport:
    base: dict[str, object] = dict(
        id=2,
        epoch=7,
        seq=1,
        position=(1.0, 2.0, 1.5),
        viewpoints=as_points([(1.0, 1.0, 1.0), (2.0, 2.0, 1.0)]),
        points=as_points([(1.5, 1.0, 1.0), (2.5, 2.0, 1.0)]),
        gains=np.array([3.0, 0.5], dtype=np.float32),
        visited=as_points([(0.0, 0.0, 1.0)]),
        arrived=True,
    )
    base.update(fields)
    return FrontierReport(**base)


def test_frontier_report_round_trips() -> None:
    report = _report()
    back = decode(encode(report), FrontierReport)
    assert back == report
    assert back.viewpoints.shape == (2, 3) and back.arrived


@pytest.mark.parametrize(
    "fields, message",
    [
        ({"gains": np.array([1.0], dtype=np.float32)}, "same length"),
        ({"gains": np.array([1.0, -2.0], dtype=np.float32)}, "non-negative"),
        ({"points": np.array([[1.0, 2.0], [3.0, 4.0]], dtype=np.float32)}, "shape"),
        ({"visited": as_points([(np.nan, 0.0, 0.0)])}, "non-finite"),
        ({"viewpoints": np.zeros((2, 3), dtype=np.float64)}, "dtype"),
    ],
)
def test_bad_reports_are_refused(fields: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        _report(**fields)


def test_oversized_report_fails_to_decode() -> None:
    n = MAX_CANDIDATES + 1
    honest = _report()
    payload = encode(honest).replace(b"", b"")  # start from a valid envelope, then forge the arrays
    assert decode(payload, FrontierReport) == honest
    forged = FrontierReport.model_construct(
        **{
            **dict(honest),
            "viewpoints": np.zeros((n, 3), np.float32),
            "points": np.zeros((n, 3), np.float32),
            "gains": np.zeros(n, np.float32),
        }
    )
    with pytest.raises(DecodeError) as err:
        decode(encode(forged), FrontierReport)
    assert err.value.reason == "invalid"


def test_assignment_names_each_member_once() -> None:
    good = TargetAssignment(
        leader=1,
        epoch=3,
        round=4,
        members=[1, 2, 3],
        drones=[1, 3],
        viewpoints=as_points([(1.0, 1.0, 1.0), (5.0, 5.0, 1.0)]),
        points=as_points([(2.0, 1.0, 1.0), (6.0, 5.0, 1.0)]),
    )
    back = decode(encode(good), TargetAssignment)
    assert back.target_of(3) == ((5.0, 5.0, 1.0), (6.0, 5.0, 1.0))
    assert back.target_of(2) is None
    with pytest.raises(ValueError, match="at most once"):
        TargetAssignment(
            leader=1,
            epoch=3,
            round=4,
            members=[1, 2],
            drones=[2, 2],
            viewpoints=as_points([(0, 0, 1)] * 2),
            points=as_points([(0, 0, 1)] * 2),
        )
    with pytest.raises(ValueError, match="at most once"):
        TargetAssignment(
            leader=1,
            epoch=3,
            round=4,
            members=[1, 2],
            drones=[9],
            viewpoints=as_points([(0, 0, 1)]),
            points=as_points([(0, 0, 1)]),
        )
    with pytest.raises(ValueError, match="leader is a member"):
        TargetAssignment(leader=5, epoch=3, round=4, members=[1, 2], done=True)
