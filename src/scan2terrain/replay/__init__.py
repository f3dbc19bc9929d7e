"""Replay: the recorded beams cast into a world's collision geometry as written, and how far
the simulated ranges are from the recorded ones (``beams.py``, ``cast.py``)."""
