"""What the CLI shows: the report of a written world (how to open it, where to spawn a robot) and
the progress bars (tqdm, on stderr)."""

from __future__ import annotations

import json
import math
import shlex
import sys
import time
from typing import TYPE_CHECKING, Any

from scan2terrain.texts import minus

if TYPE_CHECKING:
    from pathlib import Path

    from scan2terrain.types import ScanCounts
    from scan2terrain.world.folder import Result


class ProgressBar:
    """Scans/s, points/s and ETA on stderr (tqdm), updated at most a few times a second. Rates
    count from entering the block, not from the first update (which comes after a scan)."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self._bar: Any = None
        self._last = 0
        self._start = 0.0

    def __enter__(self) -> ProgressBar:
        self._start = time.monotonic()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()

    def update(self, counts: ScanCounts, total: int) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total or None,
                unit="scan",
                file=sys.stderr,
                dynamic_ncols=True,
                mininterval=0.25,
            )
        self._bar.update(counts.messages - self._last)
        self._last = counts.messages
        self._bar.set_postfix_str(_rate(counts.points, self._start), refresh=False)


class TaskBar:
    """Streamed tasks done and points/s on stderr (tqdm)."""

    def __init__(self, *, enabled: bool) -> None:
        self.enabled = enabled
        self._bar: Any = None
        self._last = 0
        self._start = 0.0

    def __enter__(self) -> TaskBar:
        self._start = time.monotonic()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.close()

    def update(self, done: int, total: int, points: int) -> None:
        if not self.enabled:
            return
        if self._bar is None:
            from tqdm import tqdm

            self._bar = tqdm(
                total=total, unit="task", file=sys.stderr, dynamic_ncols=True, mininterval=0.25
            )
        self._bar.update(done - self._last)
        self._last = done
        self._bar.set_postfix_str(_rate(points, self._start), refresh=False)


def _rate(points: int, start: float) -> str:
    """Points per second since ``start`` (time.monotonic), as the bars show it."""
    elapsed = max(time.monotonic() - start, 1e-3)
    return f"{points / elapsed / 1e6:.2f} M points/s"


def spawn_lines(simulator: str, pose: tuple[float, ...], robot: Path | None) -> list[str]:
    """Where to spawn a robot (spawn.yaml), and the commands that put the folder's robot
    (``robot``, its model file for this simulator; None: a ``ROBOT.sdf`` of the user's) there."""
    x, y, z, _, _, yaw = (f"{v:g}" for v in pose)
    which = "e.g.:" if robot is None else "e.g. the folder's robot/:"
    head = f"    spawn a robot at x={x} y={y} z={z} yaw={yaw} (spawn.yaml), {which}"
    path = "ROBOT.sdf" if robot is None else str(robot.absolute())
    model = shlex.quote(path)
    if simulator == "gz":
        qz, qw = math.sin(pose[5] / 2), math.cos(pose[5] / 2)
        # In the request the path is a protobuf text string: quoted for it, and the whole
        # request quoted once more for the shell.
        name = json.dumps(path)
        req = (
            f'sdf_filename: {name}, name: "robot", pose: {{position: {{x: {x}, y: {y},'
            f" z: {z}}}, orientation: {{z: {qz:.6g}, w: {qw:.6g}}}}}"
        )
        return [
            head,
            "      gz service -s /world/scan2terrain/create --reqtype gz.msgs.EntityFactory"
            f" --reptype gz.msgs.Boolean --timeout 5000 --req {shlex.quote(req)}",
            f"      ros2 run ros_gz_sim create -world scan2terrain -file {model} -name robot"
            f" -x {x} -y {y} -z {z} -Y {yaw}",
        ]
    return [
        head,
        f"      gz model --spawn-file={model} --model-name=robot -x {x} -y {y} -z {z} -Y {yaw}",
        f"      rosrun gazebo_ros spawn_model -sdf -file {model} -model robot"
        f" -x {x} -y {y} -z {z} -Y {yaw}",
    ]


def report(result: Result) -> str:
    """How to open what was written, for a human."""
    out = result.out
    walls = result.geometry != "heightmap"
    rows, cols = result.tiles
    side = f"{result.heightmap_side}x{result.heightmap_side} px"
    ground = f"heightmap {side}" if rows * cols == 1 else f"{rows}x{cols} heightmap tiles of {side}"
    lines = [
        f"Wrote {out}/ ({result.headline})"
        if result.headline
        else f"Wrote {out}/ (no world: {result.no_world})"
        if result.no_world
        else f"Wrote {out}/ (voxels: {result.walls}; {result.size_z:g} m from the lowest to the"
        " highest voxel)"
        if result.geometry == "voxels"
        else f"Wrote {out}/ ({result.geometry}: {result.walls}; walls {result.size_z:g} m high)"
        if walls
        else f"Wrote {out}/ ({ground} at {result.resolution:g} m/px, heights up to "
        f"{result.size_z:g} m)"
    ]
    for w in result.worlds:
        p = w.placement
        # Absolute paths: the resource variables are read by a simulator started anywhere.
        # Quoted: pasted into a shell, a path with spaces stays one word.
        models, world = shlex.quote(str(w.models.absolute())), shlex.quote(str(w.world.absolute()))
        if p.simulator == "gz":
            lines += [
                "  gz-sim (Garden or newer; DART physics, the default engine):",
                f"    GZ_SIM_RESOURCE_PATH={models} gz sim {world}",
                f"    (Fortress: IGN_GAZEBO_RESOURCE_PATH={models} ign gazebo {world})",
                "    map frame = world frame: a map point (x, y) is world (x, y).",
            ]
        elif walls:
            lines += [
                "  Gazebo Classic:",
                f"    GAZEBO_MODEL_PATH={models} gazebo {world}",
                "    map frame = world frame: a map point (x, y) is world (x, y).",
            ]
        else:
            ox, oy = p.offset
            lines += [
                "  Gazebo Classic:",
                f"    GAZEBO_MODEL_PATH={models} gazebo {world}",
                "    Classic cannot move a heightmap: the terrain is centred on the world origin,",
                f"    a map point (x, y) is world ({minus('x', ox)}, {minus('y', oy)}).",
            ]
        if w.map_yaml is not None:
            lines.append(f"    navigation map lined up with this world: {w.map_yaml}")
        if w.spawn is not None:
            lines += spawn_lines(p.simulator, w.spawn, w.robot)
    if result.preview is not None:
        lines.append(f"  preview ({result.preview_label}): {result.preview}")
    if result.preview3d is not None:
        sim = result.worlds[0].placement.simulator
        lines.append(f"  3D preview ({sim} collision geometry, spawn in red): {result.preview3d}")
    for note in result.notes:
        lines.append(f"  {note}")
    lines.append(f"  effective config: {result.config}")
    return "\n".join(lines)
