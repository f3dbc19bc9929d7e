"""Readers: files in, typed grids out. Nothing here knows about Gazebo."""

from scan2terrain.readers.image import GreyImage, read_grey_image
from scan2terrain.readers.mapserver import MapMetadata, read_map_yaml

__all__ = ["GreyImage", "MapMetadata", "read_grey_image", "read_map_yaml"]
