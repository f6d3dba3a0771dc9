"""STATUSTEXT longer than 50 bytes in MAVLink 2 chunks (id, chunk_seq), as QGroundControl
and MAVSDK reassemble them: packed and parsed by pymavlink."""

from __future__ import annotations

import pytest

from contracts.mavlink import StatustextAssembler, mavlink, new_mavlink, statustext_messages


def _over_the_wire(msgs: list) -> list:
    tx, rx = new_mavlink(1, 1), mavlink.MAVLink(None)
    return [m for msg in msgs for m in rx.parse_buffer(msg.pack(tx)) or []]


@pytest.mark.parametrize("length, chunks", [(1, 1), (50, 1), (51, 2), (99, 2), (100, 3),
                                            (149, 3)])
def test_a_text_goes_in_chunks_and_comes_back_whole(length, chunks):
    text = "".join(chr(ord("a") + i % 26) for i in range(length))
    msgs = statustext_messages(4, text, 9)
    assert len(msgs) == chunks
    assert [m.id for m in msgs] == ([0] if chunks == 1 else [9] * chunks)
    assert [m.chunk_seq for m in msgs] == (list(range(chunks)) if chunks > 1 else [0])
    assembler = StatustextAssembler()
    whole = [t for m in _over_the_wire(msgs) if (t := assembler.add(m)) is not None]
    assert whole == [text]


def test_a_lost_chunk_loses_that_text_only():
    assembler = StatustextAssembler()
    first = _over_the_wire(statustext_messages(4, "x" * 120, 1))
    second = _over_the_wire(statustext_messages(4, "y" * 70, 2))
    got = [assembler.add(m) for m in (first[0], first[2], *second)]
    assert [g for g in got if g is not None] == ["y" * 70]


def test_pending_texts_are_bounded():
    assembler = StatustextAssembler(max_pending=4)
    for chunk_id in range(1, 100):  # first chunks only, never finished
        assembler.add(_over_the_wire(statustext_messages(4, "z" * 60, chunk_id))[0])
    assert len(assembler._pending) <= 4


def test_a_chunk_id_out_of_range_is_refused():
    with pytest.raises(ValueError, match="chunk id"):
        statustext_messages(4, "w" * 60, 0)


def test_a_chunked_text_in_the_log_is_one_event_at_the_time_it_was_said(tmp_path):
    from contracts.mavlink import AUTOPILOT_COMPID
    from contracts.telemetry import mavlink_key
    from ground.record.events import statustext_events
    from ground.telemetry.mcap_file import McapFile

    log = McapFile(tmp_path / "telemetry-000.mcap", 256 * 1024, "zstd")
    channel = log.channel(mavlink_key(1, AUTOPILOT_COMPID, "STATUSTEXT"), "mavlink")
    tx = new_mavlink(1, AUTOPILOT_COMPID)
    said = [(2_000_000_000, "simulator link up"), (5_500_000_000, "GPS lost: " + "q" * 70)]
    seq = 0
    for t_ns, text in said:
        for msg in statustext_messages(4, text, 3):
            log.add(channel, t_ns, t_ns, seq, bytes(msg.pack(tx)))
            seq += 1
    log.finish()
    events = statustext_events(tmp_path, 1)
    assert [(e.t_s, e.text) for e in events] == [(2.0, said[0][1]), (5.5, said[1][1])]
