"""Pose correction: scan matching, loop closure and the pose graph (``scans.correct``)."""
