"""The commands: one module per family, each a short composition of the stages (readers ->
octree -> grids -> filters -> geometry -> exporters) through the shared steps (steps.py) and the
one world writer (world.py).

maps.py    map2world, image2world; occupancy_world and height_world, the grid -> world steps
voxels.py  octree2world (.bt trees and OctoMap scan files)
dem.py     dem2world
scans.py   bag2world, cloud2world, convert, inspect (bags and point-cloud files, octree path)
stream.py  the same end points streamed into grid tiles, on one process or Dask
"""
