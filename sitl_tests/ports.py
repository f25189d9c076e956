"""UDP ports for tests that give a port number to two processes (``groundctl sim
--gcs`` and ``groundctl fly --connect``).

The usual "bind port 0, read the number, close" leaves the port free for anyone until
the second process binds it: every other socket of the suite (four workers of flights)
binds port 0 too, and one that got the number in between received a simulated fleet's
telemetry meant for another test (seen: a dry-run's ground station flooded by a `sim
--show` fleet's 9 vehicles standing on the same takeoff slots).  The kernel hands out
port-0 binds only from its ephemeral range, so the ports here come from below it, a
block per xdist worker: nothing else in the suite can be given them.  Two suites at
once on one machine (parallel clones, CI jobs) would pick the same numbers: each port
handed out is also locked (``flock`` on a file of its own in the temporary directory)
for as long as the worker lives, and a port another process holds is passed over.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import socket
import tempfile
from typing import IO

#: Ports per xdist worker.
BLOCK = 200
_counter = itertools.count()
#: The locks of the ports this worker handed out, held until it exits.
_held: list[IO[bytes]] = []


def _ephemeral_low() -> int:
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default


def reserved_udp_port() -> int:
    """A free loopback UDP port no port-0 bind can be given, unique to this worker."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    base = _ephemeral_low() - BLOCK * (index + 1) - 1000
    if base < 1024:
        raise RuntimeError(f"no room below the ephemeral range for worker {worker}")
    for _ in range(BLOCK):
        port = base + next(_counter) % BLOCK
        lock = open(os.path.join(tempfile.gettempdir(),  # noqa: SIM115 - held past here
                                 f"groundctl-test-udp-{port}.lock"),
                    "ab")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue  # another suite on this machine has it
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                lock.close()
                continue  # in use by something outside the suites
        _held.append(lock)
        return port
    raise RuntimeError(f"no free UDP port in {base}..{base + BLOCK - 1}")
