"""How long a Feetech servo's reply may take, and how long to wait before asking again.

LeRobot's bus gives each reply 50 ms plus the bytes' line time (its
``setPacketTimeout``); ``scservo_sdk`` alone gives ~34 ms at 1 Mbaud. A reply that
misses its window can still land later, and a Feetech status packet names the
servo, not the register: taken as the answer to the next request, it shifts every
later read by one. So whoever asks again after a lost reply first waits past the
window and drops what arrived (the connector's retries, its calibration
restore, the agent's idle calibration check and telemetry).
"""

from __future__ import annotations

from typing import Any

#: The reply window LeRobot's bus sets, in milliseconds, before the bytes' own line time.
LEROBOT_REPLY_WINDOW_MS = 50
#: How long to wait after a lost reply before asking again: past that window, so a late reply
#: has landed (and is dropped) before the next request is sent.
LATE_REPLY_WAIT_S = 0.06


def use_lerobot_reply_window(handler: Any) -> None:
    """Give each reply the window LeRobot's bus gives it (50 ms plus the bytes' time).

    Why: the SDK's own window (~34 ms at 1 Mbaud) is shorter than the one LeRobot
    patches in, and a servo (or a loaded machine's simulator) answering within
    LeRobot's window must read the same here as through LeRobot.
    """

    def set_packet_timeout(packet_length: int) -> None:
        handler.packet_start_time = handler.getCurrentTime()
        handler.packet_timeout = handler.tx_time_per_byte * (packet_length + 3.0) + LEROBOT_REPLY_WINDOW_MS

    handler.setPacketTimeout = set_packet_timeout
