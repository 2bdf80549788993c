"""The topic tree and the payloads of ``cell/plant.md``: built, read back, and refused with
a message that names what is wrong."""
from __future__ import annotations

import json

import pytest

from cell.plant import schema
from cell.plant.topics import CellTopics, TopicError, parse, subscription
from tests.cell.plant.helpers import TOPICS, record


def test_topics_of_a_cell():
    t = CellTopics("site1", "line2", "cell-1")
    assert (t.status, t.cycle, t.event, t.watermark) == (
        "site1/line2/cell-1/status", "site1/line2/cell-1/cycle", "site1/line2/cell-1/event",
        "site1/line2/cell-1/watermark")
    assert parse("site1/line2/cell-1/cycle") == (t, "cycle")
    assert subscription("cycle") == "+/+/+/cycle"
    assert subscription("watermark", site="site1") == "site1/+/+/watermark"


@pytest.mark.parametrize("bad", ["", "a/b", "+", "#", "a b", "x" * 65])
def test_a_name_that_would_break_the_tree_is_refused(bad):
    with pytest.raises(TopicError, match="cell"):
        CellTopics("site1", "line2", bad)


def test_a_topic_outside_the_tree_is_refused():
    with pytest.raises(TopicError, match="kind one of"):
        parse("site1/line2/cell-1/other")


def _cycle(**change) -> bytes:
    rec = record(7)
    rec.id = 12
    data = json.loads(schema.cycle_payload(TOPICS.path, "log1", rec, prev_id=9, session=3, seq=1))
    data.update(change)
    return json.dumps(data).encode()


def test_a_cycle_message_round_trips_without_the_trace():
    msg = schema.parse("cycle", TOPICS.cycle, _cycle(), TOPICS.path)
    assert (msg.cell, msg.log_id, msg.cycle_id, msg.prev_id, msg.session, msg.seq) == (
        TOPICS.path, "log1", 12, 9, 3, 1)
    assert msg.record.part_id == 7 and msg.record.status == "done"
    assert msg.record.target_mm == (400.0, 10.0)
    assert "trace" not in json.loads(_cycle())["record"]
    assert json.loads(_cycle())["schema"] == schema.SCHEMA_VERSION


@pytest.mark.parametrize("payload, says", [
    (b"{not json", "payload is not JSON"),
    (b"[1, 2]", "JSON list, not an object"),
    (b'{"cell": "a/b/c"}', "no 'schema' version"),
    (_cycle(schema=2), "unknown schema version 2"),
    (_cycle(schema="1"), "unknown schema version '1'"),
    (_cycle(cycle_id=0), "cycle_id"),
    (_cycle(prev_id=12), "prev_id 12 must be below cycle_id 12"),
    (_cycle(colour="red"), "colour: Extra inputs are not permitted"),
    (_cycle(cell="site1/line2/cell-9"), "not the topic's"),
])
def test_a_bad_payload_is_refused_naming_what_is_wrong(payload, says):
    with pytest.raises(schema.PayloadError) as exc:
        schema.parse("cycle", TOPICS.cycle, payload, TOPICS.path)
    assert says in str(exc.value)
    assert str(exc.value).startswith(TOPICS.cycle)


def test_a_record_field_missing_is_named():
    data = json.loads(_cycle())
    del data["record"]["recipe"]
    with pytest.raises(schema.PayloadError, match=r"record\.recipe: Field required"):
        schema.parse("cycle", TOPICS.cycle, json.dumps(data).encode(), TOPICS.path)


def test_status_and_watermark_payloads_read_back():
    st = schema.parse("status", TOPICS.status, schema.status_payload(TOPICS.path, False, 4, "log1"))
    assert (st.online, st.session, st.log_id) == (False, 4, "log1")
    wm = schema.parse("watermark", TOPICS.watermark, schema.watermark_payload(TOPICS.path, "log1", 99))
    assert (wm.log_id, wm.cycle_id) == ("log1", 99)
    ev = schema.parse("event", TOPICS.event, schema.event_payload(TOPICS.path, 4, 1, "started", {"n": 1}))
    assert (ev.kind, ev.data) == ("started", {"n": 1})


def test_the_payloads_record_is_the_logs_record_without_trace_and_id():
    # the contract (cell/plant.md) names CycleRecord's fields; a field the log gains must be
    # added to schema v1's CycleFields too (or the schema versioned), never silently dropped
    from dataclasses import fields

    from cell.cyclelog import CycleRecord
    from cell.plant.schema import CycleFields
    assert set(CycleFields.model_fields) == {f.name for f in fields(CycleRecord)} - {"trace", "id"}


