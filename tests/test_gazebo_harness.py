"""Self-tests of tests/gazebo_harness.py (independent of the scan2terrain package).

Tiny worlds and images are written by hand into tmp_path; SDFormat 12 and gz-common 4
(Debian packages) do the parsing and the height-field reconstruction.
"""

from __future__ import annotations

import math
import shutil
import signal
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.gazebo_harness import (
    INSTALL_HINT,
    HeightmapProbe,
    SdfParseError,
    ShapeProbe,
    probe_binary,
    probe_shapes,
    probe_world,
    terrain_height,
    vertex_world_xy,
)

# 5x5 test image: distinct values at asymmetric places so a flip or transpose shows.
PIXELS = np.zeros((5, 5), dtype=np.uint8)
PIXELS[0, 0] = 255  # top-left
PIXELS[1, 3] = 128
PIXELS[4, 1] = 64
PIXELS[2, 2] = 200  # centre
PIXELS[3, 4] = 32


def _world_19(uri: str, *, model_pose: str = "0 0 0 0 0 0", col_pose: str = "1 2 0 0 0 0") -> str:
    """gz-sim style: model at the origin, collision <pose> = offset, visual <pos> = offset."""
    return f"""<?xml version="1.0"?>
<sdf version="1.9">
  <world name="default">
    <model name="terrain_test">
      <static>true</static>
      <pose>{model_pose}</pose>
      <link name="link">
        <collision name="collision">
          <pose>{col_pose}</pose>
          <geometry>
            <heightmap>
              <uri>{uri}</uri>
              <size>4 4 10</size>
              <sampling>1</sampling>
            </heightmap>
          </geometry>
        </collision>
        <visual name="visual">
          <geometry>
            <heightmap>
              <uri>{uri}</uri>
              <size>4 4 10</size>
              <pos>1 2 0</pos>
              <sampling>1</sampling>
            </heightmap>
          </geometry>
        </visual>
      </link>
    </model>
  </world>
</sdf>
"""


def _write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _collision(probes: list[HeightmapProbe]) -> HeightmapProbe:
    found = [p for p in probes if p.kind == "collision"]
    assert len(found) == 1
    return found[0]


def _visual(probes: list[HeightmapProbe]) -> HeightmapProbe:
    found = [p for p in probes if p.kind == "visual"]
    assert len(found) == 1
    return found[0]


def _probe(tmp_path: Path, pixels: np.ndarray, name: str, **kw: str) -> HeightmapProbe:
    Image.fromarray(pixels).save(tmp_path / f"{name}.png")
    world = _write(tmp_path / f"{name}.sdf", _world_19(f"{name}.png", **kw))
    version, probes = probe_world(world, [], tmp_path / "out")
    assert version == "1.9"
    return _collision(probes)


def _check_gz_heights(probe: HeightmapProbe, pixels: np.ndarray) -> None:
    """Heights = v / v_max * size.z at every vertex, and terrain_height agrees."""
    expected = pixels.astype(np.float64) / float(pixels.max()) * 10.0
    assert probe.heights is not None
    assert probe.heights.shape == (5, 5)
    np.testing.assert_allclose(probe.heights, expected, rtol=0, atol=1e-5)
    rows, cols = np.mgrid[0:5, 0:5]
    # gz: spacing size/vertSize = 0.8 m, centred on the collision pose (1, 2).
    wx = 1.0 + (cols - 2) * 0.8
    wy = 2.0 + (2 - rows) * 0.8
    got = terrain_height(probe, wx, wy, "gz")
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-5)
    vx, vy = vertex_world_xy(probe, rows, cols, "gz")
    np.testing.assert_allclose(vx, wx, atol=1e-12)
    np.testing.assert_allclose(vy, wy, atol=1e-12)


# --------------------------------------------------------------------------- 8-bit


