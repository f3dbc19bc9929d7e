"""The mutation fuzz's oracle (tests/output_sanity.py) passes real outputs and flags each kind of
nonsense a damaged input could put in them (issue 28)."""

from __future__ import annotations

import re
import shutil
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.cli import main
from tests.conftest import write_map
from tests.fixtures import AUTZEN_CSV, MOON
from tests.output_sanity import output_problems


@pytest.fixture(scope="module")
def outputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """One output of each kind: a wall mesh world (OBJ, STL, DAE, map YAML), a heightmap
    world from an image and from a DEM, a converted cloud as XYZ and as PLY."""
    root = tmp_path_factory.mktemp("outputs")
    pixels = np.full((30, 40), 254, dtype=np.uint8)
    pixels[0, :] = pixels[-1, :] = pixels[:, 0] = pixels[:, -1] = 0
    pixels[10:14, 12:30] = 0
    map_yaml = write_map(root / "map", pixels, name="m.png", origin="[-2.0, -1.5, 0.0]")
    y, x = np.mgrid[0:33, 0:33]
    Image.fromarray(((x * y) % 256).astype(np.uint8)).save(root / "hill.png")
    dem = MOON
    cloud = AUTZEN_CSV
    commands: dict[str, list[str | Path]] = {
        "mesh": ["map2world", map_yaml, "-o", root / "mesh", "--no-preview"],
        "image": ["image2world", root / "hill.png", "-o", root / "image", "--resolution", "0.1"],
        "dem": ["dem2world", dem, "-o", root / "dem", "--no-preview"],
        "xyz": ["convert", cloud, root / "c.xyz"],
        "ply": ["convert", cloud, root / "c.ply"],
    }
    out = {}
    for name, argv in commands.items():
        assert main([str(a) for a in argv]) == 0, argv
        out[name] = Path(argv[2] if name in ("xyz", "ply") else argv[3])
    return out


def test_real_outputs_pass(outputs: dict[str, Path]) -> None:
    for name, path in outputs.items():
        assert output_problems(path) == [], name
    mesh = outputs["mesh"]
    assert list(mesh.rglob("*.obj")) and list(mesh.rglob("*.stl")) and list(mesh.rglob("*.dae"))
    assert list(mesh.rglob("map_*.yaml"))
    assert list(outputs["dem"].rglob("heightmap.png"))


def edit_text(pattern: str, replacement: str, glob: str) -> Callable[[Path], None]:
    """Replace the first match of ``pattern`` in the first file matching ``glob``."""

    def damage(out: Path) -> None:
        path = next(out.rglob(glob))
        text = path.read_text()
        new = re.sub(pattern, replacement, text, count=1)
        assert new != text, (pattern, path)
        path.write_text(new)

    return damage


def heightmap_pixels(change: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], None]:
    def damage(out: Path) -> None:
        path = next(out.rglob("heightmap.png"))
        with Image.open(path) as im:
            pixels = np.asarray(im)
        Image.fromarray(change(pixels)).save(path)

    return damage


def stl_first_value(value: float) -> Callable[[Path], None]:
    def damage(out: Path) -> None:
        path = next(out.rglob("*.stl"))
        raw = bytearray(path.read_bytes())
        struct.pack_into("<f", raw, 84 + 12, value)  # the first triangle's first vertex x
        path.write_bytes(bytes(raw))

    return damage


def ply_first_x(value: float) -> Callable[[Path], None]:
    def damage(out: Path) -> None:
        raw = bytearray(out.read_bytes())
        end = raw.index(b"end_header\n") + len(b"end_header\n")
        assert b"property double x" in raw[:end], raw[:end]
        struct.pack_into("<d", raw, end, value)
        out.write_bytes(bytes(raw))

    return damage


def first_line(line: str) -> Callable[[Path], None]:
    def damage(out: Path) -> None:
        out.write_text(line + "\n" + out.read_text())

    return damage


