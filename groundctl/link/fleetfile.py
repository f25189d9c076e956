"""Fleet files: which vehicles fly, where they listen, which plan track each flies.

::

    [[vehicle]]
    system_id = 3
    address = "127.0.0.1:14561"   # optional: where it listens and talks from
    track = 0                      # optional: the plan track it flies (else by position)

    [[vehicle]]
    system_id = 12
    spare = true                   # optional: one of the show's spares (no track)

An address pins its vehicle: only packets from that host and port speak for
that system id (a HEARTBEAT under its id from anywhere else is an address
conflict, whoever comes first).  ``address = "10.0.0.3:*"`` pins the host only,
for a vehicle that talks from a port of its own choosing; it is contacted once
it has spoken.  Either every entry names a track or none does: a half-mapped
fleet is a mistake, not a request for mixed assignment.  A spare (``spare = true``)
names none: it stands on one of the plan's spare pads (the nearest free one) and is
never given a track before the show, whichever way the others are mapped.

Several MAVLink networks (one link each, with its own system ids 1..254) are listed
as ``[[network]]`` tables, in order, and every vehicle says which it is on::

    [[network]]
    name = "north"
    connection = "udp:0.0.0.0:14550"
    signing_key = "00112233..."     # optional: this network's own key (64 hex digits)

    [[vehicle]]
    network = "north"
    system_id = 3

The vehicle is then ``vehicle_id(network, system_id)`` (:mod:`groundctl.vehicleid`:
network 2's system id 3 is ``2:3``), and a system id may appear once per network.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from groundctl.errors import EXIT_USAGE, LinkError
from groundctl.vehicleid import MAX_NETWORKS, vehicle_id


class FleetFileError(LinkError):
    """A fleet file that cannot be used (path, where, message)."""

    exit_code = EXIT_USAGE

    def __init__(self, path: str | Path, where: str, message: str) -> None:
        self.path = str(path)
        self.where = where
        self.message = message
        super().__init__(f"{self.path}: {where}: {message}" if where else f"{self.path}: {message}")


@dataclass(frozen=True)
class Endpoint:
    """Where one vehicle listens."""

    system_id: int
    """MAVLink system id (1-254)."""
    host: str
    """IP address or host name."""
    port: int | None
    """UDP port; None: any port of that host (``host:*``)."""

    @property
    def address(self) -> tuple[str, int] | None:
        """Where to contact it before it has spoken (None: unknown until then)."""
        return None if self.port is None else (self.host, self.port)


def parse_address(text: str) -> tuple[str, int]:
    """``"host:port"`` -> ``(host, port)``; raises ValueError naming the problem."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise ValueError(f"address {text!r} must look like 'host:port'")
    try:
        port = int(port_text)
    except ValueError:
        raise ValueError(f"address {text!r}: port {port_text!r} is not a number") from None
    if not 0 < port < 65536:
        raise ValueError(f"address {text!r}: port {port} is not in 1..65535")
    return host.strip("[]"), port


def parse_pin(text: str) -> tuple[str, int | None]:
    """A fleet file's address: ``"host:port"`` -> ``(host, port)``, ``"host:*"`` (any
    port of that host) -> ``(host, None)``; raises ValueError naming the problem."""
    host, sep, port_text = text.rpartition(":")
    if sep and host and port_text == "*":
        return host.strip("[]"), None
    return parse_address(text)


@dataclass(frozen=True)
class FleetNetwork:
    """One MAVLink network of a fleet file."""

    name: str
    """Its name (what vehicles say in ``network = ...``)."""
    listen: tuple[str, int]
    """The local UDP address its link listens on."""
    signing_key: bytes | None = None
    """Its own MAVLink 2 signing key, if it has one."""


@dataclass(frozen=True)
class FleetFile:
    """Everything a fleet file says."""

    system_ids: tuple[int, ...]
    """Every vehicle listed, in file order (vehicle ids: on network 1 the system id)."""
    endpoints: tuple[Endpoint, ...]
    """The vehicles listed with an address."""
    tracks: dict[int, int]
    """Vehicle id -> plan track (empty when the file maps none)."""
    networks: tuple[FleetNetwork, ...] = ()
    """The ``[[network]]`` tables in order (empty: one network, given by ``--connect``)."""
    spares: frozenset[int] = frozenset()
    """Vehicle ids marked ``spare = true`` (for
    :attr:`RunnerConfig.spare_ids <groundctl.flight.runner.config.RunnerConfig.spare_ids>`)."""


