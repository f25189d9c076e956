"""Show executor: the pure (I/O-free) core.

* :mod:`~groundctl.execute.frames` — show frame <-> geodetic <-> each vehicle's NED.
* :mod:`~groundctl.execute.mapping` — which vehicle flies which plan track.
* :mod:`~groundctl.execute.preflight` — pre-flight checks and the per-vehicle report.
* :mod:`~groundctl.execute.setpoints` — per-vehicle setpoints and LED send decisions.
* :mod:`~groundctl.execute.sequence` — the flight sequence state machine.

The async driver that runs these against a :class:`~groundctl.link.FleetLink`
lives apart from them: everything here takes the time as an argument.
"""
