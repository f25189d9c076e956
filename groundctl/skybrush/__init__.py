"""Shows from and to Skybrush: the compiled ``.skyc`` format and Skybrush Studio's CSV export.

* :mod:`.archive` -- a zip from anywhere, read with its sizes and names checked first;
* :mod:`.model` -- a Skybrush show as read: per drone its home, its trajectory as timed
  Bezier segments (elevated to cubic) and its light keys;
* :mod:`.lights` -- the light program bytecode (Skybrush's ``ledctrl``), both ways;
* :mod:`.reader` / :mod:`.csvshow` / :mod:`.writer` -- ``.skyc`` in, CSV in, ``.skyc`` out;
* :mod:`.convert` -- to and from groundctl's :class:`~groundctl.plan.plan.Plan`;
* :mod:`.conflicts` / :mod:`.repair` -- every separation conflict, and re-planning only
  the conflicting stretches;
* :mod:`.sniff` -- what a file given to a command is;
* :mod:`.importing` -- what the CLI calls.
"""