def test_8bit_world_parses_strictly_and_matches_fillheightmap(tmp_path: Path) -> None:
    probe = _probe(tmp_path, PIXELS, "h8")
    assert probe.model == "terrain_test"
    assert probe.link == "link"
    assert probe.name == "collision"
    assert probe.sdf_original_version == "1.9"
    assert probe.vert_size == 5
    assert probe.image_width == probe.image_height == 5
    assert probe.image_bpp == 8
    assert probe.sampling == 1
    assert probe.size == (4.0, 4.0, 10.0)
    assert probe.pos == (0.0, 0.0, 0.0)
    np.testing.assert_allclose(probe.pose, (1, 2, 0, 0, 0, 0), atol=1e-12)
    assert probe.path == (tmp_path / "h8.png").resolve()
    assert probe.max_elevation_fallback is False
    assert probe.max_elevation == pytest.approx(1.0)
    assert (probe.textures, probe.blends) == (0, 0)
    _check_gz_heights(probe, PIXELS)

    # The top-left pixel is at -x, +y of the field (image seen from above, north up).
    assert terrain_height(probe, 1 - 1.6, 2 + 1.6, "gz") == pytest.approx(10.0, abs=1e-5)
    # Half-way between two vertices: linear.
    mid = terrain_height(probe, 1.0, 2.0 + 0.4, "gz")  # between (1,2)=0 and (2,2)=200
    assert mid == pytest.approx(0.5 * 200 / 255 * 10, abs=1e-5)
    # Outside the field -> NaN; field spans (V-1)*0.8 = 3.2 m, not the full 4 m.
    assert math.isnan(terrain_height(probe, 1 + 1.7, 2.0, "gz"))
    assert not math.isnan(terrain_height(probe, 1 + 1.6, 2.0, "gz"))


def test_visual_reports_pos_and_world_pose(tmp_path: Path) -> None:
    Image.fromarray(PIXELS).save(tmp_path / "h8.png")
    world = _write(tmp_path / "w.sdf", _world_19("h8.png"))
    _, probes = probe_world(world, [], tmp_path / "out")
    visual = _visual(probes)
    assert visual.pos == (1.0, 2.0, 0.0)
    np.testing.assert_allclose(visual.pose, (0, 0, 0, 0, 0, 0), atol=1e-12)
    assert visual.heights is None
    assert visual.vert_size is None
    with pytest.raises(ValueError, match="not a collision"):
        terrain_height(visual, 0.0, 0.0, "gz")


def test_brightest_pixel_reaches_full_size_z(tmp_path: Path) -> None:
    dim = np.zeros((5, 5), dtype=np.uint8)
    dim[0, 0] = 128
    dim[3, 1] = 64
    probe = _probe(tmp_path, dim, "dim")
    assert probe.heights is not None
    assert probe.heights.max() == pytest.approx(10.0, abs=1e-5)
    assert probe.heights[3, 1] == pytest.approx(5.0, abs=1e-5)
    _check_gz_heights(probe, dim)


def test_pose_is_resolved_to_the_world_frame(tmp_path: Path) -> None:
    yaw = math.pi / 2
    probe = _probe(tmp_path, PIXELS, "rot", model_pose=f"10 0 1 0 0 {yaw}")
    # world = model(10, 0, 1, yaw 90) * collision(1, 2, 0) = (10 - 2, 1, 1), yaw 90.
    np.testing.assert_allclose(probe.pose, (8, 1, 1, 0, 0, yaw), atol=1e-9)
    rows, cols = np.mgrid[0:5, 0:5]
    wx, wy = vertex_world_xy(probe, rows, cols, "gz")
    got = terrain_height(probe, wx, wy, "gz")
    np.testing.assert_allclose(got, 1.0 + PIXELS / 255.0 * 10.0, atol=1e-5)
    # Yawed 90 deg: the image's top-left corner (-x, +y locally) is at world (-y, -x).
    assert terrain_height(probe, 8 - 1.6, 1 - 1.6, "gz") == pytest.approx(11.0, abs=1e-5)


# --------------------------------------------------------------------------- 16-bit


def test_16bit_image_gives_the_same_heights(tmp_path: Path) -> None:
    wide = PIXELS.astype(np.uint16) * 257  # 255 -> 65535: same ratios
    image = Image.fromarray(wide)
    assert image.mode == "I;16"
    probe = _probe(tmp_path, wide, "h16")
    assert probe.image_bpp == 16
    # gz-common 4.5.1's Image::MaxColor fails on 16-bit images (returns 0); the probe
    # then scales to the brightest sample itself and says so.
    assert probe.max_elevation_fallback == (probe.max_elevation_reported == 0.0)
    if probe.max_elevation_fallback:
        assert probe.max_elevation == pytest.approx(1.0)
    _check_gz_heights(probe, PIXELS)


def test_16bit_fallback_scales_to_the_brightest_sample(tmp_path: Path) -> None:
    wide = np.zeros((5, 5), dtype=np.uint16)
    wide[0, 0] = 30000
    wide[2, 3] = 60000
    wide[4, 4] = 15000
    probe = _probe(tmp_path, wide, "h16b")
    assert probe.max_elevation_fallback == (probe.max_elevation_reported == 0.0)
    assert probe.max_elevation == pytest.approx(60000 / 65535)
    _check_gz_heights(probe, wide)


