"""The effective config written beside a world (scan2terrain.yaml) names what was built: every
``auto`` the command resolved is written as the value it used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from scan2terrain.cli import main
from tests.fixtures import FUSE_DIR


def written(out: Path) -> dict[str, dict[str, object]]:
    doc: dict[str, dict[str, object]] = yaml.safe_load((out / "scan2terrain.yaml").read_text())
    return doc


@pytest.mark.parametrize(
    ("extra", "insert"),
    [([], "raycast"), (["--stream"], "endpoints"), (["--insert", "endpoints"], "endpoints")],
)
def test_bag2world_names_how_the_scans_went_in(
    tmp_path: Path, extra: list[str], insert: str
) -> None:
    out = tmp_path / "w"
    args = ["bag2world", str(FUSE_DIR), "-o", str(out), "--correct", "off", "--no-fidelity", "-q"]
    assert main([*args, *extra]) == 0
    cfg = written(out)
    assert cfg["scans"]["insert"] == insert
    assert cfg["world"]["geometry"] == "mesh" and cfg["world"]["wall_faces"] == "hits"


def test_cloud2world_names_end_points(tmp_path: Path) -> None:
    cloud = tmp_path / "box.xyz"
    pts = np.random.default_rng(3).uniform((-2, -2, 0), (2, 2, 1), size=(500, 3))
    np.savetxt(cloud, pts, fmt="%.3f")
    out = tmp_path / "w"
    assert main(["cloud2world", str(cloud), "-o", str(out), "--resolution", "0.1", "-q"]) == 0
    assert written(out)["scans"]["insert"] == "endpoints"


@pytest.mark.parametrize("extra", [[], ["--stream"]])
def test_bag2world_names_how_the_scans_were_posed(tmp_path: Path, extra: list[str]) -> None:
    """scans.poses and scans.correct: auto are written as the source used and the decision
    taken; a rerun with the written config poses the scans the same way."""
    out, again = tmp_path / "w", tmp_path / "again"
    args = ["bag2world", str(FUSE_DIR), "--no-fidelity", "--no-preview", "-q", *extra]
    assert main([*args, "-o", str(out)]) == 0
    scans = written(out)["scans"]
    assert scans["poses"] in ("tf", "odom") and scans["correct"] in ("on", "off"), scans
    assert main([*args, "-o", str(again), "--config", str(out / "scan2terrain.yaml")]) == 0
    assert written(again) == written(out)
    for name in ("map/map.pgm", "spawn.yaml"):
        assert (again / name).read_bytes() == (out / name).read_bytes()
