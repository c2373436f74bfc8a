"""All-or-nothing output files.

Every output of a job is first written under a temporary name in its own directory; only when
the whole job has succeeded are they renamed into place (``os.replace`` is atomic on one file
system). On any error or interrupt the temporaries are removed, so a failed run leaves no
partial output. The commands that write a USD stage share its companions here: a JSON sidecar,
a preview video and a contact sheet (``StageOutputs``), and how the stage holds the body
(``--body-points``, ``stage_rig``).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import signal
import sys
import tempfile
import threading
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from pipelines.progress import progress_bar
from sim.errors import WrinklesInputError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from sim.bodies.model import BodyModel
    from sim.types import BodyFrames, BodyRig

USD_SUFFIXES = (".usdc", ".usd", ".usda")
#: the stage format the commands write unless ``--out`` names another: binary crate, about a
#: third of the text format's size.
DEFAULT_USD_SUFFIX = ".usdc"
BODY_POINTS_HELP = (
    "write the body as a point cache (every vertex at every frame, ~10 MB per 2 s of the default "
    "body in .usdc) instead of a UsdSkel rig: a skeleton with joint animation and the skinned mesh "
    "(with pose blend shapes where the body model has them), which Blender and other USD "
    "applications pose as we do, at ~0.5 MB for 2 s and ~1 MB for 30 s")
PREVIEW_SUFFIXES = (".mp4", ".gif")


def _missing_folders(folder: Path) -> tuple[Path, list[Path]]:
    """The nearest folder at or above ``folder`` that exists (a link counts, even one to
    nowhere), and the folders below it down to ``folder`` that do not, deepest first."""
    d, missing = folder.absolute(), []
    while not os.path.lexists(d) and d != d.parent:
        missing.append(d)
        d = d.parent
    return d, missing


def check_output_path(path: str | os.PathLike, allowed_suffixes: tuple[str, ...], what: str) -> Path:
    """Validate an output path: its suffix, and that its directory exists or can be made and
    takes files. The directory is not made here (``OutputSet.temp`` makes it).

    Raises:
        WrinklesInputError: the suffix is not one of ``allowed_suffixes``, the path is a
            directory, or its directory cannot be made or written.
    """
    p = Path(path)
    if p.suffix.lower() not in allowed_suffixes:
        raise WrinklesInputError(
            f"{what} must end in one of {', '.join(allowed_suffixes)} (got '{p.suffix or 'no suffix'}')",
            path=p)
    try:
        if p.is_dir():
            raise WrinklesInputError(f"{what} is a directory", path=p)
        # nothing is created yet (``OutputSet.temp`` makes the directory when the job writes), so
        # a run that fails before its outputs leaves no empty folder; but an unwritable place fails
        # now, not after the job: a probe file in the nearest directory that exists
        existing, _ = _missing_folders(p.parent)
        if not existing.is_dir():  # a file, or a link to nowhere
            raise WrinklesInputError(f"cannot create the output directory: {existing} is not a directory",
                                     path=p.parent)
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as e:  # a folder on the way that cannot be searched, or the probe refused
        raise WrinklesInputError(f"cannot write there: {e.strerror}", path=p) from e
    return p


@contextlib.contextmanager
def _signals_held():
    """SIGINT and SIGTERM held back (delivered on exit) in the main thread, where a handler can
    interrupt; elsewhere nothing."""
    held = (signal.SIGINT, signal.SIGTERM)
    main = threading.current_thread() is threading.main_thread()
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held) if main else None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


class OutputSet:
    """A set of output files committed together.

    Use::

        with OutputSet() as out:
            write_usd(out.temp(usd_path), ...)
            write_video(out.temp(mp4_path), ...)
        # all renamed into place here, or none on error
    """

    def __init__(self) -> None:
        self._pending: list[tuple[Path, Path]] = []
        self._made: list[Path] = []  # directories temp() made, removed again on abort if empty

    def temp(self, final: str | os.PathLike) -> Path:
        """A temporary path beside ``final`` with the same suffix (writers pick formats by it);
        ``final``'s directory is made here if it does not exist."""
        final = Path(final)
        _, missing = _missing_folders(final.parent)
        try:
            final.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise WrinklesInputError(f"cannot create the output directory: {e.strerror}",
                                     path=final.parent) from e
        self._made.extend(missing)
        tmp = final.with_name(f".{final.stem}.partial-{uuid.uuid4().hex[:8]}{final.suffix}")
        self._pending.append((tmp, final))
        return tmp

    def commit(self) -> list[Path]:
        done = []
        for tmp, final in self._pending:
            if not tmp.exists():
                raise RuntimeError(f"{final}: the writer produced no file")
        with _signals_held():  # a Ctrl-C or SIGTERM between two renames would mix old and new
            for tmp, final in self._pending:
                os.replace(tmp, final)
                done.append(final)
        self._pending.clear()
        return done

    def abort(self) -> None:
        for tmp, _ in self._pending:
            try:
                tmp.unlink()
            except FileNotFoundError:
                pass
        self._pending.clear()
        for d in sorted(set(self._made), key=lambda q: len(q.parts), reverse=True):  # deepest first
            try:
                d.rmdir()  # only if empty: a directory someone else wrote into stays
            except OSError:
                pass
        self._made.clear()

    def __enter__(self) -> OutputSet:
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            try:
                self.commit()
            except BaseException:
                self.abort()
                raise
        else:
            self.abort()
        return False