def test_large_16bit_image_skips_the_failing_maxelevation_call(tmp_path: Path) -> None:
    ramp = (np.arange(257 * 257, dtype=np.uint32).reshape(257, 257) % 50000).astype(np.uint16)
    probe = _probe(tmp_path, ramp, "big16")
    assert probe.vert_size == 257
    assert probe.max_elevation_called is False
    assert probe.max_elevation_reported is None
    assert probe.max_elevation_fallback is True
    assert probe.heights is not None
    np.testing.assert_allclose(probe.heights, ramp / ramp.max() * 10.0, atol=1e-4)


def test_gz_common_max_color_quirks_are_reproduced(tmp_path: Path) -> None:
    """What Gazebo itself does, warts included (gz-common 4.5.1 + ignition-math 6).

    Image::MaxColor builds math::Color(v, v, v) from 0..255 bytes, and Color's clamp
    only divides values > 1 by 255: a pixel of value 1 becomes 1.0 and counts as the
    brightest, so an image whose real maximum is 128 no longer reaches size.z.
    """
    pixels = np.zeros((5, 5), dtype=np.uint8)
    pixels[0, 0] = 128
    pixels[4, 4] = 1
    probe = _probe(tmp_path, pixels, "one")
    assert probe.max_elevation == pytest.approx(1.0)
    assert probe.heights is not None
    assert probe.heights.max() == pytest.approx(128 / 255 * 10.0, abs=1e-5)


# --------------------------------------------------------------------------- classic


def _classic_world(model_pose: str = "0 0 0 0 0 0") -> str:
    return f"""<?xml version="1.0"?>
<sdf version="1.6">
  <world name="default">
    <include>
      <uri>model://classic_terrain</uri>
      <pose>{model_pose}</pose>
    </include>
  </world>
</sdf>
"""


CLASSIC_MODEL = """<?xml version="1.0"?>
<sdf version="1.6">
  <model name="classic_terrain">
    <static>true</static>
    <link name="link">
      <collision name="collision">
        <geometry>
          <heightmap>
            <uri>model://classic_terrain/materials/textures/terrain.png</uri>
            <size>8 8 5</size>
            <pos>0 0 0.5</pos>
            <sampling>2</sampling>
          </heightmap>
        </geometry>
      </collision>
      <visual name="visual">
        <geometry>
          <heightmap>
            <uri>model://classic_terrain/materials/textures/terrain.png</uri>
            <size>8 8 5</size>
            <pos>0 0 0.5</pos>
            <sampling>2</sampling>
          </heightmap>
        </geometry>
      </visual>
    </link>
  </model>
</sdf>
"""

CLASSIC_CONFIG = """<?xml version="1.0"?>
<model>
  <name>classic_terrain</name>
  <version>1.0</version>
  <sdf version="1.6">model.sdf</sdf>
  <description>harness self-test</description>
</model>
"""


def _classic_setup(tmp_path: Path, model_pose: str = "0 0 0 0 0 0") -> tuple[Path, Path]:
    models = tmp_path / "models"
    model = models / "classic_terrain"
    _write(model / "model.config", CLASSIC_CONFIG)
    _write(model / "model.sdf", CLASSIC_MODEL)
    (model / "materials" / "textures").mkdir(parents=True)
    Image.fromarray(PIXELS).save(model / "materials" / "textures" / "terrain.png")
    world = _write(tmp_path / "classic.sdf", _classic_world(model_pose))
    return world, models


def test_sdf16_include_model_uri_and_classic_heights(tmp_path: Path) -> None:
    world, models = _classic_setup(tmp_path, model_pose="30 -20 4 0 0 0")
    version, probes = probe_world(world, [models], tmp_path / "out")
    assert version == "1.9"  # SDFormat 12 converts everything to 1.9
    probe = _collision(probes)
    assert probe.sdf_original_version == "1.6"
    assert probe.model == "classic_terrain"
    assert probe.uri == "model://classic_terrain/materials/textures/terrain.png"
    assert probe.path == (models / "classic_terrain/materials/textures/terrain.png").resolve()
    assert probe.sampling == 2
    assert probe.vert_size == 9  # 5*2 - 2 + 1
    # The included model's pose reaches the collision's world pose ...
    np.testing.assert_allclose(probe.pose, (30, -20, 4, 0, 0, 0), atol=1e-12)
    assert probe.heights is not None
    expected_px = PIXELS / 255.0 * 5.0
    # sampling 2: even vertices are pixels, odd ones interpolate.
    np.testing.assert_allclose(probe.heights[::2, ::2], expected_px, atol=1e-5)
    np.testing.assert_allclose(
        probe.heights[1, 0], (expected_px[0, 0] + expected_px[1, 0]) / 2, atol=1e-5
    )

    # ... but Classic (ODE) keeps the field at the world origin, spacing size/(V-1)
    # = 1 m, and adds only <pos>.z.
    rows, cols = np.mgrid[0:9, 0:9]
    wx = (cols - 4) * 1.0
    wy = (4 - rows) * 1.0
    got = terrain_height(probe, wx, wy, "classic")
    np.testing.assert_allclose(got, 0.5 + probe.heights, atol=1e-5)
    vx, vy = vertex_world_xy(probe, rows, cols, "classic")
    np.testing.assert_allclose(vx, wx, atol=1e-12)
    np.testing.assert_allclose(vy, wy, atol=1e-12)
    assert terrain_height(probe, -4.0, 4.0, "classic") == pytest.approx(5.5, abs=1e-5)
    assert math.isnan(terrain_height(probe, 4.01, 0.0, "classic"))

    # gz-sim would instead follow the pose, with spacing size/vertSize.
    assert terrain_height(probe, 30 - 4 * 8 / 9, -20 + 4 * 8 / 9, "gz") == pytest.approx(
        4 + 5.0, abs=1e-5
    )


