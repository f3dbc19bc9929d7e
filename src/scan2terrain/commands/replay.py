"""The recording replayed in the worlds a command computed (bag2world, octree2world on scan
files): ``trajectory.tum`` (the sensor poses used), and unless ``output.fidelity`` is off,
``fidelity.yaml`` / ``fidelity.png`` and a line of the report, made from the worlds' bytes
before the folder is written (:class:`Replay`, a ``world.folder.Derived``).

Each world is read back from the bytes about to be written (``readers/world.py``: the
collision geometry Gazebo builds, heightmaps as its physics triangulates them), and the
beams are cast in it from their recorded sensor poses (``replay/cast.py``).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from scan2terrain.checks import refuse_existing, refuse_unused, skipped_notes
from scan2terrain.commands.correct import correct_plan
from scan2terrain.config import Config
from scan2terrain.errors import FidelityWarning, InputError
from scan2terrain.exporters.fidelity import (
    fidelity_ends_ply,
    fidelity_png,
    fidelity_yaml,
    summary,
)
from scan2terrain.exporters.trajectory import tum_bytes
from scan2terrain.readers.octomap_scan import is_scan_file, read_scans
from scan2terrain.readers.points import within_reach
from scan2terrain.readers.poses import matrices_to_quaternions
from scan2terrain.readers.scans import plan_bag, posed_scans
from scan2terrain.readers.world import read_world
from scan2terrain.replay.beams import BeamRecorder
from scan2terrain.replay.cast import fidelity
from scan2terrain.types import Beams, Fidelity, PoseCorrection, ScanCounts
from scan2terrain.world.folder import Result, SimWorld, WorldFolder, write_world_folder

if TYPE_CHECKING:
    from scan2terrain.readers.world import WorldGeometry

#: Fewer beams than this share within 10 cm: the report warns.
WARN_BELOW = 0.5
#: In a world of walls on a floor at z = 0, a sensor this close above the floor, or below
#: it, is replayed this high above it (metres): a 2D scan plane on the floor meets the floor's
#: edge, and a ray starting on a surface stops on it.
FLOOR_CLEARANCE = 0.1


@dataclass(frozen=True)
class Replay:
    """What :func:`~scan2terrain.world.folder.write_world_folder` asks for the replay's files."""

    beams: Beams
    pose_source: str  #: where the poses came from (the plan's reason)
    fidelity: bool = True  #: output.fidelity
    #: The worlds' floor (map z) where they are walls on a ground at z = 0 (occupancy grids):
    #: a 2D laser at or below it is replayed FLOOR_CLEARANCE above it; None: terrain.
    floor: float | None = None
    #: The poses before correction (``scans.correct``), for trajectory_raw.tum.
    raw: PoseCorrection | None = None

    def files(self, worlds: Sequence[SimWorld]) -> tuple[dict[str, bytes], list[str]]:

        b = self.beams
        files = {
            "trajectory.tum": tum_bytes(
                b.stamps_ns,
                b.origins,
                matrices_to_quaternions(b.rotations),
                comment="the sensor poses of the scans used, by scan2terrain\nt x y z qx qy qz qw",
            )
        }
        if (raw := self.raw) is not None:
            files["trajectory_raw.tum"] = tum_bytes(
                raw.stamps_ns,
                raw.prior_xyz,
                raw.prior_xyzw,
                comment="the sensor poses as recorded, before correction, by scan2terrain\n"
                "t x y z qx qy qz qw",
            )
        if not self.fidelity or not worlds:
            return files, []
        if len(b.scan) == 0:
            return files, ["fidelity: no beam with a return to replay"]
        notes = []
        b, lifted = lift_low(b, self.floor)
        if lifted:
            notes.append(
                f"fidelity: {lifted} scan(s) with the sensor at or below the walls' floor "
                f"(z < {FLOOR_CLEARANCE:g} m) replayed {FLOOR_CLEARANCE:g} m above it (no mount "
                "height known? --mount or --pose gives it)"
            )
        reports: list[Fidelity] = []
        seen: list[tuple[WorldGeometry, tuple[float, float, float], Fidelity]] = []
        for w in worlds:
            geometry, offset = world_geometry(w)
            # Walls are the same triangles in both simulators' worlds: cast once.
            same = [f for g, o, f in seen if o == offset and _same(g, geometry)]
            if same:
                reports.append(dataclasses.replace(same[0], world=w.name))
                continue
            reports.append(replay(geometry, offset, b, w.name, self.pose_source))
            seen.append((geometry, offset, reports[-1]))
        sampled = len(b.scan) < b.returns
        files["fidelity.yaml"] = fidelity_yaml(reports, beams_used=len(b.scan), sampled=sampled)
        files["fidelity.png"] = fidelity_png(reports[0])
        files["fidelity_ends.ply"] = fidelity_ends_ply(reports[0])
        notes[:0] = [summary(r) for r in reports]
        worst = min(reports, key=lambda r: r.overall.within_10cm or 0.0)
        if (worst.overall.within_10cm or 0.0) < WARN_BELOW:
            warnings.warn(advice(worst), FidelityWarning, stacklevel=2)
        return files, notes


