"""map_server YAML + image -> occupancy, as nav2's map_io.cpp does it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.errors import InputError
from scan2terrain.readers import read_map_yaml
from scan2terrain.readers.mapserver import read_map_metadata
from tests.conftest import write_map
from tests.fixtures import MAPS


def nav2_reference(
    rgb: np.ndarray,
    *,
    alpha: np.ndarray | None,
    mode: str,
    negate: bool,
    occ_t: float,
    free_t: float,
    full: float = 255.0,
) -> np.ndarray:
    """Per-pixel transcription of nav2 loadMapFromFile, with plain loops (slow, obvious)."""
    h, w = rgb.shape[:2]
    out = np.zeros((h, w), dtype=np.int8)
    for y in range(h):
        for x in range(w):
            channels = [float(c) for c in rgb[y, x]]
            if mode == "trinary" and alpha is not None:
                channels.append(float(alpha[y, x]))
            shade = sum(channels) / len(channels) / full
            occ = shade if negate else 1.0 - shade
            if mode == "trinary":
                v = 100 if occ_t < occ else (0 if occ < free_t else -1)
            elif mode == "scale":
                if alpha is not None and alpha[y, x] != full:
                    v = -1
                elif occ_t < occ:
                    v = 100
                elif occ < free_t:
                    v = 0
                else:
                    v = int(np.rint((occ - free_t) / (occ_t - free_t) * 100.0))
            else:
                pct = np.floor(shade * 255 + 0.5)
                v = int(pct) if 0 <= pct <= 100 else -1
            out[h - 1 - y, x] = v
    return out


RNG = np.random.default_rng(7)


@pytest.mark.parametrize("mode", ["trinary", "scale", "raw"])
@pytest.mark.parametrize("negate", [False, True])
@pytest.mark.parametrize("kind", ["L", "RGB", "RGBA", "LA"])
def test_matches_nav2_per_pixel(tmp_path: Path, mode: str, negate: bool, kind: str) -> None:
    h, w = 9, 13
    if kind == "L":
        img = RNG.integers(0, 256, (h, w), dtype=np.uint8)
        rgb, alpha = np.repeat(img[..., None], 3, axis=2), None
    elif kind == "LA":
        img = RNG.integers(0, 256, (h, w, 2), dtype=np.uint8)
        img[..., 1] = np.where(RNG.random((h, w)) < 0.7, 255, img[..., 1])
        rgb, alpha = np.repeat(img[..., :1], 3, axis=2), img[..., 1]
    else:
        c = 4 if kind == "RGBA" else 3
        img = RNG.integers(0, 256, (h, w, c), dtype=np.uint8)
        if c == 4:
            img[..., 3] = np.where(RNG.random((h, w)) < 0.7, 255, img[..., 3])
        rgb, alpha = img[..., :3], (img[..., 3] if c == 4 else None)
    yaml_path = write_map(tmp_path, img, extra=f"mode: {mode}\n", free=0.25)
    text = yaml_path.read_text().replace("negate: 0", f"negate: {int(negate)}")
    yaml_path.write_text(text)
    _, grid = read_map_yaml(yaml_path)
    np.testing.assert_array_equal(
        grid.data,
        nav2_reference(rgb, alpha=alpha, mode=mode, negate=negate, occ_t=0.65, free_t=0.25),
    )


def test_sixteen_bit_png(tmp_path: Path) -> None:
    vals = np.array([[0, 65535], [30000, 60000]], dtype=np.uint16)
    folder = tmp_path / "m"
    folder.mkdir()
    Image.fromarray(vals).save(folder / "m.png")
    (folder / "m.yaml").write_text(
        "image: m.png\nresolution: 0.5\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    _, grid = read_map_yaml(folder / "m.yaml")
    # occ = 1 - v/65535: 1.0 -> 100, 0 -> 0, 0.542 -> unknown, 0.0845 -> 0; rows flipped.
    np.testing.assert_array_equal(grid.data, [[-1, 0], [100, 0]])


def test_jpeg_and_relative_image_path(tmp_path: Path) -> None:
    img = np.full((8, 8), 254, dtype=np.uint8)
    img[:, :2] = 0
    (tmp_path / "images").mkdir()
    Image.fromarray(img).save(tmp_path / "images/m.jpg", quality=95)
    y = tmp_path / "maps/m.yaml"
    y.parent.mkdir()
    y.write_text(
        "image: ../images/m.jpg\nresolution: 0.05\norigin: [1, 2, 0.5]\nnegate: false\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    meta, grid = read_map_yaml(y)
    assert meta.image == (tmp_path / "images/m.jpg").resolve()
    assert (meta.origin.x, meta.origin.y, meta.origin.yaw) == (1.0, 2.0, 0.5)
    assert (grid.data[:, :2] == 100).all() and (grid.data[:, 3:] == 0).all()


def test_real_maps_have_the_documented_classes(real_map: Path) -> None:
    """Class fractions as measured by the fixture set's own README (independent tooling)."""
    expected = {  # occupied, free, unknown fractions under each map's own YAML
        "willow": (0.012, 0.499, 0.489),
        "tb3": (0.005, 0.054, 0.941),
        "levine": (0.002, 0.998, 0.000),
        "warehouse": (0.018, 0.845, 0.137),
    }
    key = next(k for k, v in MAPS.items() if v == real_map)
    meta, grid = read_map_yaml(real_map)
    n = grid.data.size
    got = tuple(round(float((grid.data == v).sum()) / n, 3) for v in (100, 0, -1))
    assert got == pytest.approx(expected[key], abs=0.002)
    with Image.open(meta.image) as img:
        assert grid.shape == (img.height, img.width)


