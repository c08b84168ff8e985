"""The master (installed as ``igi.master``): schedules tasks over workers (ZeroMQ broker), merges
their buffers, filters with the discontinuity buffer, accumulates and streams frames to the
viewer; :mod:`igi.master.cli` is the ``igi`` command line."""
