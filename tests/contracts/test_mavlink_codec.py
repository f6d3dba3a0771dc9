"""The compiled MAVLink 2 codec (contracts/mavlink_codec.py) against pymavlink: the same
frames packed over randomized fields, the same fields read, the same frames refused;
and a whole simulator sample (contracts/sim_samples.py ``pack_sample``) as pymavlink
packs its messages."""

from __future__ import annotations

import random
import struct

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME
from contracts.mavlink import mavlink, new_mavlink
from contracts.mavlink_codec import (
    HEADER_BYTES,
    FrameLayout,
    checked_frame,
    frame_length,
    msgid_at,
)
from contracts.sim_samples import (
    FIX_SIZE,
    SAMPLE_BYTES,
    gps_fix,
    pack_sample,
    sample_messages,
    sensor_reading,
)
from tests.contracts.test_sim_link_frames import CLASSES, _exact, _fields, _message, _messages

LAYOUTS = {cls: FrameLayout(cls) for cls in CLASSES}
STYLES = ("random", "extremes", "zeros", "trailing zeros")


def test_layouts_are_pymavlinks_payloads():
    for cls, layout in LAYOUTS.items():
        assert layout.payload_bytes == cls.unpacker.size
        assert (layout.msgid, layout.crc_extra) == (cls.id, cls.crc_extra)


def test_packing_is_pymavlinks_byte_for_byte():
    """Random, extreme (uint64 at 2**64 - 1 among them), zero and trailing-zero values of
    each message, any sequence number and ids."""
    rng = random.Random(7)
    packed = 0
    for k, msg in enumerate(_messages(3000, seed=11)):
        mav = mavlink.MAVLink(None, rng.randint(0, 255), rng.randint(0, 255))
        mav.seq = rng.randint(0, 255)
        try:
            expected = msg.pack(mav)
        except (struct.error, OverflowError):
            continue  # pymavlink cannot pack it (a float beyond float32): nothing to match
        layout = LAYOUTS[type(msg)]
        assert layout.pack_fields(_fields(msg), mav) == expected, (msg.get_type(), k)
        packed += 1
    assert packed > 2900


def test_unpacking_reads_what_pymavlink_reads():
    """Every field of every frame, trimmed payloads zero-extended, NaN and -0.0 by their
    bits, unsigned 64-bit values above 2**63 as pymavlink gives them."""
    mav = mavlink.MAVLink(None, 1, 51)
    for msg in _messages(2000, seed=12):
        try:
            frame = msg.pack(mav)
        except (struct.error, OverflowError):
            continue
        theirs = new_mavlink(1, 1).parse_buffer(frame)[0]
        layout = LAYOUTS[type(msg)]
        values = layout.unpack(frame)
        assert values is not None
        assert tuple(map(_exact, layout.fields(*values))) == \
            tuple(_exact(getattr(theirs, name)) for name in theirs.fieldnames)


def test_a_damaged_frame_is_refused_as_pymavlink_refuses_it():
    """Any one byte of a frame changed: where pymavlink still reads the same message (a
    change it cannot see) the codec reads it too; where pymavlink refuses the frame, or
    reads another message, the codec leaves it to pymavlink (None)."""
    rng = random.Random(13)
    mav = mavlink.MAVLink(None, 1, 51)
    refused = 0
    for k in range(1500):
        cls = CLASSES[k % len(CLASSES)]
        msg = _message(cls, STYLES[k % 4], rng)
        try:
            frame = bytearray(msg.pack(mav))
        except (struct.error, OverflowError):
            continue
        at = rng.randrange(len(frame))
        frame[at] ^= 1 << rng.randrange(8)
        theirs = new_mavlink(1, 1).parse_buffer(bytes(frame)) or []
        ours = LAYOUTS[cls].unpack(bytes(frame))
        good = [m for m in theirs if m.get_type() == cls.msgname]
        if ours is None:
            refused += 1
            assert not good or at == 5 or at == 6, (k, at)  # ids: not ours to judge
        else:
            assert len(good) == 1
            assert tuple(map(_exact, LAYOUTS[cls].fields(*ours))) == \
                tuple(_exact(getattr(good[0], n)) for n in good[0].fieldnames)
    assert refused > 1000


def test_frame_headers():
    mav = mavlink.MAVLink(None, 1, 51)
    frame = np.frombuffer(mavlink.MAVLink_hil_sensor_message(
        *([5] + [1.0] * 13 + [0x1FFF, 0])).pack(mav), dtype=np.uint8)
    assert frame_length(frame, 0) == len(frame)
    assert msgid_at(frame, 0) == mavlink.MAVLINK_MSG_ID_HIL_SENSOR
    assert checked_frame(frame, 0, mavlink.MAVLink_hil_sensor_message.crc_extra,
                         mavlink.MAVLink_hil_sensor_message.unpacker.size)
    assert frame_length(frame[:HEADER_BYTES - 1], 0) == 0  # the header not all there
    assert frame_length(np.frombuffer(b"\x00" * 12, dtype=np.uint8), 0) == -1
    signed = frame.copy()
    signed[2] = 1
    assert frame_length(signed, 0) == len(frame) + 13
    assert not checked_frame(signed, 0, mavlink.MAVLink_hil_sensor_message.crc_extra, 64)


@pytest.mark.parametrize("seed", range(3))
def test_a_sample_packs_as_pymavlink_packs_its_messages(seed):
    """pack_sample's frames are sample_messages' packed by pymavlink, with and without a
    fix, for states and readings anywhere (saturating integers included)."""
    from sitl.plant import VehicleState
    from sitl.truth import ideal_readings

    rng = np.random.default_rng(seed)
    for k in range(300):
        scale = 10.0 ** rng.integers(-2, 6)
        q = rng.normal(size=4)
        position = rng.normal(size=3) * scale
        position[2] = np.clip(position[2], -4e4, 1e3)  # a standard atmosphere's pressure
        state = VehicleState(0.0, position, rng.normal(size=3) * scale,
                             np.zeros(3), np.zeros(3), rng.normal(size=3),
                             q / np.linalg.norm(q))
        accel = rng.normal(size=3) * scale
        truth, sensor, fix = ideal_readings(k * 10_000, state, accel, DEFAULT_HOME)
        with_fix = k % 3 == 0
        mav = mavlink.MAVLink(None, 1, 51)
        mav.seq = k % 256
        try:
            expected = b"".join(m.pack(mav) for m in sample_messages(
                truth, sensor, fix if with_fix else None, DEFAULT_HOME))
        except (struct.error, OverflowError):
            continue
        out = np.empty(SAMPLE_BYTES, dtype=np.uint8)
        end, sensor_end, gps_end = pack_sample(
            out, mav.seq, 1, 51, np.array(DEFAULT_HOME), truth.time_us, state.numbers(),
            accel, sensor_reading(sensor),
            gps_fix(fix) if with_fix else np.zeros(FIX_SIZE), fix.time_us if with_fix else -1)
        assert out[:end].tobytes() == expected, k
        assert (gps_end > 0) == with_fix
        assert out[gps_end:sensor_end].tobytes() == sample_messages(
            truth, sensor, None, DEFAULT_HOME)[0].pack(mav)
