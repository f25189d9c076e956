"""Fleet files: explicit vehicle endpoints, for vehicles that do not find us first.

::

    [[vehicle]]
    system_id = 3
    address = "127.0.0.1:14561"
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from groundctl.errors import EXIT_USAGE, LinkError


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
    port: int
    """UDP port."""

    @property
    def address(self) -> tuple[str, int]:
        return (self.host, self.port)


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


def parse_fleet(data: dict[str, object], path: str | Path = "<fleet>") -> list[Endpoint]:
    """Endpoints from an already-parsed fleet TOML document."""
    vehicles = data.get("vehicle", [])
    if not isinstance(vehicles, list):
        raise FleetFileError(path, "vehicle", "must be an array of tables ([[vehicle]])")
    endpoints: list[Endpoint] = []
    seen: set[int] = set()
    for i, entry in enumerate(vehicles, start=1):
        where = f"vehicle {i}"
        if not isinstance(entry, dict):
            raise FleetFileError(path, where, "must be a table")
        sysid = entry.get("system_id")
        if not isinstance(sysid, int) or isinstance(sysid, bool) or not 1 <= sysid <= 254:
            raise FleetFileError(path, f"{where}: system_id",
                                 f"must be an integer in 1..254, got {sysid!r}")
        if sysid in seen:
            raise FleetFileError(path, f"{where}: system_id", f"{sysid} appears twice")
        seen.add(sysid)
        address = entry.get("address")
        if not isinstance(address, str):
            raise FleetFileError(path, f"{where}: address",
                                 f"must be a string 'host:port', got {address!r}")
        try:
            host, port = parse_address(address)
        except ValueError as exc:
            raise FleetFileError(path, f"{where}: address", str(exc)) from exc
        endpoints.append(Endpoint(sysid, host, port))
    return endpoints


def load_fleet(path: str | Path) -> list[Endpoint]:
    """Endpoints listed in the fleet file at ``path``."""
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise FleetFileError(path, "", f"cannot read: {exc.strerror or exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise FleetFileError(path, "", f"not valid TOML: {exc}") from exc
    return parse_fleet(data, path)
