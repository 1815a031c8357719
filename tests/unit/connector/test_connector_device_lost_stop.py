"""A job stopped for a lost device: the interlock and the motion refusal name the loss, the grace window opens."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.unit

LOST = "device lost: arm arm's serial port: /dev/serial/by-id/usb-arm does not exist"


def test_a_stop_for_a_lost_device_trips_the_interlock_naming_it_and_opens_the_grace_window(
    make_connector, cell_config, client_for
) -> None:
    connector = make_connector(cell_config(None, timeoutSeconds=600))
    connector.cancel(LOST)
    trip = connector.interlock.trip_info
    assert trip is not None and trip.message == LOST
    assert connector.cell.deadline.grace_remaining_s() is not None
    reply = client_for(connector.robot_endpoint).request({"op": "return_to_rest"})
    assert reply["error_type"] == "ShuttingDown" and LOST in reply["error"]
