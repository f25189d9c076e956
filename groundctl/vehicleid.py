"""How a vehicle is named when a ground station flies several MAVLink networks.

A network is one link (a UDP endpoint) with its own system id space 1..254, so a
vehicle is (network, system id).  groundctl keeps it one integer, the *vehicle id*
``(network - 1) * NETWORK_STRIDE + system id``, so everything that keys, sorts or
sends vehicles by number (the sequence, the guard, the report, numpy arrays) works
unchanged, and on the first network the vehicle id *is* the system id.

It is spelled one way everywhere a person reads it: ``17`` for network 1's system
id 17 (so every one-network spelling is as it always was), ``2:17`` for network 2's.
:class:`VehicleId` is an ``int`` that prints itself so (in f-strings, ``str`` and
``repr``); JSON, which writes integers as numbers, carries the vehicle id itself
(``2:17`` is 1017), and :func:`parse_vehicle` reads either form back.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

#: Vehicle ids of network n are (n - 1) * NETWORK_STRIDE + 1 .. + 254: decimal, so a
#: vehicle id read as a number still shows its network and system id (1017 is 2:17).
NETWORK_STRIDE: Final = 1000
#: MAVLink system ids a vehicle may have (255 is conventionally a ground station's).
MAX_SYSID: Final = 254
#: At most this many networks (10 x 254 vehicles).
MAX_NETWORKS: Final = 10

_NUMERIC_FORMATS = frozenset("bcdoxXn")


class VehicleId(int):
    """A vehicle id that prints as its spelling (``17``, ``2:17``)."""

    __slots__ = ()

    def __new__(cls, value: int) -> VehicleId:
        return super().__new__(cls, value)

    @property
    def network(self) -> int:
        """Its network, numbered from 1."""
        return int(self) // NETWORK_STRIDE + 1

    @property
    def sysid(self) -> int:
        """Its MAVLink system id on its network."""
        return int(self) % NETWORK_STRIDE

    def __str__(self) -> str:
        return spell(int(self))

    __repr__ = __str__

    def __format__(self, spec: str) -> str:
        if spec and spec[-1] in _NUMERIC_FORMATS:
            return int.__format__(self, spec)
        return format(str(self), spec)


def vehicle_id(network: int, sysid: int) -> VehicleId:
    """The vehicle id of system id ``sysid`` on network ``network`` (from 1)."""
    if not 1 <= network <= MAX_NETWORKS:
        raise ValueError(f"network {network} is not in 1..{MAX_NETWORKS}")
    if not 1 <= sysid <= 255:
        raise ValueError(f"system id {sysid} is not in 1..255")
    return VehicleId((network - 1) * NETWORK_STRIDE + sysid)


def network_of(vid: int) -> int:
    """The network (from 1) of a vehicle id."""
    return int(vid) // NETWORK_STRIDE + 1


def network_index(vid: int) -> int:
    """The network of a vehicle id, from 0 (a list index)."""
    return int(vid) // NETWORK_STRIDE


def sysid_of(vid: int) -> int:
    """The MAVLink system id of a vehicle id on its network."""
    return int(vid) % NETWORK_STRIDE


def spell(vid: int) -> str:
    """``17`` on network 1, ``2:17`` on network 2."""
    net, sysid = divmod(int(vid), NETWORK_STRIDE)
    return str(sysid) if net == 0 else f"{net + 1}:{sysid}"


def spell_many(ids: Iterable[int], most: int = 12) -> str:
    """Vehicles as a short list, runs folded: ``1-4, 7, 9, 2:1-2:250``; past ``most``
    pieces, ``... and N more`` (a line for a person, at any fleet size)."""
    pieces: list[str] = []
    run: list[int] = []

    def close() -> None:
        if len(run) > 2:
            pieces.append(f"{spell(run[0])}-{spell(run[-1])}")
        else:
            pieces.extend(spell(v) for v in run)

    for v in sorted(set(int(i) for i in ids)):
        if run and v == run[-1] + 1:
            run.append(v)
            continue
        close()
        run = [v]
    close()
    if len(pieces) > most:
        left = len(pieces) - most
        return ", ".join(pieces[:most]) + f", ... and {left} more"
    return ", ".join(pieces)


def parse_vehicle(text: str) -> VehicleId:
    """A vehicle as a person writes it: ``17``, ``2:17`` or the vehicle id ``1017``.

    Raises ValueError with a one-line reason for anything else.
    """
    text = text.strip()
    try:
        if ":" in text:
            net_text, sys_text = text.split(":", 1)
            return vehicle_id(int(net_text), int(sys_text))
        value = int(text)
    except ValueError as exc:
        raise ValueError(f"{text!r} is not a vehicle (write 17, or 2:17 for network 2's "
                         f"system id 17): {exc}") from None
    if value < 1 or not 1 <= value % NETWORK_STRIDE <= 255 \
            or value // NETWORK_STRIDE >= MAX_NETWORKS:
        raise ValueError(f"{text!r} is not a vehicle (write 17, or 2:17 for network 2's "
                         "system id 17)")
    return VehicleId(value)


def networks_for(drones: int, asked: int = 0) -> int:
    """How many networks a fleet of ``drones`` needs: ``asked`` (``--networks``), or as
    many as :data:`MAX_SYSID` system ids each need; ValueError with a one-line reason."""
    needed = -(-drones // MAX_SYSID)
    if needed > MAX_NETWORKS:
        raise ValueError(f"at most {MAX_NETWORKS * MAX_SYSID} vehicles ({MAX_NETWORKS} "
                         f"networks of {MAX_SYSID}); the fleet has {drones}")
    if asked and asked < needed:
        raise ValueError(f"--networks {asked} is too few for {drones} vehicles "
                         f"({MAX_SYSID} per network): at least {needed}")
    if asked > MAX_NETWORKS:
        raise ValueError(f"--networks must be in 1..{MAX_NETWORKS}, got {asked}")
    return max(asked, needed, 1)


def network_layout(drones: int, networks: int) -> tuple[list[int], list[int]]:
    """(network from 1, system id) of each of ``drones`` vehicles spread over
    ``networks``: consecutive blocks of the takeoff slots, as even as they go, numbered
    from 1 on each network."""
    per = -(-drones // networks)
    nets = [i // per + 1 for i in range(drones)]
    return nets, [i % per + 1 for i in range(drones)]
