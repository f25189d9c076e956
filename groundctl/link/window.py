"""Work on every vehicle at once, but only a bounded number per MAVLink network at a time.

Pre-flight talks to each vehicle in exchanges of several round trips (a parameter
read with four requests outstanding, a fence upload point by point).  Started for
1,000 vehicles at once that is thousands of requests in one burst on four links, and
their answers arrive as one burst too: a radio drops them, a loopback socket overflows,
and every exchange then waits for its retries.  Here each network lets
:data:`PER_NETWORK` vehicles work at a time and the next starts as one finishes, so a
link carries a steady load whatever the fleet's size, and networks go on side by side.
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Iterable
from typing import TypeVar

from groundctl.vehicleid import network_index

T = TypeVar("T")

#: Vehicles of one network in a pre-flight exchange at once (each with its own window of
#: requests: four parameters, or one fence point).
PER_NETWORK = 32


async def per_network(ids: Iterable[int], work: Callable[[int], Awaitable[T]], *,
                      limit: int = PER_NETWORK) -> list[T]:
    """``work(vid)`` for every vehicle id, at most ``limit`` at a time on each network;
    the results in the order of ``ids``.  An exception from one vehicle's work is
    raised once the others have finished (as ``asyncio.gather`` with its results
    collected first: no exchange is left running unawaited)."""
    if limit < 1:
        raise ValueError(f"`limit` must be at least 1, got {limit}")
    gates: dict[int, asyncio.Semaphore] = {}

    async def one(vid: int) -> T:
        gate = gates.setdefault(network_index(vid), asyncio.Semaphore(limit))
        async with gate:
            return await work(vid)

    results = await asyncio.gather(*(one(v) for v in ids), return_exceptions=True)
    for r in results:
        if isinstance(r, BaseException):
            raise r
    return results  # type: ignore[return-value]
