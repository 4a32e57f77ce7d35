"""``adclient replay TRIAL --out walk.gif``: a trial's evaluation episode as an animated GIF.

Drawn here from the trial's URDF and its worker's ``replay.json``
(:mod:`adclient.replay_gif`: NumPy and Pillow, imported only by this command), never by
a simulator: the CLI is the SDK, and the SDK imports none.
"""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape

from adclient.cli.common import app, fail, friendly, get_settings, stdout_console, trial_scope
from adclient.errors import NotFound


@app.command()
@friendly
def replay(
    ctx: typer.Context,
    trial_id: int = typer.Argument(..., metavar="TRIAL"),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="The GIF to write (default: trial-TRIAL.gif).", dir_okay=False
    ),
    speed: float = typer.Option(1.0, "--speed", min=0.05, max=20.0, help="Times real time."),
    force: bool = typer.Option(False, "--force", help="Overwrite the file if it is there."),
) -> None:
    """Write a trial's evaluation episode (its replay.json) as an animated GIF.

    The robot's collision shapes posed at each recorded control step, from a fixed
    three-quarter view, at SPEED times real time; loops."""
    target = out if out is not None else Path(f"trial-{trial_id}.gif")
    if target.exists() and not force:
        fail(f"{target} is there already (--force overwrites it)")
    with get_settings(ctx).client() as client, trial_scope(trial_id):
        trial = client.get_trial(trial_id)
        try:
            recorded = client.trial_replay(trial)
        except NotFound:
            fail(f"trial {trial_id} has no replay.json (its worker recorded no episode)")
        urdf = client.trial_urdf(trial)
    from adclient.replay_gif import replay_gif
    from adclient.urdf_model import read_urdf

    data = replay_gif(read_urdf(urdf), recorded, speed=speed)
    try:
        target.write_bytes(data)
    except OSError as exc:
        fail(f"cannot write {target}: {exc.strerror or exc}")
    seconds = (len(recorded.frames) - 1) * recorded.frame_period
    stdout_console().print(
        f"wrote {escape(str(target))} ({len(data) / 1000:.1f} kB, {seconds:.2f} s of "
        f"trial {trial.id}'s episode at {speed:g}x)",
        soft_wrap=True,
    )
