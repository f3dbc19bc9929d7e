"""``scan2terrain view``: time to the first frame that shows the world (run by hand, not a test).

    python benchmarks/bench_view.py [--runs 3]

Target (issue 30): under 3 s on the warehouse map's world and on a voxel world of about a million
triangles. Measured from starting the ``scan2terrain view`` process (a browser already open,
as a user's is) to the first screenshot of the page in which the world is drawn: the process
start, reading the folder, the viser server, the page and its websocket, the meshes sent and
drawn. The browser is Debian's chromium, headless, WebGL in SwiftShader (software, as on a
machine without GPU), driven by Playwright.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the repository: tests.*

from tests.fixtures import WAREHOUSE

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"]


def rough_ground(path: Path, side: float = 17.0, step: float = 0.05) -> Path:
    """A rough 2.5D ground, points ``step`` apart: its voxel surface has about a million
    triangles at 0.05 m voxels."""
    rng = np.random.default_rng(7)
    u = np.arange(0, side, step)
    x, y = np.meshgrid(u, u, indexing="ij")
    z = 0.6 * np.sin(x / 3) * np.cos(y / 4) + rng.normal(0, 0.06, x.shape)
    np.savetxt(path, np.column_stack([x.ravel(), y.ravel(), z.ravel()]), fmt="%.3f")
    return path


def first_frame(exe: Path, world: Path, port: int, page: object) -> float:
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [str(exe), "view", str(world), "--no-browser", "--port", str(port)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        while line and not line.startswith("Viewing "):
            line = proc.stdout.readline()
        page.goto(f"http://localhost:{port}")  # type: ignore[attr-defined]
        while True:
            png = page.screenshot()  # type: ignore[attr-defined]
            if drawn(png):
                return time.perf_counter() - t0
            if time.perf_counter() - t0 > 60:
                raise RuntimeError("no frame with the world in 60 s")
    finally:
        proc.terminate()
        proc.wait()


def drawn(png: bytes) -> bool:
    import io

    from PIL import Image

    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    canvas = rgb[160:, : int(rgb.shape[1] * 0.65)].astype(int)
    return bool((canvas.min(axis=-1) < 230).mean() > 0.05)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    exe = Path(sys.executable).parent / "scan2terrain"
    tmp = Path(tempfile.mkdtemp())
    from playwright.sync_api import sync_playwright

    from scan2terrain.readers.world import read_world

    try:
        worlds = {"warehouse map (walls)": tmp / "warehouse", "rough ground (voxels)": tmp / "v"}
        subprocess.run(
            [str(exe), "map2world", str(WAREHOUSE), "-o", str(worlds["warehouse map (walls)"])],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        cloud = rough_ground(tmp / "ground.xyz")
        voxels = ["--geometry", "voxels", "--resolution", "0.05"]
        out = worlds["rough ground (voxels)"]
        subprocess.run(
            [str(exe), "cloud2world", str(cloud), "-o", str(out), *voxels],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        rows = []
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            for name, world in worlds.items():
                triangles = len(read_world(world / "world_gz.sdf", simulator="gz").triangles)
                times = []
                for run in range(args.runs):
                    page = browser.new_page(viewport={"width": 1024, "height": 700})
                    times.append(first_frame(exe, world, 8600 + run, page))
                    page.close()
                rows.append((name, triangles, times))
                print(name, triangles, times, flush=True)
            browser.close()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"{'world':24s} {'triangles':>10s} {'best [s]':>9s} {'median [s]':>11s} {'target':>7s}")
    for name, triangles, times in rows:
        best, median = min(times), statistics.median(times)
        print(f"{name:24s} {triangles:10,d} {best:9.2f} {median:11.2f} {3.0:7.1f}")


if __name__ == "__main__":
    main()