@dataclass(frozen=True)
class StageOutputs:
    """The files of a command that writes a USD stage, checked before the job runs.

    Attributes:
        usd: the stage (``--out``).
        sidecar: the JSON record beside it (``<stem><suffix>``), or None.
        preview: the preview video (``--preview``), or None.
        sheet: the contact sheet PNG (``--sheet``), or None.
    """

    usd: Path
    sidecar: Path | None
    preview: Path | None
    sheet: Path | None

    def written(self) -> list[Path]:
        """The files the command writes, in the order it reports them."""
        return [p for p in (self.usd, self.sidecar, self.preview, self.sheet) if p]


def check_stage_outputs(out: str, preview: str | None, sheet: str | None, *,
                        sidecar: str | None = None) -> StageOutputs:
    """``--out``, ``--preview`` and ``--sheet`` checked (``check_output_path``) in that order;
    ``sidecar`` is the suffix of the JSON record beside the stage (e.g. ``".quality.json"``)."""
    usd = check_output_path(out, USD_SUFFIXES, "--out")
    return StageOutputs(
        usd=usd,
        sidecar=usd.with_name(usd.stem + sidecar) if sidecar else None,
        preview=check_output_path(preview, PREVIEW_SUFFIXES, "--preview") if preview else None,
        sheet=check_output_path(sheet, (".png",), "--sheet") if sheet else None,
    )


def write_previews(outputs: OutputSet, paths: StageOutputs, meshes: Callable[[], list], *,
                   num_frames: int, fps: float, camera: str, quiet: bool) -> None:
    """The preview video and contact sheet ``paths`` name, if any, of the meshes ``meshes()``
    makes (called only when there is one to write)."""
    if not (paths.preview or paths.sheet):
        return
    from pipelines.preview import contact_sheet_frames, write_contact_sheet, write_video

    drawn = meshes()
    if paths.preview:
        with progress_bar(num_frames, "preview", quiet=quiet) as advance:
            write_video(drawn, outputs.temp(paths.preview), fps=fps, camera=camera, progress=advance)
    if paths.sheet:
        with progress_bar(len(contact_sheet_frames(num_frames, 8)), "contact sheet", quiet=quiet) as advance:
            write_contact_sheet(drawn, outputs.temp(paths.sheet), fps=fps, camera=camera, progress=advance)


def add_body_points_option(parser: argparse.ArgumentParser) -> None:
    """``--body-points``: the body as a point cache instead of a UsdSkel rig (``stage_rig``)."""
    parser.add_argument("--body-points", action="store_true", help=BODY_POINTS_HELP)


def stage_rig(body: BodyModel, betas: np.ndarray | None, frames: BodyFrames, *,
              points: bool) -> BodyRig | None:
    """The rig ``usd_io.write_stage(rig=...)`` writes the body with: ``body`` shaped by
    ``betas`` (the frames' own), or None for a point cache: when ``points`` (``--body-points``)
    or when no one rig poses ``frames`` (a body whose shape changes during the clip, as the
    settle that ``simulate --keep-prelude`` keeps morphs the garment's body into the job's)."""
    if points:
        return None
    from usd_io.skel import rig_fits

    rig = body.rig(betas)
    return rig if rig_fits(rig, frames) else None


def command_line() -> str:
    """The command as typed, for the record kept beside the outputs."""
    return "wrinkles " + " ".join(shlex.quote(a) for a in sys.argv[1:])
