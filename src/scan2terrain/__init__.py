"""scan2terrain: turn what a robot saw into a Gazebo world that lines up with its map frame."""

from __future__ import annotations


def __getattr__(name: str) -> str:
    # The version has one source, the package's metadata (pyproject.toml), read on demand.
    if name == "__version__":
        from importlib.metadata import version

        return version("scan2terrain")
    raise AttributeError(f"module 'scan2terrain' has no attribute {name!r}")
