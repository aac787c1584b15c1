from swarm.bus.phase import AIRBORNE_PHASES, Phase
from swarm.roles.membership import PeerTable


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def make(own: int = 2) -> tuple[PeerTable, list, Clock]:
    events: list = []
    clock = Clock()
    table = PeerTable(own, timeout_s=3.0, on_change=lambda e, p, c: events.append((e, p, c)), clock=clock)
    return table, events, clock


def test_every_agent_starts_as_leader_of_itself() -> None:
    table, _, _ = make(own=7)
    assert table.cluster == [7]
    assert table.leader == 7 and table.role == "leader"


def test_lowest_id_leads_and_roles_follow_membership() -> None:
    table, events, _ = make(own=2)
    table.heard(3, (0, 0, 1), Phase.FLYING, 1)
    assert table.role == "leader"
    table.token_appeared(1)
    assert table.leader == 1 and table.role == "explorer"
    table.token_vanished(1)
    assert table.leader == 2 and table.role == "leader"
    assert events == [("joined", 3, "heartbeat"), ("joined", 1, "token"), ("left", 1, "token")]


def test_silent_peer_expires_after_timeout_and_rejoins_on_heartbeat() -> None:
    table, events, clock = make()
    table.heard(5, (1, 2, 3), Phase.FLYING, 9)
    clock.now += 2.9
    assert table.expire() == []
    clock.now += 0.2
    assert table.expire() == [5]
    assert table.cluster == [2]
    table.heard(5, (1, 2, 3), Phase.FLYING, 9)
    assert [e[0] for e in events] == ["joined", "left", "joined"]
    assert table.ever_seen == {5}


def test_own_messages_are_ignored() -> None:
    table, events, _ = make(own=4)
    table.heard(4, (0, 0, 0), Phase.FLYING, 1)
    table.token_appeared(4)
    assert table.cluster == [4] and events == []


def test_a_peer_down_for_good_leaves_the_cluster_but_stays_present() -> None:
    table, events, _ = make(own=3)
    table.heard(1, (0, 0, 1), Phase.FLYING, 1)
    table.heard(2, (0, 0, 1), Phase.LANDING, 1)
    assert table.cluster == [1, 2, 3] and table.leader == 1
    table.heard(1, (0, 0, 0), Phase.LANDED, 1)
    assert table.cluster == [2, 3] and table.leader == 2 and table.role == "explorer"
    for phase in (Phase.FAILSAFE, Phase.FAILED):
        table.heard(2, (0, 0, 0), phase, 1)
        assert table.cluster == [3] and table.role == "leader"
    assert set(table.peers) == {1, 2}, "a landed peer still syncs: it stays present"
    assert [e[0] for e in events] == ["joined", "joined"]


def test_a_lowest_id_flying_home_on_a_low_battery_hands_the_leadership_on() -> None:
    """Returning (a low battery ended its mission): out of the cluster, so it is given no target and does not stay
    the leader of drones still exploring, while it flies (it is still a neighbour to keep clear of)."""
    table, _, _ = make(own=3)
    table.heard(1, (0, 0, 1), Phase.FLYING, 1)
    table.heard(2, (0, 0, 1), Phase.FLYING, 1)
    assert table.leader == 1
    table.heard(1, (1, 0, 1), Phase.RETURNING, 1)
    assert table.cluster == [2, 3] and table.leader == 2
    assert Phase.RETURNING in AIRBORNE_PHASES


def test_a_peer_heard_only_by_its_token_is_in_the_cluster() -> None:
    table, _, _ = make(own=3)
    table.token_appeared(1)
    assert table.cluster == [1, 3] and table.leader == 1


def test_a_live_token_with_no_heartbeat_marks_the_peer_deaf_even_after_it_left_on_silence() -> None:
    table, _, clock = make()
    table.token_appeared(4)
    table.token_appeared(5)
    table.heard(5, (0, 0, 1), Phase.FLYING, 1)
    clock.now += 1.0
    assert table.deaf(after_s=1.5) == []  # a token just seen: its first heartbeat is still on its way
    clock.now += 1.0
    table.heard(5, (0, 0, 1), Phase.FLYING, 1)
    assert table.deaf(after_s=1.5) == [4]
    clock.now += 3.5
    assert table.expire() == [4, 5]  # both silent past the 3 s timeout; their tokens are still alive
    assert table.deaf(after_s=1.5) == [4, 5]
    table.heard(4, (0, 0, 1), Phase.FLYING, 1)
    table.token_vanished(5)  # a peer whose token goes is gone, not unheard
    assert table.deaf(after_s=1.5) == []
    table.token_appeared(2)  # our own token
    clock.now += 5.0
    assert table.deaf(after_s=1.5) == [4]


def test_a_heartbeat_delivered_after_the_peers_token_went_does_not_bring_it_back() -> None:
    """A killed leader's last heartbeat can arrive just after its token left: it must not make the leader again."""
    table, events, clock = make(own=2)
    table.token_appeared(1)
    table.heard(1, (0, 0, 1), Phase.FLYING, 7)
    table.token_vanished(1)
    clock.now += 0.05
    assert table.heard(1, (0, 0, 1), Phase.FLYING, 7) is False
    assert table.leader == 2 and table.stale_heartbeats == 1
    assert [e[:2] for e in events] == [("joined", 1), ("left", 1)]


def test_a_peer_whose_token_went_is_taken_back_by_its_token_a_new_epoch_or_heartbeats_after_the_timeout() -> None:
    table, _, clock = make(own=2)
    for peer in (1, 3, 4):
        table.token_appeared(peer)
        table.heard(peer, (0, 0, 1), Phase.FLYING, 7)
        table.token_vanished(peer)
    table.token_appeared(1)  # the link healed
    assert table.heard(1, (0, 0, 1), Phase.FLYING, 7)
    assert table.heard(3, (0, 0, 1), Phase.FLYING, 8)  # restarted
    assert not table.heard(4, (0, 0, 1), Phase.FLYING, 7)
    clock.now += 3.1  # past the silence timeout: a heartbeat now was sent after the token went
    assert table.heard(4, (0, 0, 1), Phase.FLYING, 7)
    assert table.cluster == [1, 2, 3, 4] and table.stale_heartbeats == 1
