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
        ('[[vehicle]]\nsystem_id = 3\nspare = 1\n', "vehicle 1: spare: must be true or false"),
        ('[[vehicle]]\nsystem_id = 3\nspare = true\ntrack = 0\n',
         "vehicle 1: track: a spare has no track"),
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


def test_spares_are_marked_and_need_no_track(tmp_path: Path) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text('[[vehicle]]\nsystem_id = 3\ntrack = 0\n'
                 '[[vehicle]]\nsystem_id = 12\nspare = true\n'
                 '[[vehicle]]\nsystem_id = 13\nspare = false\ntrack = 1\n')
    fleet = load_fleet_file(p)
    assert fleet.system_ids == (3, 12, 13)
    assert fleet.tracks == {3: 0, 13: 1} and fleet.spares == frozenset({12})
    p.write_text('[[vehicle]]\nsystem_id = 3\n[[vehicle]]\nsystem_id = 12\nspare = true\n')
    assert load_fleet_file(p).tracks == {} and load_fleet_file(p).spares == {12}


_TWO = ('[[network]]\nname = "north"\nconnection = "udp:127.0.0.1:14550"\n'
        '[[network]]\nname = "south"\nconnection = "127.0.0.1:14560"\n'
        'signing_key = "' + "ab" * 32 + '"\n')


def test_networks_name_their_vehicles(tmp_path: Path) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text(_TWO + '[[vehicle]]\nnetwork = "north"\nsystem_id = 3\ntrack = 0\n'
                 '[[vehicle]]\nnetwork = "south"\nsystem_id = 3\ntrack = 1\n'
                 'address = "10.0.0.3:*"\n')
    fleet = load_fleet_file(p)
    assert fleet.system_ids == (3, 1003)
    assert [str(s) for s in fleet.system_ids] == ["3", "2:3"]
    assert fleet.tracks == {3: 0, 1003: 1}
    assert fleet.endpoints == (Endpoint(1003, "10.0.0.3", None),)
    assert [(n.name, n.listen) for n in fleet.networks] == [
        ("north", ("127.0.0.1", 14550)), ("south", ("127.0.0.1", 14560))]
    assert fleet.networks[0].signing_key is None
    assert fleet.networks[1].signing_key == bytes([0xAB]) * 32


@pytest.mark.parametrize(("body", "message"), [
    (_TWO + '[[vehicle]]\nsystem_id = 3\n', "vehicle 1: network: missing"),
    (_TWO + '[[vehicle]]\nnetwork = "east"\nsystem_id = 3\n',
     "vehicle 1: network: 'east' is not a [[network]] name (north, south)"),
    (_TWO + '[[vehicle]]\nnetwork = "south"\nsystem_id = 3\n'
            '[[vehicle]]\nnetwork = "south"\nsystem_id = 3\n',
     "vehicle 2: system_id: 3 appears twice on network 'south'"),
    ('[[network]]\nname = "a"\nconnection = "udp:h:1"\n[[network]]\nname = "a"\n'
     'connection = "udp:h:2"\n', "network 2: name: 'a' appears twice"),
    ('[[network]]\nname = "a"\nconnection = "udp:h:1"\n[[network]]\nname = "b"\n'
     'connection = "udp:h:1"\n', "network 2: connection: 'udp:h:1' is another network's"),
    ('[[network]]\nname = "a"\nconnection = "serial"\n', "network 1: connection: address"),
    ('[[network]]\nname = "a"\nconnection = "udp:h:1"\nsigning_key = "zz"\n',
     "network 1: signing_key: must be 64 hex digits"),
    ('[[network]]\nname = "a"\nconnection = "udp:h:1"\nbaud = 57600\n',
     "network 1: baud: unknown key"),
    ('[[vehicle]]\nnetwork = "a"\nsystem_id = 3\n',
     "vehicle 1: network: 'a' is not a [[network]] name (none given)"),
])
def test_network_errors(tmp_path: Path, body: str, message: str) -> None:
    p = tmp_path / "fleet.toml"
    p.write_text(body)
    with pytest.raises(FleetFileError) as info:
        load_fleet_file(p)
    assert message in str(info.value) and "\n" not in str(info.value)