def test_classic_rejects_what_it_cannot_reproduce(tmp_path: Path) -> None:
    probe = _probe(tmp_path, PIXELS, "s1")  # sampling 1
    with pytest.raises(ValueError, match="sampling"):
        terrain_height(probe, 0.0, 0.0, "classic")
    with pytest.raises(ValueError, match="unknown simulator"):
        terrain_height(probe, 0.0, 0.0, "bullet")  # type: ignore[call-overload]


# --------------------------------------------------------------------------- strict


@pytest.mark.parametrize(
    ("old", "new"),
    [
        ("<heightmap>", "<heightmapp>"),
        ("<size>4 4 10</size>", "<sizee>4 4 10</sizee>"),
        ("<sampling>1</sampling>", "<samplingg>1</samplingg>"),
        ("<static>true</static>", "<static>true</static><statik>true</statik>"),
        ('<collision name="collision">', '<collision name="collision" nmae="x">'),
        ("<size>4 4 10</size>", "<size>4 4 ten</size>"),
    ],
    ids=["heightmapp", "sizee", "samplingg", "statik", "bad-attribute", "bad-value"],
)
def test_misspelled_elements_are_parse_errors(tmp_path: Path, old: str, new: str) -> None:
    Image.fromarray(PIXELS).save(tmp_path / "h8.png")
    text = _world_19("h8.png")
    assert old in text
    text = text.replace(old, new, 1)
    if old == "<heightmap>":
        text = text.replace("</heightmap>", "</heightmapp>", 1)
    world = _write(tmp_path / "bad.sdf", text)
    with pytest.raises(SdfParseError) as err:
        probe_world(world, [], tmp_path / "out")
    assert "Error" in str(err.value)


def test_misspelling_inside_an_included_model_is_an_error(tmp_path: Path) -> None:
    world, models = _classic_setup(tmp_path)
    model_sdf = models / "classic_terrain" / "model.sdf"
    model_sdf.write_text(CLASSIC_MODEL.replace("<pos>", "<poss>").replace("</pos>", "</poss>"))
    with pytest.raises(SdfParseError, match="poss"):
        probe_world(world, [models], tmp_path / "out")


def test_unresolvable_include_is_an_error(tmp_path: Path) -> None:
    world, _ = _classic_setup(tmp_path)
    with pytest.raises(SdfParseError):
        probe_world(world, [tmp_path / "nowhere"], tmp_path / "out")


# --------------------------------------------------------------------------- polylines

# An L of four 0.05 m cells from Willow Garage's map, as decimal map coordinates; the same L on
# a binary grid (0.25 m cells at the origin: every sum of coordinates exact).
L_DECIMAL = [(49.5, 3.55), (49.65, 3.55), (49.65, 3.6), (49.55, 3.6), (49.55, 3.65), (49.5, 3.65)]
L_BINARY = [(0.0, 0.0), (0.75, 0.0), (0.75, 0.25), (0.25, 0.25), (0.25, 0.5), (0.0, 0.5)]


def _polyline_model(tmp_path: Path, shapes: dict[str, list[list[tuple[float, float]]]]) -> Path:
    """A model file with one collision per entry: its rings as <polyline> elements, 2 m high."""
    parts = []
    for name, rings in shapes.items():
        lines = "".join(
            "<polyline>"
            + "".join(f"<point>{x!r} {y!r}</point>" for x, y in ring)
            + "<height>2</height></polyline>"
            for ring in rings
        )
        parts.append(f'<collision name="{name}"><geometry>{lines}</geometry></collision>')
    return _write(
        tmp_path / "polylines.sdf",
        '<?xml version="1.0"?><sdf version="1.9"><model name="m"><static>true</static>'
        f'<link name="l">{"".join(parts)}</link></model></sdf>',
    )


