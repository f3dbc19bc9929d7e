"""Voxel worlds (``world.geometry: voxels``): the occupied voxels themselves as static mesh
geometry (geometry/voxel_mesh.py), cut into chunks, on a ground slab under the lowest voxel,
written in map coordinates and handed to the one writer.

What the world holds, in the map (= world) frame, metres:

* every occupied voxel whose centre lies in ``[octree.z_min, octree.z_max]``, exactly (a point
  is inside the meshes iff it is inside an occupied voxel, up to the hair that keeps solids
  touching at an edge or a corner apart); unknown and free voxels are empty space;
* a ground slab (``GROUND_THICKNESS`` thick, ``GROUND_MARGIN`` wider all round) whose top is
  the bottom of the lowest voxels (:data:`GROUND_QUANTILE`), so a robot never falls into
  unknown space;
* map/: octomap_server's projection of the voxels in the z band, or, without a band, of those
  between 0.3 m and 2 m above the ground (the obstacles a ground robot meets; the floor
  itself would mark every cell occupied), where a column with nothing occupied there whose
  floor was seen (an occupied voxel within 0.3 m of the ground) is free, lined up with the
  world;
* spawn.yaml: a free spot on the floor (the highest voxel top within 0.3 m of the ground).

A tree swept by a 2D laser (:func:`scan_plane`: its occupied voxels lie within 0.3 m of
height and its free voxels among them, never above or below: the rays stayed in one plane)
holds no floor and walls one scan plane high, which a robot would drive over. Its occupied
columns become walls ``terrain.height`` high (rounded up to whole voxels) on a ground at
z = 0, as the walls of the other geometries, and map/ is the projection of the whole tree
(or of the z band): the walls and the free space the laser swept. A thin tree without free
voxels (end points only) is taken for a floor: nothing tells it from one.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from scan2terrain.config import Config
from scan2terrain.errors import InputError
from scan2terrain.exporters import meshfile, sdf
from scan2terrain.exporters.heightmap import CLASSIC, GZ
from scan2terrain.exporters.preview import preview_png
from scan2terrain.filters.voxels3d import remove_small_components
from scan2terrain.geometry.voxel_mesh import (
    TooManyChunks,
    TooManyTriangles,
    VoxelChunk,
    mesh_voxels,
)
from scan2terrain.grids.occupied import occupied_voxels
from scan2terrain.grids.projection import column_stats, project_occupancy
from scan2terrain.grids.spawn import Around
from scan2terrain.octree.keys import KEY_OFFSET
from scan2terrain.types import FREE, OCCUPIED, UNKNOWN, OccupancyGrid, StartPose
from scan2terrain.world.folder import (
    Result,
    WorldFolder,
    map_notes,
    sim_world,
)
from scan2terrain.world.names import unique_name
from scan2terrain.world.preview import Preview
from scan2terrain.world.spawn import spawn_for

if TYPE_CHECKING:
    from scan2terrain.octree.colour import VoxelColours

#: The floor a spawn stands on and the obstacles map/ shows, above the ground (metres).
FLOOR_BAND = 0.3
OBSTACLE_TOP = 2.0
#: The ground is the bottom of the voxel layer below which lie fewer than this share of the
#: voxels: a few stray voxels under the floor (geb079.bt has one, 16 cm below) do not lower it.
GROUND_QUANTILE = 0.001
#: Most chunks (a model holds a collision and a visual per chunk, three files each).
MAX_CHUNKS = 4096
#: Most colours in the visual meshes (a submesh and a material each: draw calls).
MAX_COLOURS = 64
#: A tree is one scan plane (see :func:`scan_plane`) when its occupied voxels span at most
#: this height (metres): then none reaches the obstacles of map/ above the floor band.
SCAN_PLANE_SPAN = FLOOR_BAND
#: Most occupied voxels meshed: meshing holds about 2 KB a voxel at its peak today (10 M voxels
#: took 20 GB), so larger sets are refused before any work instead of exhausting memory.
MAX_MESH_VOXELS = 4_000_000


def voxel_mesh_folder(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    resolution: float,
    *,
    source: Path,
    cfg: Config,
    start: StartPose | None = None,
    runs: NDArray[np.uint16] | None = None,
    colours: VoxelColours | None = None,
) -> WorldFolder:
    """Known voxels (OctoMap keys, occupied or free; ``runs`` as in grids.projection) to a world
    whose geometry is the occupied voxels in the z band (see the module docstring); with
    ``colours`` (the points' mean colour per voxel) the visuals carry them."""

    o, w = cfg.octree, cfg.world
    z_min, z_max = o.z_band
    key_side = resolution  # the octree's (the voxels may be coarsened)
    lattice, resolution, rgb, left_out, plane = _solid_lattice(
        keys, occupied, runs, resolution, source=source, cfg=cfg, colours=colours
    )
    plane_z = [] if plane is None else ((np.array(plane) - KEY_OFFSET + [0, 1]) * key_side).tolist()
    cells = max(1, round(w.chunk / resolution))
    palette = labels = None
    if rgb is not None:
        palette, labels = meshfile.quantise_colours(rgb, MAX_COLOURS)
    chunks = _chunks(lattice, resolution, cells, labels, w.chunk, w.max_triangles, source)
    # The ground: a slab under the lowest voxels, over the voxels' extent.
    lo = lattice.min(axis=0) * resolution
    hi = (lattice.max(axis=0) + 1) * resolution
    layers = np.sort(lattice[:, 2])
    z_ground = float(layers[int(GROUND_QUANTILE * len(layers))] * resolution)
    ground = sdf.Ground(
        (float(lo[0] + hi[0]) / 2, float(lo[1] + hi[1]) / 2),
        (float(hi[0] - lo[0]), float(hi[1] - lo[1])),
        z=z_ground,
    )
    # map/ and the spawn: the projection of the obstacles, and the floor's height.
    banded = (o.z_min, o.z_max) != (None, None)
    if banded or plane is not None:  # a scan plane: the whole tree, as octomap_server's map
        band = (z_min, z_max)
    else:
        band = (z_ground + FLOOR_BAND, z_ground + OBSTACLE_TOP)
    map_out = project_occupancy(keys, occupied, resolution, z_min=band[0], z_max=band[1], runs=runs)
    if plane is None:
        floor = column_stats(
            keys, occupied, resolution, z_min=z_ground, z_max=z_ground + FLOOR_BAND, runs=runs
        )
        floor_top = np.where(floor.known, floor.max_z + resolution / 2, z_ground)
        if not banded:  # the floor seen with nothing on it: free (end points hold no free voxel)
            seen = floor.known & (map_out.data == UNKNOWN)
            map_out = map_out.with_data(np.where(seen, FREE, map_out.data).astype(np.int8))
    else:
        floor_top = np.full(map_out.shape, z_ground)
    walls = map_out.data == OCCUPIED
    wall_top = float(hi[2]) if plane is not None else z_ground + OBSTACLE_TOP
    on_slab, around = _slab_around(map_out, ground)
    spawn = spawn_for(
        np.where(walls, wall_top, floor_top).astype(np.float64),
        resolution,
        map_out.origin,
        start,
        ground=~walls & on_slab,
        free=map_out.data == FREE,
        around=around,
    )
    triangles = sum(len(c.mesh.faces) for c in chunks)
    summary = (
        f"{len(lattice)} occupied voxels of {resolution!r} m in {len(chunks)} chunks of up to"
        f" {cells * resolution:g} m, {triangles} triangles"
    )
    described = (
        f" Generated by scan2terrain from {source.name}: {summary}, on a ground slab whose top"
        f" is z = {z_ground!r} (under the lowest voxels). Unknown and free voxels are"
        " empty space. Map frame (x, y, z) = world (x, y, z) in gz-sim and Gazebo Classic.\n"
    )
    files: dict[str, bytes] = {}
    stems = []
    for c in chunks:
        stem = "voxels_" + "_".join(str(i) for i in c.index)
        stems.append(stem)
        base = f"{sdf.MESH_DIR}/{stem}"
        files[f"{base}.stl"] = meshfile.stl_bytes(c.mesh)
        face_colours = None if palette is None else palette[c.face_labels]
        files[f"{base}.dae"] = meshfile.dae_bytes(c.mesh, stem, face_colours=face_colours)
        files[f"{base}.obj"] = meshfile.obj_bytes(c.mesh)
    payload = repr(("voxels", resolution, w.chunk, w.min_voxels, band)).encode()
    base_name = unique_name(source, lattice.tobytes() + payload, cfg)
    size_z = float(hi[2] - lo[2])
    result = Result(
        resolution=resolution, size_z=size_z, geometry="voxels", walls=summary,
        spawn=spawn, preview_label="the 2D projection (map/)",
    )  # fmt: skip
    if palette is not None:
        result.notes.append(
            f"colour: each voxel the mean of its points' RGB (grey without), {len(palette)}"
            " colours in the visual meshes"
        )
    if left_out:
        result.notes.append(f"{left_out} voxels in components under {w.min_voxels} voxels left out")
    if plane is not None:
        result.notes.append(
            f"one scan plane (a 2D laser): the occupied voxels lie between z = {plane_z[0]:g}"
            f" and {plane_z[1]:g} m, amid the free space the rays swept, and no floor was"
            f" seen: each occupied column is a wall {size_z:g} m high (terrain.height"
            f" {cfg.terrain.height:g} m, whole voxels) from the ground at z = 0, as the other"
            " geometries build walls; map/: the projection of the whole tree"
            + ("" if not banded else " in the z band")
        )
    elif not banded:
        result.notes.append(
            f"map/: the voxels {FLOOR_BAND:g} to {OBSTACLE_TOP:g} m above the ground at z ="
            f" {z_ground:g} (no --z-min/--z-max); free where only the floor was seen"
        )
    result.notes.extend(map_notes(cfg, map_out))
    sims = (GZ, CLASSIC) if w.simulator == "both" else (w.simulator,)
    parts = []
    for sim in sims:
        name = base_name if sim == GZ or len(sims) == 1 else f"{base_name}_classic"
        p = sdf.walls_placement(sim, name, "voxels", ground, size_z)
        model = {f"models/{name}/{rel}": data for rel, data in files.items()}
        model[f"models/{name}/model.sdf"] = sdf.voxels_model_sdf(
            p, ground, stems, comment=described, coloured=palette is not None
        )
        model[f"models/{name}/model.config"] = sdf.model_config(p, f"Voxels from {source.name}")
        parts.append(sim_world(p, model, cfg=cfg, comment=described, spawn=spawn))
    preview = Preview(preview_png(map_out.data, None, occupancy=True), result.preview_label)
    # The projection is in world axes already (yaw 0, on voxel boundaries).
    return WorldFolder(source, result, parts, map_out, preview, {}, cfg)


def _solid_lattice(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    runs: NDArray[np.uint16] | None,
    resolution: float,
    *,
    source: Path,
    cfg: Config,
    colours: VoxelColours | None,
) -> tuple[NDArray[np.int64], float, NDArray[np.uint8] | None, int, tuple[int, int] | None]:
    """The occupied voxels to mesh, as a lattice (keys less KEY_OFFSET): those in the z band,
    coarsened to ``world.voxel_size``, small components left out, a scan plane extruded; with
    the voxel side, their colours, how many were left out and the scan plane (keys) or None."""
    o, w = cfg.octree, cfg.world
    solid = occupied_voxels(keys, occupied, runs, source, why="world.geometry voxels")
    if len(solid) == 0:
        raise InputError(source, "the octree holds no occupied voxel: nothing to make a world of")
    plane = scan_plane(keys, occupied, runs, resolution)
    z_min, z_max = o.z_band
    centre_z = (solid[:, 2].astype(np.float64) - KEY_OFFSET + 0.5) * resolution
    solid = solid[(centre_z >= z_min) & (centre_z <= z_max)]
    if len(solid) == 0:
        raise InputError(source, "no occupied voxel in the z band: nothing to make a world of")
    if len(solid) > MAX_MESH_VOXELS:
        raise InputError(
            source,
            f"{len(solid)} occupied voxels in the z band, more than the {MAX_MESH_VOXELS} that"
            " --geometry voxels meshes: choose a coarser --resolution or a narrower"
            " --z-min/--z-max band",
        )
    rgb = None if colours is None else colours.mean(solid)
    lattice = solid.astype(np.int64) - KEY_OFFSET
    if w.voxel_size is not None:
        lattice, resolution, rgb = _coarser(lattice, resolution, w.voxel_size, source, rgb)
    kept = len(lattice)
    if w.min_voxels > 1:
        keep = remove_small_components(lattice, w.min_voxels)
        lattice = lattice[keep]
        rgb = None if rgb is None else rgb[keep]
        if len(lattice) == 0:
            raise InputError(
                source, f"every occupied voxel is in a component under world.min_voxels"
                f" {w.min_voxels}: nothing is left"
            )  # fmt: skip
    left_out = kept - len(lattice)
    if plane is not None:
        lattice, rgb = _extrude(lattice, rgb, cfg.terrain.height, resolution, source)
    return lattice, resolution, rgb, left_out, plane


def _chunks(
    lattice: NDArray[np.int64],
    resolution: float,
    cells: int,
    labels: NDArray[np.integer] | None,
    chunk: float,
    max_triangles: int,
    source: Path,
) -> list[VoxelChunk]:
    """The lattice meshed in chunks of ``cells`` voxels a side; too many chunks or triangles
    refused in the words of the options that change them."""
    try:
        return mesh_voxels(
            lattice, resolution, chunk_cells=cells, labels=labels,
            max_triangles=max_triangles, max_chunks=MAX_CHUNKS,
        )  # fmt: skip
    except TooManyChunks as exc:
        raise InputError(
            source,
            f"--chunk {chunk:g} m cuts the voxels into {exc.count} chunks, more than"
            f" {MAX_CHUNKS} (three mesh files and two SDF elements each): choose a larger"
            " --chunk",
        ) from exc
    except TooManyTriangles as exc:
        raise InputError(
            source,
            f"the voxel meshes would hold {exc.count} triangles, over world.max_triangles"
            f" {exc.limit}: raise it (--max-triangles), choose a coarser --resolution or a"
            " narrower --z-min/--z-max band",
        ) from exc


def _slab_around(grid: OccupancyGrid, ground: sdf.Ground) -> tuple[NDArray[np.bool_], Around]:
    """Where the ground slab (``GROUND_MARGIN`` beyond the voxels) is under ``grid`` (yaw 0,
    as projected from keys): the cells wholly on it, and the whole cells of it beyond the grid
    (its top is ``ground.z``). Free space the rays swept may reach past the slab."""
    r, (rows, cols) = grid.resolution, grid.shape
    x0, y0 = grid.origin.x, grid.origin.y
    sx, sy = (s / 2 + sdf.GROUND_MARGIN for s in ground.size)
    # Slab edges in cells from the grid's lower-left corner (a hair of rounding forgiven).
    left, right = ((ground.centre[0] - x0 + d * sx) / r for d in (-1, 1))
    bottom, top = ((ground.centre[1] - y0 + d * sy) / r for d in (-1, 1))
    eps = 1e-6
    c, rr = np.arange(cols), np.arange(rows)
    on_x = (c >= left - eps) & (c + 1 <= right + eps)
    on_y = (rr >= bottom - eps) & (rr + 1 <= top + eps)
    cells = (
        math.floor(-left + eps), math.floor(-bottom + eps),
        math.floor(right - cols + eps), math.floor(top - rows + eps),
    )  # fmt: skip
    return on_y[:, None] & on_x[None, :], Around(cells, ground.z)


def scan_plane(
    keys: NDArray[np.uint16],
    occupied: NDArray[np.bool_],
    runs: NDArray[np.uint16] | None,
    resolution: float,
) -> tuple[int, int] | None:
    """The lowest and highest z key of the occupied voxels of a tree swept by one planar (2D)
    laser, else None: the occupied voxels span at most :data:`SCAN_PLANE_SPAN`, and there are
    free voxels, all in the occupied voxels' z keys (a floor seen from above has its free space
    over it; end points alone have none). ``runs`` as in grids.projection."""
    free = ~occupied
    if not free.any():
        return None
    bottom = keys[:, 2].astype(np.int64)
    top = bottom if runs is None else bottom + runs.astype(np.int64) - 1
    lo, hi = int(bottom[occupied].min()), int(top[occupied].max())
    if (hi - lo + 1) * resolution > SCAN_PLANE_SPAN + 1e-9 * resolution:
        return None
    if int(bottom[free].min()) < lo or int(top[free].max()) > hi:
        return None
    return lo, hi


def _extrude(
    lattice: NDArray[np.int64],
    rgb: NDArray[np.uint8] | None,
    height: float,
    resolution: float,
    source: Path,
) -> tuple[NDArray[np.int64], NDArray[np.uint8] | None]:
    """Each (x, y) column of the voxels as a wall from z = 0 up to ``height`` metres or more
    (whole voxels), coloured as one of its voxels; refused past :data:`MAX_MESH_VOXELS`."""
    layers = max(1, math.ceil(height / resolution - 1e-9))
    columns, first = np.unique(lattice[:, :2], axis=0, return_index=True)
    if len(columns) * layers > MAX_MESH_VOXELS:
        raise InputError(
            source,
            f"walls of {layers} voxels over the {len(columns)} columns a 2D laser hit make"
            f" {len(columns) * layers} voxels, more than the {MAX_MESH_VOXELS} that --geometry"
            " voxels meshes: use --geometry mesh (the same walls as extruded outlines), a"
            " lower --height or a larger --voxel-size",
        )
    z = np.tile(np.arange(layers, dtype=np.int64), len(columns))
    walls = np.column_stack([np.repeat(columns, layers, axis=0), z])
    return walls, None if rgb is None else np.repeat(rgb[first], layers, axis=0)


def _coarser(
    lattice: NDArray[np.int64],
    resolution: float,
    size: float,
    source: Path,
    rgb: NDArray[np.uint8] | None,
) -> tuple[NDArray[np.int64], float, NDArray[np.uint8] | None]:
    """Voxels ``size`` metres a side (``resolution`` times a power of two), occupied where any
    of theirs is: OctoMap's inner nodes at a coarser depth (the key offset is a power of two,
    so they are the same cubes)."""
    factor = size / resolution
    power = round(math.log2(factor)) if factor > 0 else -1
    if power < 0 or abs(factor - 2**power) > 1e-6 * factor:
        choices = ", ".join(f"{resolution * 2**i:g}" for i in range(4))
        raise InputError(
            source,
            f"world.voxel_size {size:g} m is not the octree's {resolution:g} m times a power of"
            f" two ({choices}, ...)",
        )
    if power == 0:
        return lattice, resolution, rgb
    coarse, inverse = np.unique(np.floor_divide(lattice, 2**power), axis=0, return_inverse=True)
    if rgb is None:
        return coarse, resolution * 2**power, None
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(coarse), 3), np.int64)
    np.add.at(sums, inverse, rgb.astype(np.int64))
    count = np.bincount(inverse, minlength=len(coarse))[:, None]
    mean = ((2 * sums + count) // (2 * count)).astype(np.uint8)  # rounded half up
    return coarse, resolution * 2**power, mean