def test_warehouse_reads_non_default_fields() -> None:
    meta = read_map_metadata(MAPS["warehouse"])
    assert meta.mode == "trinary" and meta.free_thresh == 0.1 and meta.resolution == 0.03
    assert (meta.origin.x, meta.origin.y) == (-15.1, -25.0)


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (
            "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\nfree_thresh: 0.2\n",
            "missing required key 'occupied_thresh'",
        ),
        (
            "image: m.png\nresolution: 0\norigin: [0, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'resolution' must be > 0",
        ),
        (
            "image: m.png\nresolution: -0.05\norigin: [0, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'resolution' must be > 0",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 0.2\nfree_thresh: 0.65\n",
            "thresholds out of order",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 1.5\nfree_thresh: 0.2\n",
            "thresholds out of order",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [0, zero, 0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'origin' must hold numbers",
        ),
        # nav2's loadMapYaml: "value of the 'origin' tag should have 3 elements"; ROS1's
        # map_server reads origin[2] and fails without it.
        (
            "image: m.png\nresolution: 0.1\norigin: [1.5, -2]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            r"'origin' must be \[x, y, yaw\] \(3 numbers, as nav2's map_server requires\), not 2",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [1.5, -2, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            r"'origin' must be \[x, y, yaw\] .*, not 4",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: 3\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'origin' must be a list",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 2\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'negate' must be",
        ),
        (
            "image: m.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\nmode: fancy\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "'mode' must be one of",
        ),
        ("image: m.png\nresolution: [0.1\n", "malformed YAML at line"),
        ("just a string\n", "expected a map_server YAML mapping"),
        (
            "image: nothere.png\nresolution: 0.1\norigin: [0, 0, 0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.2\n",
            "image file not found",
        ),
    ],
)
def test_bad_yaml(tmp_path: Path, body: str, message: str) -> None:
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "m.png")
    (tmp_path / "m.yaml").write_text(body)
    with pytest.raises(InputError, match=message) as info:
        read_map_yaml(tmp_path / "m.yaml")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("yaw", ["1e300", "-1e300", "2e6"])
def test_an_origin_yaw_that_is_no_angle_is_refused(tmp_path: Path, yaw: str) -> None:
    """The mutation run found 1e300: the world was written with that yaw in its SDF, which
    Gazebo's parser and our reader refuse (beyond 1e7), so the refusal named our own file."""
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(tmp_path / "m.png")
    (tmp_path / "m.yaml").write_text(
        f"image: m.png\nresolution: 0.1\norigin: [0, 0, {yaw}]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.2\n"
    )
    with pytest.raises(InputError, match=r"m\.yaml: origin yaw .* rad is no angle"):
        read_map_yaml(tmp_path / "m.yaml")


def test_missing_yaml(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="map YAML file not found"):
        read_map_yaml(tmp_path / "none.yaml")


def test_not_an_image(tmp_path: Path) -> None:
    (tmp_path / "m.png").write_text("this is not a PNG")
    y = write_map(tmp_path / "x", np.zeros((2, 2), np.uint8))
    y.write_text(y.read_text().replace("image: m.png", f"image: {tmp_path / 'm.png'}"))
    with pytest.raises(InputError, match="not an image file"):
        read_map_yaml(y)


def test_truncated_png(tmp_path: Path) -> None:
    y = write_map(tmp_path, RNG.integers(0, 256, (200, 200), dtype=np.uint8))
    data = (tmp_path / "m.png").read_bytes()
    (tmp_path / "m.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"m\.png: cannot decode image"):
        read_map_yaml(y)


def test_pixel_limit(tmp_path: Path) -> None:
    y = write_map(tmp_path, np.zeros((100, 100), np.uint8))
    with pytest.raises(InputError, match="over the limit of 5000"):
        read_map_yaml(y, max_pixels=5000)
