"""Exporters: grids in, files out (heightmap PNG, SDF model and world, map_server map, preview)."""
