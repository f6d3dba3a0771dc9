"""MAVLink 2 signing state that outlives the process, and SETUP_SIGNING.

The signing spec protects against replays with timestamps. A link rejects a signed frame
whose timestamp is not newer than the last one from its stream (link id, system,
component), and rejects a new stream's frame older than a minute before its own clock.
Kept only in memory, the stream table empties on a restart. A frame captured in the
minute before the restart could then be replayed and accepted.

So the vehicle keeps its signing clock and each stream's last timestamp in a state file
(``--signing-state``, by default under ``$XDG_STATE_HOME/ivfm``). The file is written
at most once a second while they change, and at shut-down. On start it is read back,
and the clock restarts no earlier than it stopped. This matches what PX4 keeps for
MAV_SIGN_CFG on its SD card.

SETUP_SIGNING sets the key (all zeros: signing off) for this run. It is taken only over
a link that is signed already, or from a local address: a key must never travel in the
clear across a network.
"""

from __future__ import annotations

import ipaddress
import json
import os
import time
from pathlib import Path
from typing import Any

from contracts.atomic_file import write_atomic
from contracts.mavlink import mavlink

SIGNING_EPOCH_S = 1420070400  # 2015-01-01, MAVLink's signing clock's origin
MAX_STREAMS = 1024  # stream entries kept in the file (the newest)
SAVE_EVERY_S = 1.0


def signing_clock_now() -> int:
    """MAVLink's signing clock: 10 us units since 2015-01-01."""
    return int((time.time() - SIGNING_EPOCH_S) * 100_000)


def default_state_path(sysid: int) -> Path:
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "ivfm" / f"signing-{sysid}.json"


class SigningState:
    """The signing clock and stream timestamps of a vehicle's links, on disk."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._saved: Any = None
        self._saved_s = -1e18

    def restore(self, signings: list[mavlink.MAVLinkSigning]) -> str:
        """Load the file into ``signings`` (each link's); says what it did."""
        try:
            data = json.loads(self.path.read_text())
            clock = int(data["timestamp"])
            streams = {(int(a), int(b), int(c)): int(t) for a, b, c, t in data["streams"]}
        except FileNotFoundError:
            return f"signing state {self.path}: none yet (a first start)"
        except (OSError, ValueError, KeyError, TypeError) as exc:
            return f"signing state {self.path} unreadable ({exc}): starting without it"
        for signing in signings:
            signing.timestamp = max(signing.timestamp, clock + 1)
            for stream, stamp in streams.items():
                signing.stream_timestamps[stream] = max(
                    stamp, signing.stream_timestamps.get(stream, 0))
        return f"signing state {self.path}: {len(streams)} stream(s), clock restored"

    def save(self, signings: list[mavlink.MAVLinkSigning], now_s: float,
             force: bool = False) -> None:
        """Write the state when it changed, at most every SAVE_EVERY_S (``force``: now)."""
        if not force and now_s - self._saved_s < SAVE_EVERY_S:
            return
        streams: dict[tuple[int, int, int], int] = {}
        for signing in signings:
            for stream, stamp in signing.stream_timestamps.items():
                streams[stream] = max(stamp, streams.get(stream, 0))
        newest = sorted(streams.items(), key=lambda kv: kv[1])[-MAX_STREAMS:]
        data = {"timestamp": max(s.timestamp for s in signings),
                "streams": [[*k, v] for k, v in newest]}
        if data == self._saved:
            self._saved_s = now_s
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_atomic(self.path, json.dumps(data), private=True)
        except OSError:
            return  # a read-only disk costs the replay protection across restarts only
        self._saved, self._saved_s = data, now_s


def is_local(address: tuple[str, int] | None) -> bool:
    """A loopback sender (the same machine)."""
    if address is None:
        return True  # in-process callers
    try:
        return ipaddress.ip_address(address[0]).is_loopback
    except ValueError:
        return False


MAX_SIGNING_TIMESTAMP = 2**48 - 1  # a frame carries 48 bits of it (10 us since 2015)


def apply_setup_signing(signings: list[mavlink.MAVLinkSigning], key: bytes,
                        initial_timestamp: int) -> str:
    """SETUP_SIGNING's key on every link; all zeros turns signing off. Says what it did.
    A timestamp a frame cannot carry is refused (ValueError): the vehicle could not sign
    with it (found by the fuzz run: 2**64 - 1 broke every frame the vehicle sent)."""
    if not 0 <= int(initial_timestamp) <= MAX_SIGNING_TIMESTAMP:
        raise ValueError(f"SETUP_SIGNING refused: initial_timestamp {initial_timestamp} is "
                         "not a 48-bit signing timestamp")
    if not any(key):
        for signing in signings:
            signing.secret_key = None
            signing.sign_outgoing = False
        return "signing off (SETUP_SIGNING with an all-zero key)"
    for signing in signings:
        signing.secret_key = bytes(key)
        signing.sign_outgoing = True
        signing.allow_unsigned_callback = None
        signing.timestamp = max(signing.timestamp, int(initial_timestamp), signing_clock_now())
    return "signing on (key from SETUP_SIGNING, until restart)"