#: name: (output, damage, a word of the problem reported)
DAMAGES: dict[str, tuple[str, Callable[[Path], None], str]] = {
    "sdf-nan": ("image", edit_text(r"<pose>[^<]*</pose>", "<pose>nan 0 0 0 0 0</pose>", "*.sdf"),
                "non-finite"),
    "sdf-inf-attribute": ("mesh", edit_text(r'<sdf version="[^"]*"', '<sdf version="inf"',
                                            "model.sdf"), "non-finite"),
    "sdf-far": ("dem", edit_text(r"<pose>[^<]*</pose>", "<pose>2e9 0 0 0 0 0</pose>",
                                 "model.sdf"), "beyond"),
    "sdf-deep": ("dem", edit_text(r"<pose>[^<]*</pose>", "<pose>0 0 -3e5 0 0 0</pose>",
                                  "model.sdf"), "z beyond"),
    "size-zero": ("mesh", edit_text(r"<size>[^<]*</size>", "<size>0 1 1</size>", "model.sdf"),
                  "not above 0"),
    "size-tiny": ("dem", edit_text(r"<size>[^<]*</size>", "<size>1e-300 1e-300 1</size>",
                                   "model.sdf"), "outside"),
    "size-huge": ("image", edit_text(r"<size>[^<]*</size>", "<size>3e301 3e301 1</size>",
                                     "model.sdf"), "outside"),
    "sdf-broken": ("mesh", edit_text(r"</sdf>", "</sd", "model.sdf"), "unreadable"),
    "yaml-nan": ("mesh", edit_text(r"pose: \[[-0-9.]+", "pose: [.nan", "spawn.yaml"),
                 "non-finite"),
    "spawn-far": ("dem", edit_text(r"pose: \[[-0-9.]+", "pose: [1.0e+12", "spawn.yaml"),
                  "beyond"),
    "map-resolution": ("mesh", edit_text(r"resolution: \S+", "resolution: 1.0e-300",
                                         "map_*.yaml"), "resolution"),
    "map-origin": ("mesh", edit_text(r"origin: \[[-0-9.]+", "origin: [1.0e+300", "map_*.yaml"),
                   "origin"),
    "obj-inf": ("mesh", edit_text(r"\nv \S+", "\nv inf", "*.obj"), "non-finite"),
    "obj-far": ("mesh", edit_text(r"\nv \S+", "\nv 1e300", "*.obj"), "x, y up to"),
    "obj-face": ("mesh", edit_text(r"\nf \d+", "\nf 999999", "*.obj"), "vertex indices"),
    "stl-nan": ("mesh", stl_first_value(float("nan")), "non-finite"),
    "stl-far": ("mesh", stl_first_value(3e38), "x, y up to"),
    "dae-far": ("mesh", edit_text(r"<float_array([^>]*)>\S+", r"<float_array\1>1e300", "*.dae"),
                "COLLADA"),
    "heightmap-dim": ("image", heightmap_pixels(lambda p: (p // 2).astype(p.dtype)),
                      "not full scale"),
    "heightmap-shape": ("dem", heightmap_pixels(lambda p: p[:-1, :-1]), "not square"),
    "heightmap-missing": ("dem", lambda out: next(out.rglob("heightmap.png")).unlink(),
                          "missing"),
    "xyz-far": ("xyz", first_line("1e300 0 0"), "up to"),
    "xyz-nan": ("xyz", first_line("nan 0 0"), "non-finite"),
    "ply-far": ("ply", ply_first_x(-2e9), "up to"),
}  # fmt: skip


@pytest.mark.parametrize("name", list(DAMAGES))
def test_damaged_output_is_flagged(outputs: dict[str, Path], tmp_path: Path, name: str) -> None:
    which, damage, word = DAMAGES[name]
    src = outputs[which]
    copy = tmp_path / src.name
    if src.is_dir():
        shutil.copytree(src, copy)
    else:
        shutil.copyfile(src, copy)
    damage(copy)
    found = output_problems(copy)
    assert any(word in p for p in found), found


def test_flat_heightmap_passes(outputs: dict[str, Path], tmp_path: Path) -> None:
    """Every pixel 0: a flat field, which Gazebo scales by 1 (exporters/heightmap.quantise)."""
    copy = tmp_path / "image"
    shutil.copytree(outputs["image"], copy)
    heightmap_pixels(np.zeros_like)(copy)
    assert output_problems(copy) == []
