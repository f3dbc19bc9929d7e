"""The Python API: each command a function, with the command line's options as keyword
arguments and its refusals as exceptions; re-exported by the package (``scan2terrain.map2world``).

    import scan2terrain

    result = scan2terrain.map2world("map.yaml", "world", geometry="boxes", height=2.5)
    print(result.worlds[0].path, result.worlds[0].spawn)

One path: a call's arguments are read by the command line's own parser (``cli/parser.py``, the
options declared once in ``cli/options.py``), so a value is checked as the typed flag is, and
run by :func:`run`, which the CLI runs too: the same effective config, the same files, byte for
byte, the same report (:attr:`Result.text`).

Keywords are the command's long flags, dashes as underscores: ``--wall-faces half`` is
``wall_faces="half"``, ``--config cfg.yaml`` is ``config="cfg.yaml"``. A flag without a value
takes True (given) or False (not given): ``no_filter=True``, ``overwrite=True``. A flag of
several values, or a repeatable one, takes a sequence (``pose=(0, 0, 0.3, 0, 0, 0)``,
``topic=["/scan"]``; one value alone is fine too). None is the default, as a flag not typed.
:func:`keywords` lists a command's keywords with their help. The command line's ``-v``, ``-q``
and ``--progress`` have no keyword: the API prints nothing, raises with the traceback, and
takes a ``progress`` callback where the command reports progress.

Refusals are the errors of :mod:`scan2terrain.errors` (``InputError``, ``ConfigError``,
``OutputError``, all a ``Scan2TerrainError``), whose message is the line the command line
prints after ``error:`` (it only folds a library's text onto one line); a value the parser
refuses (not a number, not a choice, a wrong count) is a ``ConfigError``. An unknown keyword
is a ``TypeError`` naming the nearest ones. Nothing is written on a refusal.

Importing this module loads no numpy: the commands load on call.

Adding a command: its row in ``cli/dispatch.COMMANDS`` and its options in ``cli/parser.py``,
then a function here calling :func:`_call` with its positional arguments, listed in
:data:`COMMAND_FUNCTIONS` and ``__all__`` (and in the package's ``__init__.py``).
"""

from __future__ import annotations

import argparse
import difflib
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from scan2terrain.cli.dispatch import COMMANDS, Progress, ProgressCallback
from scan2terrain.cli.display import report
from scan2terrain.cli.parser import Parser, RaisingParser, build_parser, flags_of, name_flags
from scan2terrain.config import TOP_LEVEL_KEYS, load_config
from scan2terrain.errors import InputError, Scan2TerrainError
from scan2terrain.exporters.output import OutputDir

if TYPE_CHECKING:
    from scan2terrain.types import Spawn
    from scan2terrain.world.folder import Result as Written

__all__ = [
    "Progress",
    "ProgressCallback",
    "Result",
    "World",
    "bag2world",
    "cloud2world",
    "convert",
    "dem2world",
    "fidelity",
    "image2world",
    "inspect",
    "keywords",
    "map2world",
    "octree2world",
    "view",
]

#: A file or folder, as a string or a path.
StrPath: TypeAlias = "str | os.PathLike[str]"
#: One file, or several (a split bag, clouds merged).
StrPaths: TypeAlias = "StrPath | Sequence[StrPath]"
#: x, y, z (metres), roll, pitch, yaw (radians).
Pose: TypeAlias = "tuple[float, float, float, float, float, float]"


@dataclass(frozen=True)
class World:
    """One simulator's world in the folder written."""

    simulator: str  #: ``"gz"`` (gz-sim) or ``"classic"`` (Gazebo Classic)
    path: Path  #: the world file, absolute (world_gz.sdf, world_classic.world)
    spawn: Pose | None  #: where a robot can start, in this world's frame (spawn.yaml)


