"""``adclient files``: a trial's files on disk, its robot's URDF and whatever its worker
uploaded (``robot.png``, ``curve.json``, ``checkpoint.zip``...); ``best --save`` uses it
for the best design.

An artifact's name comes from whoever uploaded it (or from a server that may not be the
one you think): a name is written only as one plain file name inside the folder, as the
server's own rule for names has it (no separator, no leading dot), never a path; a file
already there is kept unless ``--force``; nothing is written unless every download
succeeded.
"""

from __future__ import annotations

import os
import re
import tempfile
from dataclasses import dataclass
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from adclient.cli.common import (
    EXIT_USAGE,
    app,
    fail,
    friendly,
    get_settings,
    stderr_console,
    stdout_console,
    trial_scope,
)
from adclient.client import Client
from adclient.errors import Invalid, NotFound, quoted
from adclient.schemas import NAME_PATTERN, Trial

PLAIN_NAME = re.compile(NAME_PATTERN.removeprefix("^").removesuffix("$"))
"""An artifact name the server accepts: letters, digits, ``_``, ``.`` and ``-``, not
first a dot; matched whole (``fullmatch``: a ``$`` would let a trailing newline by)."""
URDF_NAME = "robot.urdf"
"""The name a worker uploads its robot's URDF as, and the name the URDF of a trial no
worker ran (the server writes it from the trial's design or template) is saved as."""
FORCE_OPTION = typer.Option(False, "--force", help="Overwrite files already there.")


@dataclass
class TrialFile:
    name: str
    data: bytes


def _size_text(size: int) -> str:
    if size < 1000:
        return f"{size} bytes"
    return f"{size / 1000:.1f} kB" if size < 1_000_000 else f"{size / 1_000_000:.1f} MB"


def _download(client: Client, trial: Trial, err: Console) -> tuple[list[TrialFile], list[str]]:
    """The trial's files, and the artifact names not saved: refused as file names, or
    gone since they were listed."""
    files: list[TrialFile] = []
    refused: list[str] = []
    taken: set[str] = set()
    for artifact in client.artifacts(trial.id):
        name = artifact.name
        if not PLAIN_NAME.fullmatch(name) or name.casefold() in taken:
            refused.append(name)  # a path, a dot file, or a second file of one name
            continue
        taken.add(name.casefold())
        try:
            files.append(TrialFile(name, client.get_artifact(trial.id, name)))
        except NotFound:  # gone since the listing (its trial's study deleted, say)
            refused.append(name)
    space = client.study_info(trial.study_id).space
    if URDF_NAME not in taken and space.type in ("design", "template"):
        try:
            files.append(TrialFile(URDF_NAME, client.trial_urdf(trial.id).encode("utf-8")))
        except Invalid as exc:  # a template whose params do not expand: the rest still
            err.print(f"no {URDF_NAME}: {escape(exc.message)}", soft_wrap=True)
    return files, refused


def _write(target: Path, data: bytes, *, force: bool) -> None:
    """Write ``target`` (a new file; with ``force`` a file or link there is replaced, never
    followed)."""
    if not force:
        descriptor = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        with os.fdopen(descriptor, "wb") as stream:
            stream.write(data)
        return
    descriptor, temporary = tempfile.mkstemp(dir=target.parent, prefix=".adclient-")
    try:
        with os.fdopen(descriptor, "wb") as stream:
            stream.write(data)
        os.chmod(temporary, 0o666 & ~_umask())
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def save_trial_files(
    client: Client, trial: Trial, folder: Path, *, force: bool, out: Console
) -> None:
    """Download the trial's files into ``folder`` (made if missing) and say what was
    written on ``out``; fail naming the files already there (without ``force``), or the
    artifacts whose names are not file names (after writing the others)."""
    if folder.exists() and not folder.is_dir():
        fail(f"{folder} is not a folder", EXIT_USAGE)
    err = stderr_console()
    files, refused = _download(client, trial, err)
    if not files and not refused:
        fail(f"trial {trial.id} has no files (no robot, and its worker uploaded none)")
    there = [file.name for file in files if os.path.lexists(folder / file.name)]
    if there and not force:
        names = ", ".join(there)
        fail(f"{folder} already has {names}: give --force to overwrite (nothing written)")
    folder.mkdir(parents=True, exist_ok=True)
    for file in files:
        target = folder / file.name  # a plain name (PLAIN_NAME): inside the folder
        try:
            _write(target, file.data, force=force)
        except OSError as exc:
            fail(f"cannot write {target}: {exc.strerror or exc}")
        out.print(f"wrote {escape(str(target))} ({_size_text(len(file.data))})", soft_wrap=True)
    out.print(f"trial {trial.id}: {len(files)} files in {escape(str(folder))}", soft_wrap=True)
    if refused:
        names = ", ".join(quoted(name) for name in refused)
        fail(f"not written: {names} (not a plain file name, a second file of one name, or gone)")


@app.command()
@friendly
def files(
    ctx: typer.Context,
    trial_id: int = typer.Argument(..., metavar="TRIAL"),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="The folder to write to (default: trial-TRIAL).", file_okay=False
    ),
    force: bool = FORCE_OPTION,
) -> None:
    """Download a trial's files: its URDF, images, curve, checkpoint.

    The robot's URDF and whatever its worker uploaded (robot.png, curve.json,
    checkpoint.zip...), each a file in the folder; prints what was written."""
    folder = out if out is not None else Path(f"trial-{trial_id}")
    with get_settings(ctx).client() as client, trial_scope(trial_id):
        trial = client.get_trial(trial_id)
        save_trial_files(client, trial, folder, force=force, out=stdout_console())
