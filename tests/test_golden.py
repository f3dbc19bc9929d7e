"""Golden regression: the outputs for the real maps and an image, file by file.

PNG files are compared by their decoded pixels (the compressed bytes depend on the zlib build),
everything else byte for byte. Regenerate on purpose only, and say why in the commit message:

    SCAN2TERRAIN_REGEN_GOLDEN=1 pytest tests/test_golden.py
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from scan2terrain.cli import main
from tests.fixtures import IMAGES, MAPS

GOLDEN = Path(__file__).parent / "golden/outputs.json"
CASES = {
    **{f"map2world_{k}": ["map2world", str(v)] for k, v in MAPS.items()},
    "map2world_willow_heightmap": ["map2world", str(MAPS["willow"]), "--geometry", "heightmap"],
    "image2world_bowl": ["image2world", str(IMAGES["bowl_rgb"]), "--resolution", "0.25"],
    "map2world_tb3_paper_options": [
        "map2world",
        str(MAPS["tb3"]),
        "--filter",
        "paper",
        "--unknown",
        "height",
        "--width",
        "300",
        "--canvas-height",
        "200",
        "--offset-x",
        "-20",
        "--offset-y",
        "10",
        "--invert",
        "--speckle-min-cells",
        "3",
        "--upsample",
        "2",
        "--bit-depth",
        "16",
        "--simulator",
        "gz",  # 16-bit is gz-sim only: Classic reads the first byte (refused with both)
    ],
}


def digest(path: Path) -> str:
    if path.suffix in (".png", ".pgm"):
        with Image.open(path) as im:
            pixels = np.asarray(im)
            tag = f"{im.mode}{pixels.shape}".encode()
        return hashlib.sha256(tag + pixels.tobytes()).hexdigest()
    return hashlib.sha256(path.read_bytes()).hexdigest()


def outputs(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): digest(p) for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("case", sorted(CASES))
def test_golden(tmp_path: Path, case: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    assert main([*CASES[case], "-o", str(out), "-q"]) == 0, capsys.readouterr().err
    got = outputs(out)
    golden = json.loads(GOLDEN.read_text()) if GOLDEN.exists() else {}
    if os.environ.get("SCAN2TERRAIN_REGEN_GOLDEN"):
        golden[case] = got
        GOLDEN.write_text(json.dumps(golden, indent=1, sort_keys=True) + "\n")
    assert case in golden, f"no golden for {case}: regenerate on purpose (see module docstring)"
    assert got == golden[case]
