"""A simulated fleet in several processes, flown as one: a dry-run of more vehicles
than one simulator process carries (about 600 on this project's 2-core reference
machine: 1.6 ms of CPU per vehicle per second) is split, one part per MAVLink
network, each part a :class:`~groundctl.sim.process.SimProcess` on the same paced
clock (a participant of its own).

:class:`SimGroup` answers as one :class:`SimProcess` does: a call about one vehicle
goes to the process that flies it, a call about the fleet goes to every process and
their answers are put together (lists in vehicle order, mappings merged, counts summed,
lags the largest).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from groundctl.clock import PacedClock, ScaledClock
from groundctl.errors import SimulatorError
from groundctl.sim.config import SimConfig
from groundctl.sim.process import SimProcess

#: SimFleet methods about one vehicle: which argument names it (by position; a None
#: there, or no such argument, means every vehicle).
VEHICLE_ARGUMENT = {"state": 0, "set_link_faults": 1, "link_faults": 0, "cut_link": 0,
                    "gps_glitch": 1, "refuse_arming": 0, "lose_acks": 1, "motor_failure": 0,
                    "low_battery": 1, "gust": 2, "push": 1, "weaken": 1}
#: Fleet-wide figures put together by something other than the first part's.
SUMMED = frozenset({"overruns"})
LARGEST = frozenset({"max_lag"})


def split_config(config: SimConfig, parts: int) -> list[SimConfig]:
    """``config`` cut into ``parts`` fleets of consecutive vehicles (by network where it
    has several: each network in one part), each with its own seed."""
    n = config.count
    nets = list(config.networks) if config.networks is not None else [1] * n
    groups: list[list[int]] = []
    if config.networks is not None and len(set(nets)) >= parts:
        per = -(-len(set(nets)) // parts)
        order = sorted(set(nets))
        for k in range(parts):
            mine = set(order[k * per:(k + 1) * per])
            groups.append([i for i in range(n) if nets[i] in mine])
    else:
        bounds = np.linspace(0, n, parts + 1).round().astype(int)
        groups = [list(range(int(a), int(b))) for a, b in itertools.pairwise(bounds)]
    groups = [g for g in groups if g]

    def pick(values: Sequence[Any] | np.ndarray | None, idx: list[int]) -> Any:
        if values is None:
            return None
        if isinstance(values, np.ndarray):
            return values[idx]
        return [values[i] for i in idx]

    return [replace(config, count=len(idx), positions=pick(config.positions, idx),
                    ekf_origins=pick(config.ekf_origins, idx),
                    system_ids=pick(config.system_ids, idx),
                    networks=pick(config.networks, idx), seed=config.seed + 7919 * k)
            for k, idx in enumerate(groups)]


class SimGroup:
    """Several simulator processes answering as one (see the module docstring)."""

    def __init__(self, configs: Sequence[SimConfig],
                 clocks: Sequence[ScaledClock | PacedClock]) -> None:
        self.parts: list[SimProcess] = []
        try:
            for config, clock in zip(configs, clocks, strict=True):
                self.parts.append(SimProcess(config, clock))
        except BaseException:
            for part in self.parts:
                part._kill()
            raise
        self.sysids: list[int] = [s for p in self.parts for s in p.sysids]
        """System ids (vehicle ids), in vehicle order."""
        self.ports: list[int] = [q for p in self.parts for q in p.ports]
        self._owner = {s: p for p in self.parts for s in p.sysids}
        self._answers: list[Any] = [None] * len(self.parts)
        self._ready = [False] * len(self.parts)

    @property
    def pid(self) -> int:
        """The first part's process id (:attr:`pids`: every part's)."""
        return self.parts[0].pid

    @property
    def pids(self) -> list[int]:
        return [p.pid for p in self.parts]

    @property
    def alive(self) -> bool:
        return all(p.alive for p in self.parts)

    @property
    def exitcode(self) -> int | None:
        codes = [p.exitcode for p in self.parts]
        bad = [c for c in codes if c not in (None, 0)]
        return bad[0] if bad else (None if None in codes else 0)

    def _part_for(self, name: str, args: tuple[Any, ...], kwargs: dict[str, Any]
                  ) -> SimProcess | None:
        k = VEHICLE_ARGUMENT.get(name)
        if k is None:
            return None
        sysid = args[k] if len(args) > k else kwargs.get("sysid")
        if sysid is None:
            return None
        part = self._owner.get(int(sysid))
        if part is None:
            raise SimulatorError(f"no simulated vehicle {sysid}")
        return part

    def call(self, name: str, *args: Any, **kwargs: Any) -> Any:
        part = self._part_for(name, args, kwargs)
        if part is not None:
            return part.call(name, *args, **kwargs)
        return _merge([p.call(name, *args, **kwargs) for p in self.parts])

    def get(self, name: str) -> Any:
        values = [p.get(name) for p in self.parts]
        if name in SUMMED:
            return sum(values)
        if name in LARGEST:
            return max(values)
        return _merge(values)

    def ask(self, name: str, *args: Any, **kwargs: Any) -> None:
        for k, part in enumerate(self.parts):
            if not self._ready[k]:
                part.ask(name, *args, **kwargs)

    def answer(self) -> tuple[bool, Any]:
        """Every part's answer put together, once all have come."""
        for k, part in enumerate(self.parts):
            if not self._ready[k]:
                ready, value = part.answer()
                if ready:
                    self._ready[k], self._answers[k] = True, value
        if not all(self._ready):
            return False, None
        answers, self._answers = self._answers, [None] * len(self.parts)
        self._ready = [False] * len(self.parts)
        return True, _merge(answers)

    def stop(self) -> None:
        first: SimulatorError | None = None
        for part in self.parts:
            try:
                part.stop()
            except SimulatorError as exc:
                first = first or exc
        if first is not None:
            raise first

    def _kill(self) -> None:
        for part in self.parts:
            part._kill()


def _merge(values: list[Any]) -> Any:
    """The parts' answers as one fleet's: in vehicle order."""
    first = values[0]
    if len(values) == 1 or first is None:
        return first
    if isinstance(first, np.ndarray):
        return np.concatenate(values)
    if isinstance(first, list):
        return [x for v in values for x in v]
    if isinstance(first, tuple):
        return tuple(_merge([v[i] for v in values]) for i in range(len(first)))
    if isinstance(first, dict):
        return {k: x for v in values for k, x in v.items()}
    if isinstance(first, bool):
        return all(values)
    if isinstance(first, (int, float)):
        return sum(values)
    return first