def _cap_area(shape: ShapeProbe, z: float) -> float:
    assert shape.triangles is not None
    cap = shape.triangles[np.all(shape.triangles[..., 2] == z, axis=1)][..., :2]
    a, b = cap[:, 1] - cap[:, 0], cap[:, 2] - cap[:, 0]
    return float(np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]).sum() / 2)


def test_polylines_are_extruded_as_gz_sim_builds_them(tmp_path: Path) -> None:
    """gz-common's CreateExtrudedPolyline: caps and walls from z = 0 to the height, holes open."""
    square = [(0.0, 0.0), (2.0, 0.0), (2.0, 2.0), (0.0, 2.0)]
    hole = [(0.5, 0.5), (0.5, 1.5), (1.5, 1.5), (1.5, 0.5)]
    world = _polyline_model(tmp_path, {"ring": [square, hole], "l": [L_BINARY]})
    _, shapes = probe_shapes(world, [], tmp_path / "out")
    ring, ell = shapes
    for s in shapes:
        assert s.type == "polyline" and s.extrusion == "ok" and s.extrusion_signal is None
        assert s.mesh_min is not None and s.mesh_min[2] == 0.0
        assert s.mesh_max is not None and s.mesh_max[2] == 2.0
    assert _cap_area(ring, 0.0) == _cap_area(ring, 2.0) == pytest.approx(3.0)
    assert _cap_area(ell, 0.0) == _cap_area(ell, 2.0) == pytest.approx(0.25)
    assert [pts.tolist() for _, pts in ring.polylines] == [
        [list(p) for p in square],
        [list(p) for p in hole],
    ]


def test_gz_common_hole_test_drops_a_triangle_of_a_decimal_outline(tmp_path: Path) -> None:
    """gz-common 4's even-odd test counts both edges at a vertex its centroid ray meets when
    (y1 + y2) - min(y1, y2) rounds above max(y1, y2): the decimal L fails to extrude ("Unable
    to extrude mesh. Triangulation failed"); on a binary grid the same shape builds."""
    world = _polyline_model(tmp_path, {"decimal": [L_DECIMAL], "binary": [L_BINARY]})
    _, (decimal, binary) = probe_shapes(world, [], tmp_path / "out")
    assert decimal.extrusion == "failed" and decimal.triangles is None
    assert binary.extrusion == "ok"


def test_a_crash_in_the_extrusion_is_reported_for_its_geometry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """GTS can kill the process (stack overflow, assertion): the probe extrudes in a forked
    child, reports the crash for that geometry, and extrudes the others."""
    world = _polyline_model(tmp_path, {n: [L_BINARY] for n in ("a", "b", "c")})
    monkeypatch.setenv("HEIGHTMAP_PROBE_FAULT", "crash:b")
    _, shapes = probe_shapes(world, [], tmp_path / "out")
    assert [(s.name, s.extrusion, s.extrusion_signal) for s in shapes] == [
        ("a", "ok", None),
        ("b", "crashed", signal.SIGSEGV),
        ("c", "ok", None),
    ]
    assert shapes[2].triangles is not None and _cap_area(shapes[2], 2.0) == pytest.approx(0.25)


def test_a_hung_extrusion_times_out(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    world = _polyline_model(tmp_path, {n: [L_BINARY] for n in ("a", "b")})
    monkeypatch.setenv("HEIGHTMAP_PROBE_FAULT", "hang:a")
    monkeypatch.setenv("HEIGHTMAP_PROBE_EXTRUDE_TIMEOUT", "1")
    _, shapes = probe_shapes(world, [], tmp_path / "out")
    assert [(s.extrusion, s.extrusion_signal) for s in shapes] == [
        ("timeout", signal.SIGALRM),
        ("ok", None),
    ]


# --------------------------------------------------------------------------- build


def test_probe_binary_is_cached(tmp_path: Path) -> None:
    first = probe_binary()
    assert first.is_file()
    assert probe_binary() == first
    assert ".build" in first.parts


def test_missing_toolchain_raises_with_install_hint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from tests import gazebo_harness

    monkeypatch.setattr(gazebo_harness, "BUILD_ROOT", tmp_path / "build")
    monkeypatch.setattr(shutil, "which", lambda _name: None)  # the harness's shutil
    with pytest.raises(RuntimeError) as err:
        gazebo_harness.probe_binary()
    assert INSTALL_HINT in str(err.value)
