"""What a log analyst expects in the tlog, asked for once per vehicle, off the critical path.

Low-rate ATTITUDE, BATTERY_STATUS, EXTENDED_SYS_STATE and the estimator's health
(EKF_STATUS_REPORT on ArduPilot, ESTIMATOR_STATUS on PX4) by
MAV_CMD_SET_MESSAGE_INTERVAL, and every parameter once (PARAM_REQUEST_LIST), so
the recording holds them.  Started after a vehicle's show streams are set;
at most :data:`CONCURRENT` vehicles at a time, each request tried once: a
refusal or silence only means the log lacks that message.
"""

from __future__ import annotations

import asyncio
import logging
import weakref

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from groundctl.errors import LinkError
from groundctl.link.flavours import Flavour
from groundctl.link.fleet import FleetLink

log = logging.getLogger(__name__)

#: Message id -> Hz, both autopilots.
LOG_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 1.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
}
#: The estimator's health, per autopilot.
ESTIMATOR = {Flavour.ARDUPILOT: mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
             Flavour.PX4: mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS}
CONCURRENT = 8

_gates: weakref.WeakKeyDictionary[FleetLink, asyncio.Semaphore] = weakref.WeakKeyDictionary()


async def request_log_extras(link: FleetLink, sysid: int) -> None:
    """The log streams and one PARAM_REQUEST_LIST for ``sysid``."""
    gate = _gates.get(link)
    if gate is None:
        gate = _gates[link] = asyncio.Semaphore(CONCURRENT)
    state = link.vehicles.get(sysid)
    flavour = state.flavour if state is not None else None
    rates = dict(LOG_STREAMS)
    if flavour in ESTIMATOR:
        rates[ESTIMATOR[flavour]] = 1.0
    async with gate:
        try:
            link.send_message(sysid, mavlink.MAVLink_param_request_list_message(sysid, 1))
        except LinkError as exc:
            log.debug("vehicle %s: PARAM_REQUEST_LIST not sent: %s", sysid, exc)
        for msg_id, hz in rates.items():
            try:
                await link.set_message_interval(sysid, msg_id, hz, retries=0)
            except LinkError as exc:
                log.debug("vehicle %s: log stream %s not set: %s", sysid, msg_id, exc)
