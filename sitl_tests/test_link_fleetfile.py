"""Fleet files: explicit endpoints, with errors naming file, entry and field."""

from __future__ import annotations

from pathlib import Path

import pytest

from groundctl.link.fleetfile import (
    Endpoint,
    FleetFile,
    FleetFileError,
    load_fleet,
    load_fleet_file,
)


def test_load(tmp_path: Path) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text('[[vehicle]]\nsystem_id = 3\naddress = "127.0.0.1:14561"\n'
                 '[[vehicle]]\nsystem_id = 4\naddress = "10.0.0.4:14550"\n')
    assert load_fleet(p) == [Endpoint(3, "127.0.0.1", 14561), Endpoint(4, "10.0.0.4", 14550)]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ('[[vehicle]]\nsystem_id = 0\naddress = "h:1"\n', "vehicle 1: system_id: must be"),
        ('[[vehicle]]\nsystem_id = 3\naddress = "h"\n', "vehicle 1: address: address 'h'"),
        ('[[vehicle]]\nsystem_id = 3\naddress = "h:99999"\n', "not in 1..65535"),
        ('[[vehicle]]\nsystem_id = 3\naddress = "h:1"\n[[vehicle]]\nsystem_id = 3\n'
         'address = "h:2"\n', "vehicle 2: system_id: 3 appears twice"),
        ("[[vehicle]\n", "not valid TOML"),
        ('[[vehicle]]\nsystem_id = 3\ntrack = -1\n', "vehicle 1: track: must be a non-negative"),
        ('[[vehicle]]\nsystem_id = 3\ntrack = 0\n[[vehicle]]\nsystem_id = 4\ntrack = 0\n',
         "vehicle 2: track: track 0 appears twice"),
        ('[[vehicle]]\nsystem_id = 3\ntrack = 0\n[[vehicle]]\nsystem_id = 4\n',
         "vehicle(s) [4] have no track"),
        ('[[vehicle]]\nsystem_id = 3\nadress = "h:1"\n', "vehicle 1: adress: unknown key"),
        ('[[vehicles]]\nsystem_id = 3\n', "vehicles: unknown table"),
    ],
)
def test_errors(tmp_path: Path, body: str, message: str) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text(body)
    with pytest.raises(FleetFileError) as info:
        load_fleet(p)
    assert str(info.value).startswith(str(p))
    assert message in str(info.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(FleetFileError, match="cannot read"):
        load_fleet(tmp_path / "nope.toml")


def test_tracks_and_addresses_are_both_optional(tmp_path: Path) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text('[[vehicle]]\nsystem_id = 3\ntrack = 1\n'
                 '[[vehicle]]\nsystem_id = 4\naddress = "127.0.0.1:14562"\ntrack = 0\n')
    assert load_fleet_file(p) == FleetFile((3, 4), (Endpoint(4, "127.0.0.1", 14562),),
                                           {3: 1, 4: 0})
