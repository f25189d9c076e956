"""Rerun views of a plan, a live flight and a recorded one.

Pure parts (no Rerun, no files): :mod:`~groundctl.viz.tlogread` decodes a
tlog into arrays, :mod:`~groundctl.viz.flight` turns them into what is shown
(positions on the executor's ticks, LED colours, tracking error, minimum
separation).  I/O: :mod:`~groundctl.viz.scene` writes them to a Rerun
recording with ``send_columns``, :mod:`~groundctl.viz.replay` reads a
recording directory, :mod:`~groundctl.viz.live` streams a flight as it flies.
"""
