"""How long a Feetech servo's reply may take, and how long to wait before asking again. Pure.

LeRobot's bus gives each reply 50 ms plus the bytes' line time (its
``setPacketTimeout``); ``scservo_sdk`` alone gives ~34 ms at 1 Mbaud. A reply that
misses its window can still land later, and a Feetech status packet names the
servo, not the register: taken as the answer to the next request, it shifts every
later read by one. So whoever asks again after a lost reply first waits past the
window and drops what arrived (the connector's retries, its calibration
restore, the agent's idle calibration check).
"""

from __future__ import annotations

#: The reply window LeRobot's bus sets, in milliseconds, before the bytes' own line time.
LEROBOT_REPLY_WINDOW_MS = 50
#: How long to wait after a lost reply before asking again: past that window, so a late reply
#: has landed (and is dropped) before the next request is sent.
LATE_REPLY_WAIT_S = 0.06