@dataclass(frozen=True)
class Result:
    """What a command did: the files it wrote, its notes and its report.

    ``paths`` are absolute (``out`` joined with each file's place in it, made absolute when the
    call ran), sorted; ``out`` is the folder (or convert's file) as given. ``spawn`` is where a
    robot can start in the map frame (``spawn.why`` says how it was chosen) and each
    :class:`World` has the pose in its own frame, as ``spawn.yaml`` says; ``fidelity`` is
    ``fidelity.yaml`` as read (the recording replayed in the worlds) when it was written.
    ``text`` is the report the command line prints.
    """

    command: str  #: the command's name (``"map2world"``)
    out: Path | None  #: the folder, or convert's file, written (None: inspect)
    paths: tuple[Path, ...]  #: every file written, absolute, sorted
    worlds: tuple[World, ...]  #: the worlds written, one per simulator
    notes: tuple[str, ...]  #: what was read and chosen (lines of the report)
    spawn: Spawn | None  #: where a robot can start, in the map frame
    fidelity: Mapping[str, Any] | None  #: fidelity.yaml's figures, when written
    text: str  #: the report, as the command line prints it


#: Options of the command line that are not keywords here: the output (a positional
#: argument), what the CLI prints, and its progress bars (a callback here).
_NOT_KEYWORDS = frozenset({"help", "out", "verbose", "quiet", "progress"})


