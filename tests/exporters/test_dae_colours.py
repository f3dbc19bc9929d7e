"""Coloured COLLADA (issue 15): one ``<triangles>`` element and material per colour, read back by
pycollada, trimesh and gz-common 4's own loader (tests/gazebo/heightmap_probe.cpp)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import trimesh

from scan2terrain.exporters.meshfile import dae_bytes, quantise_colours, stl_bytes
from scan2terrain.geometry.mesh import Mesh
from tests.gazebo_harness import probe_shapes

RED, BLUE, OLIVE = (255, 0, 0), (0, 0, 255), (128, 128, 0)


def two_cubes() -> Mesh:
    """Two unit cubes side by side (12 faces each), x in [0, 1] and [2, 3]."""
    a = trimesh.creation.box(extents=(1, 1, 1))
    a.apply_translation((0.5, 0.5, 0.5))
    b = a.copy()
    b.apply_translation((2.0, 0.0, 0.0))
    both = trimesh.util.concatenate([a, b])
    assert isinstance(both, trimesh.Trimesh)
    return Mesh(np.asarray(both.vertices, dtype=np.float64), np.asarray(both.faces, dtype=np.int64))


def cube_colours() -> np.ndarray:
    """The first cube red, the second blue but for its last two faces (olive)."""
    colours = np.array([RED] * 12 + [BLUE] * 10 + [OLIVE] * 2, dtype=np.uint8)
    return colours


def face_keys(triangles: np.ndarray) -> set[tuple[float, ...]]:
    """Faces (T, 3, 3) as sets of rounded corners, whatever their vertex order."""
    return {tuple(sorted(map(tuple, np.round(t, 9).tolist()))) for t in triangles}  # type: ignore[arg-type]


def test_without_colours_nothing_changes() -> None:
    mesh = two_cubes()
    assert dae_bytes(mesh, "walls") == dae_bytes(mesh, "walls", face_colours=None)
    assert b"rgb-" not in dae_bytes(mesh, "walls")


def test_one_material_per_colour_read_back_by_pycollada(tmp_path: Path) -> None:
    import collada  # type: ignore[import-untyped]

    mesh, colours = two_cubes(), cube_colours()
    data = dae_bytes(mesh, "voxels 0", face_colours=colours)
    assert data == dae_bytes(mesh, "voxels 0", face_colours=colours)  # deterministic
    path = tmp_path / "c.dae"
    path.write_bytes(data)
    doc = collada.Collada(str(path))
    (geometry,) = doc.geometries
    assert len(geometry.primitives) == 3
    # in the palette's (r, g, b) order: blue, olive, red
    assert [p.material for p in geometry.primitives] == ["rgb-0000FF", "rgb-808000", "rgb-FF0000"]
    effects = {m.id: m.effect for m in doc.materials}
    (node,) = doc.scenes[0].nodes
    bound = {b.symbol: b.target.id for b in node.children[0].materials}
    for prim, colour, count in zip(
        geometry.primitives, (BLUE, OLIVE, RED), (10, 2, 12), strict=True
    ):
        assert len(prim) == count
        effect = effects[bound[prim.material]]
        want = (*(c / 255 for c in colour), 1.0)
        assert tuple(effect.diffuse) == pytest.approx(want)
        assert tuple(effect.ambient) == pytest.approx(want)
        # each face sits in its colour's element
        faces = np.flatnonzero((colours == colour).all(axis=1))
        assert face_keys(prim.vertex[prim.vertex_index]) == face_keys(
            mesh.vertices[mesh.faces[faces]]
        )


def test_trimesh_reads_the_colours_per_face(tmp_path: Path) -> None:
    mesh, colours = two_cubes(), cube_colours()
    path = tmp_path / "c.dae"
    path.write_bytes(dae_bytes(mesh, "voxels", face_colours=colours))
    scene = trimesh.load(path, force="scene")
    assert isinstance(scene, trimesh.Scene)
    seen: dict[tuple[int, ...], set[tuple[float, ...]]] = {}
    for geom in scene.geometry.values():
        assert isinstance(geom, trimesh.Trimesh)
        colour = tuple(int(v) for v in np.asarray(geom.visual.material.main_color)[:3])  # type: ignore[union-attr]
        seen[colour] = face_keys(geom.vertices[geom.faces])
    for colour in (RED, BLUE, OLIVE):
        faces = np.flatnonzero((colours == colour).all(axis=1))
        assert seen[colour] == face_keys(mesh.vertices[mesh.faces[faces]])


def test_quantise_colours() -> None:
    exact = np.array([[1, 2, 3], [250, 251, 252], [1, 2, 3]], dtype=np.uint8)
    palette, index = quantise_colours(exact, 2)  # few enough: as they are
    assert palette.tolist() == [[1, 2, 3], [250, 251, 252]] and index.tolist() == [0, 1, 0]
    # three colours, two allowed. 5 bits per channel: 4 -> level 0 -> 0, 9 -> 1 -> 8,
    # 250 -> 30 -> 247: still three, so the two most common (black, twice; then the smaller of
    # the single ones) and each row the nearest of them
    many = np.array([[0, 0, 0], [4, 0, 0], [255, 255, 250], [9, 0, 0]], dtype=np.uint8)
    palette, index = quantise_colours(many, 2)
    assert palette.tolist() == [[0, 0, 0], [8, 0, 0]] and index.tolist() == [0, 0, 1, 1]
    palette, index = quantise_colours(many, 3)
    assert palette.tolist() == [[0, 0, 0], [8, 0, 0], [255, 255, 247]]
    assert index.tolist() == [0, 0, 2, 1]
    palette, index = quantise_colours(many, 1)
    assert palette.tolist() == [[0, 0, 0]] and index.tolist() == [0, 0, 0, 0]
    rng = np.random.default_rng(3)
    noisy = rng.integers(0, 256, size=(5000, 3), dtype=np.uint8)
    palette, index = quantise_colours(noisy, 256)
    assert len(palette) == 256 and index.shape == (5000,)
    assert (np.diff(palette.astype(np.int64) @ [65536, 256, 1]) > 0).all()  # sorted, unique
    # every row close to its stand-in (5-bit rounding, then the nearest kept colour)
    assert np.abs(palette[index].astype(int) - noisy).max() < 128
    again = quantise_colours(noisy, 256)
    np.testing.assert_array_equal(again[0], palette)
    np.testing.assert_array_equal(again[1], index)


def test_five_bit_levels_keep_black_and_white() -> None:
    grey = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
    palette, index = quantise_colours(grey, 40)
    assert len(palette) == 32 and palette[0].tolist() == [0, 0, 0]
    assert palette[-1].tolist() == [255, 255, 255]
    assert np.abs(palette[index].astype(int) - grey).max() <= 4  # half a 5-bit step


def test_many_colours_become_at_most_max_materials() -> None:
    mesh = two_cubes()
    rng = np.random.default_rng(4)
    colours = rng.integers(0, 256, size=(24, 3), dtype=np.uint8)
    data = dae_bytes(mesh, "v", face_colours=colours, max_materials=5)
    assert data.count(b"<triangles ") == 5 and data.count(b"<material ") == 5
    assert sum(int(c) for c in _counts(data)) == 24


def _counts(data: bytes) -> list[str]:
    """The ``count`` of every ``<triangles>`` element."""
    return re.findall(r'<triangles material="[^"]+" count="(\d+)"', data.decode())


def test_bad_face_colours() -> None:
    mesh = two_cubes()
    with pytest.raises(ValueError, match=r"face_colours must be \(24, 3\) uint8"):
        dae_bytes(mesh, "v", face_colours=np.zeros((23, 3), dtype=np.uint8))
    with pytest.raises(ValueError, match="face_colours must be"):
        dae_bytes(mesh, "v", face_colours=np.zeros((24, 3)))  # type: ignore[arg-type]


def test_gz_common_loads_one_coloured_submesh_per_colour(tmp_path: Path) -> None:
    """gz-common 4's MeshManager (what gz-sim renders from): one submesh per colour, each with
    its material's diffuse and ambient colour and its faces."""
    mesh, colours = two_cubes(), cube_colours()
    (tmp_path / "voxels.dae").write_bytes(dae_bytes(mesh, "voxels", face_colours=colours))
    (tmp_path / "voxels.stl").write_bytes(stl_bytes(mesh))
    (tmp_path / "model.sdf").write_text(
        '<?xml version="1.0"?><sdf version="1.9"><model name="m"><static>true</static>'
        '<link name="l"><collision name="c"><geometry><mesh><uri>voxels.stl</uri></mesh>'
        '</geometry></collision><visual name="v"><geometry><mesh><uri>voxels.dae</uri></mesh>'
        "</geometry></visual></link></model></sdf>"
    )
    _, shapes = probe_shapes(tmp_path / "model.sdf", [], tmp_path / "out")
    collision, visual = shapes
    assert visual.kind == "visual" and visual.mesh_loaded and visual.submeshes is not None
    assert [s.triangles for s in visual.submeshes] == [10, 2, 12]
    for sub, colour in zip(visual.submeshes, (BLUE, OLIVE, RED), strict=True):
        want = (*(c / 255 for c in colour), 1.0)
        assert sub.diffuse == pytest.approx(want, abs=1e-6)  # float32 in gz-common
        assert sub.ambient == pytest.approx(want, abs=1e-6)
    # the triangles, submesh after submesh, are the faces of each colour
    assert visual.triangles is not None
    bounds = np.cumsum([0] + [s.triangles for s in visual.submeshes])
    for k, colour in enumerate((BLUE, OLIVE, RED)):
        faces = np.flatnonzero((colours == colour).all(axis=1))
        got = visual.triangles[bounds[k] : bounds[k + 1]]
        assert face_keys(got) == face_keys(mesh.vertices[mesh.faces[faces]])
    # the STL collision: one submesh, gz-common's default material (STL holds no colour)
    assert collision.submeshes is not None and len(collision.submeshes) == 1
    assert collision.submeshes[0].triangles == 24


def test_gz_common_reads_the_grey_walls_material(tmp_path: Path) -> None:
    (tmp_path / "walls.dae").write_bytes(dae_bytes(two_cubes(), "walls"))
    (tmp_path / "model.sdf").write_text(
        '<?xml version="1.0"?><sdf version="1.9"><model name="m"><static>true</static>'
        '<link name="l"><visual name="v"><geometry><mesh><uri>walls.dae</uri></mesh>'
        "</geometry></visual></link></model></sdf>"
    )
    _, (visual,) = probe_shapes(tmp_path / "model.sdf", [], tmp_path / "out")
    assert visual.submeshes is not None and len(visual.submeshes) == 1
    assert visual.submeshes[0].triangles == 24
    assert visual.submeshes[0].diffuse == pytest.approx((0.7, 0.7, 0.7, 1.0), abs=1e-6)
    assert visual.submeshes[0].ambient == pytest.approx((0.4, 0.4, 0.4, 1.0), abs=1e-6)
