"""scan2terrain: turn what a robot saw into a Gazebo world that lines up with its map frame."""

__version__ = "0.1.0"