def posed_by(pose_source: str, raw: PoseCorrection | None) -> str:
    """Where the poses came from, saying when they were corrected."""
    return (
        pose_source
        if raw is None
        else f"{pose_source}, corrected by scan matching and loop closure"
    )


def scan_replay(
    recorder: BeamRecorder, pose_source: str, cfg: Config, raw: PoseCorrection | None = None
) -> Replay:
    """The replay of the scans a world is made from, for the folder writer; ``raw``: the
    correction applied to their poses."""
    return Replay(
        recorder.beams(),
        raw=raw,
        pose_source=posed_by(pose_source, raw),
        fidelity=cfg.output.fidelity,
        # Walls stand on a floor at z = 0; terrain and voxels keep the map's heights.
        floor=0.0 if cfg.octree.grid == "occupancy" and cfg.world.geometry != "voxels" else None,
    )


def lift_low(beams: Beams, floor: float | None) -> tuple[Beams, int]:
    """The beams with each scan's sensor raised to ``FLOOR_CLEARANCE`` above ``floor`` where
    it lies lower (walls are extruded upwards from the floor, so a 2D scan plane's height
    within them does not change a range, but a plane on the floor meets the floor's edge), and
    how many scans were raised."""
    if floor is None:
        return beams, 0
    low = beams.origins[:, 2] < floor + FLOOR_CLEARANCE
    if not low.any():
        return beams, 0
    origins = beams.origins.copy()
    origins[low, 2] = floor + FLOOR_CLEARANCE
    return dataclasses.replace(beams, origins=origins), int(low.sum())


def world_geometry(world: SimWorld) -> tuple[WorldGeometry, tuple[float, float, float]]:
    """One world's collision geometry, read back from its bytes, and the offset of its frame
    from the map frame."""
    geometry = world.collisions()
    return geometry, (world.map_offset[0], world.map_offset[1], world.z_offset)


def replay(
    geometry: WorldGeometry,
    offset: tuple[float, float, float],
    beams: Beams,
    name: str,
    pose_source: str,
) -> Fidelity:
    """The beams cast into one world's triangles (world = map frame - ``offset``)."""

    return fidelity(
        geometry.vertices,
        geometry.triangles,
        beams,
        world=name,
        pose_source=pose_source,
        offset=offset,
    )


def _same(a: WorldGeometry, b: WorldGeometry) -> bool:
    return np.array_equal(a.vertices, b.vertices) and np.array_equal(a.triangles, b.triangles)


def advice(report: Fidelity) -> str:
    """The warning of a world that replays badly, with the likely cause and what helps."""
    f = report.overall
    within = 100 * (f.within_10cm or 0.0)
    causes = []
    if (f.inside or 0.0) > 0.2:
        causes.append(
            f"{100 * (f.inside or 0.0):.0f}% of the beams start inside the world's solids (a "
            "floor or ceiling taken as walls: --z-min/--z-max keep them out of the grid; or "
            "the sensor's height: --pose, --mount)"
        )
    if "odometry" in report.pose_source:
        causes.append(
            "the poses are raw odometry, which drifts (a SLAM map's tf, or a "
            "corrected --trajectory, gives the place)"
        )
    if (f.nothing or 0.0) > 0.2:
        causes.append(
            "many beams hit nothing: lower --max-range or the resolution, or widen --z-min/--z-max"
        )
    if (f.short or 0.0) > 0.2:
        causes.append(
            "many beams stop short: walls doubled or thick (pose drift, --resolution too "
            "coarse), or a floor taken for walls (--z-min/--z-max)"
        )
    if not causes:
        causes.append("check the pose source (--poses) and --resolution")
    return (
        f"{report.world}: only {within:.1f}% of the recorded beams replayed in the world land "
        f"within 10 cm of where the sensor saw them (fidelity.png shows where): "
        + "; ".join(causes)
    )


