"""Writing a world folder: ``folder.py`` is the one writer (and the typed :class:`Result` it
reports); ``terrain.py`` (heightmaps, tiles) and ``walls.py`` (mesh, boxes, polylines) make each
simulator's models and worlds for it; ``names.py`` names the models, unique per content."""
