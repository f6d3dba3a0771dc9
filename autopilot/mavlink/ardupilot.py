"""What only the ArduPilot flavour's links take, as ArduCopter answers it:
REQUEST_DATA_STREAM (its stream groups, copter.py) and the banner before the parameter
list (GCS_Param.cpp: "requesting parameters is a convenient way to get extra
information", so a GCS shows it as it connects). Written against link.py's ServerLink.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.mavlink.copter import banner_texts, data_stream_intervals
from contracts.mavlink import mavlink

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink


def say_banner(server: ServerLink, link: GroundLink | None,
               address: tuple[str, int] | None = None) -> None:
    """Copter's banner texts to ``address`` on ``link`` (every link: None)."""
    for text in banner_texts():
        server.send_text(link, mavlink.MAV_SEVERITY_INFO, text, address)


class CopterHandlers:
    """Handlers the server adds in the ArduPilot flavour (``list_parameters``: the
    parameter protocol's own PARAM_REQUEST_LIST handler, called after the banner)."""

    def __init__(self, server: ServerLink, list_parameters: Callable) -> None:
        self.server = server
        self.list_parameters = list_parameters

    def handlers(self) -> dict[str, Callable]:
        return {"REQUEST_DATA_STREAM": self.on_request_data_stream,
                "PARAM_REQUEST_LIST": self.on_param_request_list}

    def on_request_data_stream(self, link: GroundLink, address, msg, now: float) -> None:
        """A stream group's messages at a rate [Hz] on this link; rate 0 or start_stop 0
        stops them; what Copter ignores (an unknown group, start_stop not 0/1) is
        ignored."""
        intervals = data_stream_intervals(msg.req_stream_id, msg.req_message_rate,
                                          msg.start_stop)
        for msg_id, interval in (intervals or {}).items():
            if interval is None:
                link.intervals_s.pop(msg_id, None)
            else:
                link.intervals_s[msg_id] = interval
            link.next_due_s.pop(msg_id, None)

    def on_param_request_list(self, link: GroundLink, address, msg, now: float) -> None:
        say_banner(self.server, link, address)
        self.list_parameters(link, address, msg, now)