def keywords(command: str) -> dict[str, str]:
    """The keywords a command's function takes, each with its help.

    Parameters
    ----------
    command : str
        The command's name, e.g. ``"map2world"``.

    Returns
    -------
    dict of str to str
        Keyword (the long flag, dashes as underscores) -> the flag and its help as
        ``scan2terrain COMMAND --help`` shows it.

    Raises
    ------
    ValueError
        There is no such command.
    """
    if command not in COMMANDS:
        near = difflib.get_close_matches(command, list(COMMANDS), n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ValueError(f"no command {command!r}{hint}; the commands: {', '.join(COMMANDS)}")
    return {
        key: f"{_flag(action)}: {action.help or ''}"
        for key, action in _options(_command_parser(build_parser(), command)).items()
    }


def run(args: argparse.Namespace, *, progress: ProgressCallback | None = None) -> Result:
    """Run a parsed command line: the one path of the CLI and of every function here.

    Parameters
    ----------
    args : argparse.Namespace
        What the command line's parser read (``args.command`` names the command).
    progress : callable, optional
        Called with a :class:`Progress` as the command goes (octree2world on scan files,
        bag2world, cloud2world); None: not called.

    Returns
    -------
    Result

    Raises
    ------
    Scan2TerrainError
        The command's refusal; config keys in its message are named as the flags.
    """
    command = COMMANDS[args.command]
    try:
        overrides = {k: v for k, v in vars(args).items() if "." in k or k in TOP_LEVEL_KEYS}
        config = getattr(args, "config", None)  # view takes no config
        cfg = load_config(config, overrides, defaults=dict(command.defaults))
        out = getattr(args, "out", None)
        side_inputs = [p for p in (config, cfg.scans.trajectory) if p is not None]
        if out is not None and side_inputs:  # files besides the command's input never go either
            OutputDir.check_target(out, args.overwrite, tuple(side_inputs))
        done = command.run(args, cfg, progress)
    except Scan2TerrainError as exc:
        _name_flags(exc, flags_of(build_parser(), args.command))
        raise
    return _result(args, done)


# --- the commands ----------------------------------------------------------------------------


def map2world(map: StrPath, out: StrPath, **options: Any) -> Result:
    """A ROS map_server map to a Gazebo world folder: ``scan2terrain map2world``.

    Reads the map as map_server does, filters it and writes the worlds (gz-sim and/or Classic:
    walls as one mesh by default, or boxes, polylines or a heightmap), the filtered map lined
    up with them, spawn.yaml, a preview and the effective config.

    Parameters
    ----------
    map : str or os.PathLike
        The map_server YAML file.
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``geometry="boxes"``, ``height=2.5``, ``no_filter=True``, ``config="cfg.yaml"``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the report.

    Raises
    ------
    InputError
        The map cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("map2world", [map], out, options)


def image2world(image: StrPath, out: StrPath, **options: Any) -> Result:
    """Any image to a Gazebo heightmap world, luminance as height: ``scan2terrain image2world``.

    Parameters
    ----------
    image : str or os.PathLike
        The image (PNG/JPG/TIFF/BMP/PGM, grey, RGB, RGBA, palette or 16-bit).
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``resolution=0.1``, ``height=1.5``, ``invert=True``, ``origin=(1.0, 2.0)``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the report.

    Raises
    ------
    InputError
        The image cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("image2world", [image], out, options)


def dem2world(dem: StrPath, out: StrPath, **options: Any) -> Result:
    """An elevation model to a world at its true elevations: ``scan2terrain dem2world``.

    Parameters
    ----------
    dem : str or os.PathLike
        The DEM (a single-band GeoTIFF).
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``resolution=10.0``, ``bit_depth=8``, ``simulator="both"``, ``dem_passthrough=True``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the report.

    Raises
    ------
    InputError
        The DEM cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("dem2world", [dem], out, options)


def octree2world(
    tree: StrPath, out: StrPath, *, progress: ProgressCallback | None = None, **options: Any
) -> Result:
    """An OctoMap octree or scan file to a Gazebo world folder: ``scan2terrain octree2world``.

    Parameters
    ----------
    tree : str or os.PathLike
        A ``.bt`` file, or an OctoMap scan file (``.dat``, ``.dat.bz2``, ``.dat.gz``).
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    progress : callable, optional
        Called with a :class:`Progress` after each scan of a scan file.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``z_min=0.1``, ``z_max=1.8``, ``grid="height"``, ``geometry="voxels"``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the fidelity figures
        (a scan file's beams replayed), the report.

    Raises
    ------
    InputError
        The octree cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("octree2world", [tree], out, options, progress)


def bag2world(
    bag: StrPaths, out: StrPath, *, progress: ProgressCallback | None = None, **options: Any
) -> Result:
    """A ROS 1 / ROS 2 bag, MCAP file or CARMEN log to a world folder: ``scan2terrain bag2world``.

    Parameters
    ----------
    bag : str or os.PathLike, or a sequence of them
        The bag file(s) (a split bag), rosbag2 folder, or CARMEN log.
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    progress : callable, optional
        Called with a :class:`Progress` as scans are inserted (given, the bag's scans are
        counted first, for the total) or streamed tasks are done.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``topic=["/scan"]``, ``pose=(0, 0, 0.3, 0, 0, 0)``, ``resolution=0.05``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the fidelity figures,
        the report.

    Raises
    ------
    InputError
        The bag cannot be read or used; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("bag2world", _many(bag), out, options, progress)


def cloud2world(
    clouds: StrPaths, out: StrPath, *, progress: ProgressCallback | None = None, **options: Any
) -> Result:
    """Point-cloud files to a Gazebo world folder: ``scan2terrain cloud2world``.

    Parameters
    ----------
    clouds : str or os.PathLike, or a sequence of them
        The cloud files (PCD, PLY, XYZ, CSV, LAS/LAZ); with ``stream=True`` also LAS/LAZ URLs.
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    progress : callable, optional
        Called with a :class:`Progress` as streamed tasks are done (``stream=True``).
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``grid="height"``, ``resolution=0.5``, ``las_classes=[2]``, ``local_origin="auto"``.

    Returns
    -------
    Result
        The files written, the worlds and their spawn poses, the notes, the report.

    Raises
    ------
    InputError
        A cloud cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("cloud2world", _many(clouds), out, options, progress)


def convert(source: StrPaths, target: StrPath, **options: Any) -> Result:
    """Cloud files, or a bag's scans, to one cloud file: ``scan2terrain convert``.

    Parameters
    ----------
    source : str or os.PathLike, or a sequence of them
        The cloud file(s), bag, or CARMEN log.
    target : str or os.PathLike
        The cloud file to write (its format by its extension): refused if it exists, unless
        ``overwrite=True``.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``topic="/points"``, ``pose=(0, 0, 1.8, 0, 0, 0)``, ``outliers=2.0``.

    Returns
    -------
    Result
        ``paths`` holds the target; ``text`` the report.

    Raises
    ------
    InputError
        A source cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        The target exists (without ``overwrite=True``), or has no cloud format's extension.
    TypeError
        A keyword the command does not take.
    """
    return _call("convert", [*_many(source), target], None, options)


def inspect(bag: StrPaths, **options: Any) -> Result:
    """What a bag holds and what bag2world would use: ``scan2terrain inspect``.

    Parameters
    ----------
    bag : str or os.PathLike, or a sequence of them
        The bag file(s), rosbag2 folder, or CARMEN log.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``topic="/scan"``, ``max_range=20.0``.

    Returns
    -------
    Result
        ``text`` is the listing; nothing is written.

    Raises
    ------
    InputError
        The bag cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    TypeError
        A keyword the command does not take.
    """
    return _call("inspect", _many(bag), None, options)


def fidelity(world: StrPath, recording: StrPaths, out: StrPath, **options: Any) -> Result:
    """Any Gazebo world scored against a recording replayed in it: ``scan2terrain fidelity``.

    Parameters
    ----------
    world : str or os.PathLike
        The world file (``.sdf`` or ``.world``).
    recording : str or os.PathLike, or a sequence of them
        The bag file(s), rosbag2 folder, or OctoMap scan file.
    out : str or os.PathLike
        The output folder (``-o``): refused if it exists, unless ``overwrite=True``.
    **options
        The command's options by long flag (module docstring, :func:`keywords`), e.g.
        ``simulator="classic"``, ``mount=(0, 0, 0.2, 0, 0, 0)``.

    Returns
    -------
    Result
        ``fidelity`` holds the figures (fidelity.yaml); ``paths`` the files written.

    Raises
    ------
    InputError
        The world or the recording cannot be read; the message names the file and the problem.
    ConfigError
        An option's value is refused, as the command line refuses it.
    OutputError
        ``out`` exists (without ``overwrite=True``) or cannot be written.
    TypeError
        A keyword the command does not take.
    """
    return _call("fidelity", [world, *_many(recording)], out, options)


def view(world: StrPath, **options: Any) -> Result:
    """A world folder in the browser until Ctrl-C: ``scan2terrain view``.

    Parameters
    ----------
    world : str or os.PathLike
        The world folder (written by scan2terrain).
    **options
        The command's options by long flag (module docstring, :func:`keywords`):
        ``host="127.0.0.1"``, ``port=8080``, ``no_browser=True``.

    Returns
    -------
    Result
        When the server stops (Ctrl-C); nothing is written. To serve without blocking, use
        :class:`scan2terrain.commands.view.Viewer`.

    Raises
    ------
    InputError
        ``world`` is not a world folder, a file in it is broken, or the port cannot be served.
    ConfigError
        An option's value is refused, as the command line refuses it.
    TypeError
        A keyword the command does not take.
    """
    return _call("view", [world], None, options)


#: The function of each command, by the command's name.
COMMAND_FUNCTIONS = {
    "map2world": map2world,
    "image2world": image2world,
    "octree2world": octree2world,
    "bag2world": bag2world,
    "cloud2world": cloud2world,
    "convert": convert,
    "inspect": inspect,
    "dem2world": dem2world,
    "fidelity": fidelity,
    "view": view,
}


# --- keywords -> the command line's words ---------------------------------------------------


def _call(
    command: str,
    positionals: Sequence[StrPath],
    out: StrPath | None,
    options: Mapping[str, Any],
    progress: ProgressCallback | None = None,
) -> Result:
    """``command`` run with these arguments, read by the command line's parser."""
    parser = build_parser(RaisingParser)
    words = [command, *_words(command, _command_parser(parser, command), options)]
    if out is not None:
        words.append(f"--out={_word(out)}")
    args = parser.parse_args([*words, "--", *map(_word, positionals)])
    return run(args, progress=progress)


def _command_parser(parser: Parser, command: str) -> Parser:
    return parser.commands[command][0]


def _options(sub: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    """A command's options by keyword: the long flag, dashes as underscores."""
    return {
        _flag(a)[2:].replace("-", "_"): a
        for a in sub._actions
        if a.option_strings and a.dest not in _NOT_KEYWORDS
    }


def _flag(action: argparse.Action) -> str:
    return max(action.option_strings, key=len)


def _words(command: str, sub: argparse.ArgumentParser, options: Mapping[str, Any]) -> list[str]:
    """``options`` as the command line's words (``--flag=value``: a value starting with a dash
    stays a value; several values after their flag; positional arguments go after ``--``)."""
    known = _options(sub)
    words: list[str] = []
    for key, value in options.items():
        action = known.get(key)
        if action is None:
            raise TypeError(_unexpected(command, key, [*known, *_positional_names(sub)]))
        flag = _flag(action)
        if value is None:
            continue
        if action.nargs == 0:  # a flag without a value
            if not isinstance(value, bool):
                raise TypeError(
                    f"{command}() takes {key}=True ({flag}) or False (no {flag}), not {value!r}"
                )
            if value:
                words.append(flag)
        elif isinstance(action, argparse._AppendAction):  # repeatable
            words += [f"{flag}={_word(v)}" for v in _many(value)]
        elif action.nargs is None:
            words.append(f"{flag}={_word(value)}")
        else:
            words += [flag, *map(_word, _many(value))]
    return words


def _positional_names(sub: argparse.ArgumentParser) -> list[str]:
    return [a.dest for a in sub._actions if not a.option_strings] + ["out"]


def _unexpected(command: str, key: str, known: list[str]) -> str:
    near = difflib.get_close_matches(key, known, n=3, cutoff=0.6)
    hint = f" (did you mean {' or '.join(map(repr, near))}?)" if near else ""
    return (
        f"{command}() got an unexpected keyword argument {key!r}{hint}; "
        f"scan2terrain.api.keywords({command!r}) lists them"
    )


def _many(value: Any) -> list[Any]:
    """One value, or each of a sequence's (a string or a path is one)."""
    if isinstance(value, (str, bytes, os.PathLike)) or not isinstance(value, Sequence):
        return [value]
    return list(value)


def _word(value: Any) -> str:
    return os.fspath(value) if isinstance(value, os.PathLike) else str(value)


# --- what was done -> Result -----------------------------------------------------------------


def _name_flags(exc: Scan2TerrainError, flags: dict[str, str]) -> None:
    """``exc``'s message with its config keys named as flags, as the CLI prints it (in place:
    its class, traceback and cause stay)."""
    if isinstance(exc, InputError):
        exc.problem = name_flags(exc.problem, flags)
        exc.args = (f"{exc.path}: {exc.problem}" if exc.path is not None else exc.problem,)
    elif len(exc.args) == 1 and isinstance(exc.args[0], str):
        exc.args = (name_flags(exc.args[0], flags),)


def _result(args: argparse.Namespace, done: Written | str) -> Result:
    if isinstance(done, str):  # a command that writes no folder: its report
        target = getattr(args, "target", None)
        written = () if target is None else (Path(target).absolute(),)
        out = None if target is None else Path(target)
        return Result(args.command, out, written, (), (), None, None, done)
    out = Path(done.out)
    paths = tuple(sorted(p.absolute() for p in out.rglob("*") if p.is_file()))
    worlds = tuple(World(w.placement.simulator, w.world.absolute(), w.spawn) for w in done.worlds)
    figures = out / "fidelity.yaml"
    return Result(
        args.command,
        out,
        paths,
        worlds,
        tuple(done.notes),
        done.spawn,
        _read_yaml(figures) if figures.is_file() else None,
        report(done),
    )


def _read_yaml(path: Path) -> Any:
    import yaml

    return yaml.safe_load(path.read_text())