# --- scan2terrain fidelity WORLD RECORDING ------------------------------------------------------


def fidelity_command(
    world: Path,
    recording: Sequence[Path],
    out: Path,
    cfg: Config,
    *,
    simulator: str = "gz",
    overwrite: bool = False,
) -> Result:
    """Any Gazebo world scored against a recording (a bag, or an OctoMap scan file): the
    world's collision geometry, as the simulator builds it, in the recording's fixed frame;
    writes ``fidelity.yaml``, ``fidelity.png`` and ``trajectory.tum`` to ``out``."""

    refuse_existing(out, overwrite, (world, *recording))
    geometry = read_world(Path(world), simulator=simulator)  # type: ignore[arg-type]
    got = record(recording, cfg)
    pose_source, source = got.pose_source, got.source
    beams = got.recorder.beams()
    if len(beams.scan) == 0:
        raise InputError(source, "no scan has a beam with a return to replay")
    replay = Replay(beams, pose_source, floor=None, raw=got.raw)
    files, _ = replay.files([])  # trajectory.tum (and trajectory_raw.tum when corrected)
    report = fidelity(
        geometry.vertices,
        geometry.triangles,
        beams,
        world=Path(world).name,
        pose_source=pose_source,
    )
    sampled = len(beams.scan) < beams.returns
    files["fidelity.yaml"] = fidelity_yaml([report], beams_used=len(beams.scan), sampled=sampled)
    files["fidelity.png"] = fidelity_png(report)
    files["fidelity_ends.ply"] = fidelity_ends_ply(report)
    result = Result(out, notes=[summary(report), *got.notes, *geometry.parts])
    result.headline = f"a replay of {source.name} in {Path(world).name}"
    if (report.overall.within_10cm or 0.0) < WARN_BELOW:
        warnings.warn(advice(report), FidelityWarning, stacklevel=2)
    folder = WorldFolder(source, result, [], None, None, files, cfg)
    return write_world_folder(folder, out, overwrite=overwrite)


@dataclass
class Recorded:
    """A recording's posed scans, as :func:`record` read them."""

    recorder: BeamRecorder
    pose_source: str
    notes: list[str]
    source: Path  #: the file read (a bag's, in a rosbag2 folder)
    raw: PoseCorrection | None = None  #: the correction applied to the poses (scans.correct)


def record(recording: Sequence[Path], cfg: Config) -> Recorded:
    """Every posed scan of a recording (a bag, or an OctoMap scan file) into a recorder, posed
    as bag2world poses them: with ``scans.correct`` applied the same way."""
    from scan2terrain.readers.bag import open_bag

    recorder = BeamRecorder()
    first = Path(recording[0])
    if len(recording) == 1 and is_scan_file(first):
        for scan in read_scans(first):
            recorder.add(scan, within_reach(scan.points, scan.origin, cfg.octree.max_range))
        if recorder.scans == 0:
            raise InputError(first, "no scan in the file")
        return Recorded(recorder, "the scan file's NODE poses", [f"scans: {recorder.scans}"], first)

    with open_bag([Path(r) for r in recording]) as bag:
        plan = plan_bag(bag, cfg.scans, max_range=cfg.octree.max_range)
        if not plan.scan_topics:
            raise InputError(bag.path, "no LaserScan or PointCloud2 topic to replay")
        corrected = correct_plan(bag, cfg, plan)
        counts = ScanCounts()
        for scan in posed_scans(bag, cfg.scans, plan, counts, max_range=cfg.octree.max_range):
            recorder.add(scan)
            counts.inserted += 1
        refuse_unused(bag.path, counts, "replayed")
    notes = [*plan.reasons, *corrected, f"scans: {counts.inserted} replayed"]
    pose_source = posed_by(plan.pose_source, plan.correction)
    return Recorded(
        recorder, pose_source, [*notes, *skipped_notes(counts)], bag.path, plan.correction
    )
