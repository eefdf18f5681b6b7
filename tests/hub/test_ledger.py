"""The hub's verdict on a reply depends on when the reply arrived, not on when the loop
looked. (What a reply must contain: tests/hub/test_replies.py.)"""

from __future__ import annotations

from hub.ledger import Ledger
from hub.protocol import SensorReading, SpikeBatch, StepWindow

PERIOD_S = 0.01


def _ledger_at_step(k: int) -> tuple[Ledger, list[tuple]]:
    """A ledger whose roles were both sent step ``k``; and the events it records."""
    events = []
    ledger = Ledger(on_event=lambda name, **details: events.append((name, details)))
    for role in ("body", "culture"):
        ledger.expect[role] = k
        ledger.sent(role, k)
    return ledger, events


def _reply(role: str, k: int):
    w = StepWindow.of("run", k, PERIOD_S)
    if role == "body":
        return SensorReading(
            step=k, run=w.run, t_s=w.t1_s, ranges_m=[0.1], pose=[0.0, 0.0, 0.0], contact=False
        )
    return SpikeBatch(**w.stamp, channel=[3], t_ms=[1.0])


def _await_both(ledger: Ledger, k: int, deadline: float) -> None:
    ledger.await_replies({"body": k, "culture": k}, {"body": deadline, "culture": deadline})


def test_replies_in_before_the_deadline_are_on_time_even_if_the_loop_judges_them_later():
    ledger, _ = _ledger_at_step(5)
    _await_both(ledger, 5, deadline=100.0)
    # the loop's thread gets to them at 102.0, past the deadline; they arrived before it
    assert ledger.judge("body", _reply("body", 5), 96.0, running=True) == "rx"
    assert ledger.judge("culture", _reply("culture", 5), 99.0, running=True) == "rx"
    assert ledger.settle() is False
    assert all(5 in ledger.pending[r] for r in ("body", "culture"))
    assert not ledger.late and not any(ledger.missed.values())


def test_a_reply_in_after_the_deadline_is_late_however_soon_the_loop_sees_it():
    ledger, events = _ledger_at_step(5)
    _await_both(ledger, 5, deadline=100.0)
    assert ledger.judge("body", _reply("body", 5), 96.0, running=True) == "rx"
    assert ledger.judge("culture", _reply("culture", 5), 100.001, running=True) == "late"
    assert ledger.settle() is True
    assert 5 in ledger.pending["body"] and 5 not in ledger.pending["culture"]
    assert ledger.late == {"culture": 1}
    assert ("late", {"role": "culture", "step": 5, "at_step": 5}) in events
    # late, not also missing: the policy stood in for it once (a CI run counted it twice)
    assert ledger.missed["culture"] == set()
    assert [e for e in events if e[0] == "missed"] == [("missed", {"role": "culture", "step": 5})]


def test_a_reply_that_never_comes_is_missing_and_one_that_comes_after_that_is_late():
    ledger, events = _ledger_at_step(2)
    _await_both(ledger, 2, deadline=100.0)
    ledger.judge("body", _reply("body", 2), 99.0, running=True)
    assert ledger.waiting(99.5) == ["culture"] and ledger.waiting(100.0) == []
    assert ledger.settle() is True
    assert ledger.missed["culture"] == {2} and 2 in ledger.pending["body"]
    assert ("missed", {"role": "culture", "step": 2}) in events
    ledger.expect["culture"] = 3  # the loop went on, the policy stood in
    assert ledger.judge("culture", _reply("culture", 2), 100.5, running=True) == "late"
    assert ledger.missed["culture"] == set() and ledger.late["culture"] == 1


def test_duplicate_stale_future_and_early_replies_are_dropped_and_counted_by_kind():
    ledger, events = _ledger_at_step(4)
    assert ledger.judge("culture", _reply("culture", 4), 0.0, running=False) == "drop"
    assert ledger.judge("culture", _reply("culture", 4), 0.0, running=True) == "rx"
    assert ledger.judge("culture", _reply("culture", 4), 0.0, running=True) == "drop"
    assert ledger.judge("culture", _reply("culture", 3), 0.0, running=True) == "drop"
    assert ledger.judge("culture", _reply("culture", 9), 0.0, running=True) == "drop"
    assert ledger.judge("culture", _reply("culture", 9), 0.0, running=True) == "drop"
    assert ledger.dropped["culture"] == {"early": 1, "duplicate": 1, "stale": 1, "future": 2}
    assert [d["kind"] for name, d in events if name == "dropped"] == [
        "early",
        "duplicate",
        "stale",
        "future",
    ]  # the first of each kind is an event; every one is counted


def test_the_answer_to_the_final_stop_is_kept_apart_from_the_run():
    ledger, _ = _ledger_at_step(7)
    ledger.final_step = 8
    assert ledger.judge("body", _reply("body", 8), 0.0, running=False) == "final"
    assert 8 in ledger.pending["body"] and not ledger.dropped


# ---------------------------------------------------------------- parts (contract v4)


def _part(k: int, channel: int, t_ms: float) -> SpikeBatch:
    w = StepWindow.of("run", k, PERIOD_S)
    return SpikeBatch(**w.stamp, channel=[channel], t_ms=[t_ms], partial=True)


def test_a_steps_reply_taken_is_its_parts_and_its_batch():
    ledger, _ = _ledger_at_step(5)
    _await_both(ledger, 5, deadline=100.0)
    assert ledger.judge_part("culture", _part(5, 7, 0.5), running=True) == "part"
    assert ledger.judge_part("culture", _part(5, 8, 2.0), running=True) == "part"
    assert ledger.waiting(99.0) == ["body", "culture"]  # parts are not the reply
    assert ledger.judge("culture", _reply("culture", 5), 99.0, running=True) == "rx"
    taken = ledger.pending["culture"][5]
    assert taken.channel.tolist() == [7, 3, 8] and taken.t_ms.tolist() == [0.5, 1.0, 2.0]
    assert not ledger.parts["culture"]


def test_a_part_after_its_steps_reply_is_dropped_and_one_of_a_missed_step_is_late_data():
    ledger, _ = _ledger_at_step(5)
    _await_both(ledger, 5, deadline=100.0)
    ledger.judge_part("culture", _part(5, 7, 0.5), running=True)
    assert ledger.settle() is True  # step 5 missed: no reply will take its parts
    assert not ledger.parts["culture"] and [p.channel.tolist() for p in ledger.stranded] == [[7]]
    assert ledger.judge_part("culture", _part(5, 8, 2.0), running=True) == "late"
    assert ledger.late["culture"] == 0  # data, not a late reply
    ledger.sent("culture", 6)
    assert ledger.judge("culture", _reply("culture", 6), 101.0, running=True) == "rx"
    assert ledger.judge_part("culture", _part(6, 8, 2.0), running=True) == "drop"
    assert ledger.judge_part("culture", _part(9, 8, 2.0), running=True) == "drop"
    assert ledger.judge_part("culture", _part(6, 8, 2.0), running=False) == "drop"
    assert ledger.dropped["culture"] == {"duplicate": 1, "future": 1, "early": 1}
