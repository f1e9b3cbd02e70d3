"""A daemon's reply to ``cmd/<verb>`` read as ``wire.messages.Reply``: every field the daemon writes is typed,
a field it leaves out reads as left out, and a reply that is not one reads as refused, naming the field."""

from __future__ import annotations

from wire.messages import UNSET, Reply, reply_of


def test_a_status_reply_reads_as_declared() -> None:
    reply = reply_of(
        {
            "robot_id": "r1",
            "ok": True,
            "state": "idle",
            "mugs_total": 3,
            "mugs_planned": 2,
            "mugs_placed": 1,
            "mugs_failed": 0,
            "current_mug": None,
            "transitions": 4,
            "t": 1.5,
            "summary": {"placed": 1},
            "allowed": ["status", "start"],
            "recording": {"ok": False, "path": "/rec/a.mcap", "error": "disk full", "dropped": 7},
        }
    )
    assert (reply.robot_id, reply.ok, reply.state, reply.mugs_placed, reply.current_mug) == (
        "r1",
        True,
        "idle",
        1,
        None,
    )
    assert reply.allowed == ["status", "start"]
    assert reply.recording is not UNSET
    assert reply.recording.dropped == 7


def test_a_refusal_reads_with_its_error_and_nothing_else() -> None:
    reply = reply_of({"robot_id": "r1", "ok": False, "error": "pause is not allowed in idle"})
    assert reply == Reply(robot_id="r1", ok=False, error="pause is not allowed in idle")


def test_a_reply_that_is_not_one_reads_as_refused_naming_the_field() -> None:
    reply = reply_of({"robot_id": "r1", "ok": "yes"})
    assert reply.ok is False
    assert reply.robot_id == "r1"
    assert reply.error == "the reply is not a daemon's reply: ok: expected `bool`, got `str`"
