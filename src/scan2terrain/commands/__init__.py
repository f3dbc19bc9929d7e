"""The commands: one module per family, each a short composition of the stages (readers ->
octree -> grids -> filters -> geometry -> exporters) through the shared steps (steps.py). Each
command computes its world folder (:class:`~scan2terrain.world.folder.WorldFolder`, with the
report's notes), then calls the one writer, ``world.folder.write_world_folder``, once.

maps.py     map2world, image2world; occupancy_folder and height_folder, the grid -> world steps
voxels.py   octree2world; voxels_folder and octree_folder, the octree -> world tail of
            bag2world, cloud2world and octree2world
dem.py      dem2world
scans.py    bag2world, cloud2world, convert, inspect (bags and point-cloud files, octree path)
stream.py   the same end points streamed into grid tiles, on one process or Dask
correct.py  pose correction of a recording (scans.correct)
replay.py   the recording replayed in the world (fidelity files; the fidelity command)
"""
