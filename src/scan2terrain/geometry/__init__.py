"""Geometry: wall cells in, shapes out (outlines, box partitions, meshes). Nothing here writes a
file; the exporters serialise what these compute."""
