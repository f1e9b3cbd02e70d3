"""How a replay words a command's answer when the replayed daemon answers otherwise than the recorded one
did: read through ``wire.messages.reply_of``, as every reader of a reply."""

from __future__ import annotations

from replay.engine import _answer
from wire.messages import reply_of


def test_an_accepted_command_answers_ok() -> None:
    assert _answer(reply_of({"robot_id": "r1", "ok": True, "state": "idle"})) == "ok"


def test_a_refusal_answers_with_its_error() -> None:
    reply = reply_of({"robot_id": "r1", "ok": False, "error": "pause is not allowed in idle"})
    assert _answer(reply) == "refused (pause is not allowed in idle)"
    assert _answer(reply_of({"ok": False})) == "refused ()"


def test_a_recorded_reply_that_is_not_one_answers_refused_naming_the_field() -> None:
    assert _answer(reply_of({"ok": "yes"})) == (
        "refused (the reply is not a daemon's reply: ok: expected `bool`, got `str`)"
    )