def test_a_status_carries_the_cells_state_in_version_2_and_version_1_still_reads():
    st = schema.parse("status", TOPICS.status, schema.status_payload(
        TOPICS.path, True, 4, "log1", {"state": "fault", "fault_code": 31, "fault_text": "camera lost the part"}),
        TOPICS.path)
    assert (st.schema_, st.state, st.fault_code, st.fault_text) == (2, "fault", 31, "camera lost the part")
    will = schema.parse("status", TOPICS.status, schema.status_payload(TOPICS.path, False, 4, "log1"))
    assert (will.schema_, will.state, will.fault_code) == (2, None, None)
    v1 = (b'{"schema":1,"cell":"site1/line2/cell-1","online":true,"session":3,"log_id":null,'
          b'"at":"2026-01-01T00:00:00Z"}')
    old = schema.parse("status", TOPICS.status, v1, TOPICS.path)
    assert (old.online, old.session, old.state) == (True, 3, None)


@pytest.mark.parametrize("payload, says", [
    (b'{"schema":1,"cell":"site1/line2/cell-1","online":true,"session":3,"at":"x","state":"idle"}',
     "state: a field of status version 2, not 1"),
    (b'{"schema":3,"cell":"site1/line2/cell-1","online":true,"session":3,"at":"x"}',
     "unknown schema version 3 for status: this reader knows 1, 2"),
    (b'{"schema":2,"cell":"site1/line2/cell-1","online":true,"session":3,"at":"x","fault_code":-1}',
     "fault_code: Input should be greater than or equal to 0"),
])
def test_a_bad_status_is_refused_naming_what_is_wrong(payload, says):
    with pytest.raises(schema.PayloadError) as exc:
        schema.parse("status", TOPICS.status, payload, TOPICS.path)
    assert says in str(exc.value) and str(exc.value).startswith(TOPICS.status)


def _event(kind="fault", data=None, **change) -> bytes:
    body = json.loads(schema.event_payload(TOPICS.path, 3, 5, "fault", {"code": 31, "text": "lost", "state": "fault"}))
    body.update(kind=kind, **change)
    if data is not None:
        body["data"] = data
    return json.dumps(body).encode()


def test_each_event_kind_reads_back_and_an_unknown_kind_is_taken_as_it_is():
    from cell.plant.events import EVENT_KINDS
    examples = {"fault": {"code": 31, "text": "lost", "state": "fault"}, "reset": {"code": 31, "state": "idle"},
                "recipe_selected": {"number": 2, "name": "bracket-b"},
                "recipe_changed": {"action": "activate", "target": "recipes/a.yaml", "hash": "ab12"},
                "calibration_applied": {"calibration": "cal-0003", "sha256": "00ff"}}
    assert set(examples) == set(EVENT_KINDS)
    for kind, data in examples.items():
        ev = schema.parse("event", TOPICS.event, schema.event_payload(TOPICS.path, 3, 5, kind, data), TOPICS.path)
        assert (ev.kind, ev.data, ev.session, ev.seq) == (kind, data, 3, 5)
    later = schema.parse("event", TOPICS.event, _event("door_opened", {"door": 2}), TOPICS.path)
    assert (later.kind, later.data) == ("door_opened", {"door": 2})


@pytest.mark.parametrize("payload, says", [
    (_event(schema=2), "unknown schema version 2 for event: this reader knows 1"),
    (_event(data={"text": "no code"}), "fault event: data.code: Field required"),
    (_event(data={"code": 0}), "data.code: Input should be greater than or equal to 1"),
    (_event("recipe_changed", {"action": "burn", "target": "a.yaml"}), "data.action"),
    (_event("reset", {"code": 3, "colour": "red"}), "data.colour: Extra inputs are not permitted"),
    (_event("Fault!"), "kind: String should match pattern"),
    (_event(seq=0), "seq: Input should be greater than or equal to 1"),
    (_event(cell="site1/line2/cell-9"), "not the topic's"),
])
def test_a_bad_event_is_refused_naming_what_is_wrong(payload, says):
    with pytest.raises(schema.PayloadError) as exc:
        schema.parse("event", TOPICS.event, payload, TOPICS.path)
    assert says in str(exc.value) and str(exc.value).startswith(TOPICS.event)


def test_events_between_two_states():
    from cell.plant.events import state_events
    idle = {"state": "idle", "fault_code": 0, "fault_text": "", "recipe_number": 1, "recipe_name": "a"}
    fault = dict(idle, state="fault", fault_code=31, fault_text="lost")
    assert state_events(None, idle) == []
    assert state_events(None, fault) == [("fault", {"code": 31, "text": "lost", "state": "fault"})]
    assert state_events(idle, fault) == [("fault", {"code": 31, "text": "lost", "state": "fault"})]
    assert state_events(fault, dict(fault, fault_code=32)) == [("fault", {"code": 32, "text": "lost",
                                                                          "state": "fault"})]
    assert state_events(fault, idle) == [("reset", {"code": 31, "state": "idle"})]
    assert state_events(idle, dict(idle, recipe_number=2, recipe_name="b")) == [
        ("recipe_selected", {"number": 2, "name": "b"})]
    assert state_events(idle, dict(idle, state="approach", joints=[1.0])) == []