def parse_fleet_file(data: dict[str, object], path: str | Path = "<fleet>") -> FleetFile:
    """The whole fleet file from an already-parsed TOML document."""
    unknown = sorted(set(data) - {"vehicle", "network"})
    if unknown:
        raise FleetFileError(path, unknown[0], "unknown table (expected [[vehicle]] entries "
                                               "and [[network]] tables)")
    networks = _networks(data.get("network", []), path)
    by_name = {n.name: k for k, n in enumerate(networks, start=1)}
    vehicles = data.get("vehicle", [])
    if not isinstance(vehicles, list):
        raise FleetFileError(path, "vehicle", "must be an array of tables ([[vehicle]])")
    endpoints: list[Endpoint] = []
    ids: list[int] = []
    tracks: dict[int, int] = {}
    spares: set[int] = set()
    seen: set[int] = set()
    for i, entry in enumerate(vehicles, start=1):
        where = f"vehicle {i}"
        if not isinstance(entry, dict):
            raise FleetFileError(path, where, "must be a table")
        local = entry.get("system_id")
        if not isinstance(local, int) or isinstance(local, bool) or not 1 <= local <= 254:
            raise FleetFileError(path, f"{where}: system_id",
                                 f"must be an integer in 1..254, got {local!r}")
        net = entry.get("network")
        if net is None and len(networks) > 1:
            raise FleetFileError(path, f"{where}: network", "missing: with several "
                                 f"[[network]] tables each vehicle names one of "
                                 f"{sorted(by_name)}")
        if net is not None and net not in by_name:
            raise FleetFileError(path, f"{where}: network",
                                 f"{net!r} is not a [[network]] name "
                                 f"({', '.join(sorted(by_name)) or 'none given'})")
        sysid = vehicle_id(by_name[net] if net is not None else 1, local)
        if sysid in seen:
            raise FleetFileError(path, f"{where}: system_id",
                                 f"{local} appears twice" + (f" on network {net!r}"
                                                             if networks else ""))
        seen.add(sysid)
        ids.append(sysid)
        extra = sorted(set(entry) - {"system_id", "address", "track", "network", "spare"})
        if extra:
            raise FleetFileError(path, f"{where}: {extra[0]}", "unknown key (expected "
                                 "system_id, address, track, network, spare)")
        spare = entry.get("spare", False)
        if not isinstance(spare, bool):
            raise FleetFileError(path, f"{where}: spare", f"must be true or false, got "
                                                          f"{spare!r}")
        if spare:
            if "track" in entry:
                raise FleetFileError(path, f"{where}: track", "a spare has no track (it "
                                     "takes one over in flight): give it one or the other")
            spares.add(sysid)
        track = entry.get("track")
        if track is not None:
            if not isinstance(track, int) or isinstance(track, bool) or track < 0:
                raise FleetFileError(path, f"{where}: track",
                                     f"must be a non-negative integer, got {track!r}")
            if track in tracks.values():
                raise FleetFileError(path, f"{where}: track", f"track {track} appears twice")
            tracks[sysid] = track
        address = entry.get("address")
        if address is None:
            continue
        if not isinstance(address, str):
            raise FleetFileError(path, f"{where}: address",
                                 f"must be a string 'host:port', got {address!r}")
        try:
            host, port = parse_pin(address)
        except ValueError as exc:
            raise FleetFileError(path, f"{where}: address", str(exc)) from exc
        endpoints.append(Endpoint(sysid, host, port))
    if tracks and len(tracks) + len(spares) != len(ids):
        missing = [s for s in ids if s not in tracks and s not in spares]
        raise FleetFileError(path, "track", f"vehicle(s) {missing} have no track: give every "
                                            "vehicle a track (or spare = true), or none "
                                            "(assign by position)")
    return FleetFile(tuple(ids), tuple(endpoints), tracks, networks, frozenset(spares))


def _networks(tables: object, path: str | Path) -> tuple[FleetNetwork, ...]:
    """The ``[[network]]`` tables, checked."""
    if not isinstance(tables, list):
        raise FleetFileError(path, "network", "must be an array of tables ([[network]])")
    if len(tables) > MAX_NETWORKS:
        raise FleetFileError(path, "network", f"{len(tables)} networks: at most "
                                              f"{MAX_NETWORKS}")
    out: list[FleetNetwork] = []
    for i, table in enumerate(tables, start=1):
        where = f"network {i}"
        if not isinstance(table, dict):
            raise FleetFileError(path, where, "must be a table")
        extra = sorted(set(table) - {"name", "connection", "signing_key"})
        if extra:
            raise FleetFileError(path, f"{where}: {extra[0]}",
                                 "unknown key (expected name, connection, signing_key)")
        name = table.get("name")
        if not isinstance(name, str) or not name.strip():
            raise FleetFileError(path, f"{where}: name", f"must be a non-empty string, got "
                                                         f"{name!r}")
        if any(n.name == name for n in out):
            raise FleetFileError(path, f"{where}: name", f"{name!r} appears twice")
        connection = table.get("connection")
        if not isinstance(connection, str):
            raise FleetFileError(path, f"{where}: connection",
                                 f"must be a string 'udp:host:port', got {connection!r}")
        text = connection.removeprefix("udpin:").removeprefix("udp:")
        try:
            listen = parse_address(text)
        except ValueError as exc:
            raise FleetFileError(path, f"{where}: connection", str(exc)) from None
        if any(n.listen == listen for n in out):
            raise FleetFileError(path, f"{where}: connection",
                                 f"{connection!r} is another network's too")
        key_text = table.get("signing_key")
        key: bytes | None = None
        if key_text is not None:
            try:
                key = bytes.fromhex(key_text) if isinstance(key_text, str) else b""
            except ValueError:
                key = b""
            if len(key) != 32:
                raise FleetFileError(path, f"{where}: signing_key", "must be 64 hex digits")
        out.append(FleetNetwork(name, listen, key))
    return tuple(out)


def load_fleet(path: str | Path) -> list[Endpoint]:
    """Endpoints listed in the fleet file at ``path``."""
    return list(load_fleet_file(path).endpoints)


def load_fleet_file(path: str | Path) -> FleetFile:
    """Everything the fleet file at ``path`` says."""
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise FleetFileError(path, "", f"cannot read: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FleetFileError(path, "", f"not valid TOML: {exc}") from exc
    return parse_fleet_file(data, path)
