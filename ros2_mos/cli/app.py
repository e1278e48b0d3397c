"""The typer application every command module registers on, and the error boundary."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import NoReturn, Sequence

import typer

from ros2_mos.core.errors import MosError

app = typer.Typer(
    name="ros2-mos",
    help="Online moving object segmentation for rotating 3D LiDAR (Chen et al., RA-L 2021).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


#: The node's ROS params file: one option, one name, in every command that runs the pipeline.
PARAMS_OPTION = typer.Option(None, "--params", help="The node's ROS params file (config/mos.yaml; `ros2-mos params` "
                                                    "prints one); default: built-in defaults")


def fail(message: str, code: int = 1) -> NoReturn:
    """Print a one-line error to stderr and exit: the only place the CLI chooses exit codes."""
    typer.secho(f"error: {message}", err=True, fg=typer.colors.RED)
    raise typer.Exit(code)


def check_choice(value: str, choices: Sequence[str], option: str) -> None:
    """Fail now, in one line naming ``option``, where ``value`` is not one of ``choices``."""
    if value not in choices:
        fail(f"unknown {option} {value!r}: use one of {', '.join(choices)}")


def check_output(path: Path, option: str, folder: bool = False) -> None:
    """Fail now, not after the work, when ``path`` (a file, or with ``folder`` a folder) cannot be written there.

    The nearest existing ancestor must be a writable folder; an existing ``path`` must be of the right kind.
    """
    path = Path(path)
    if path.exists() and path.is_dir() != folder:
        fail(f"{option} {path} is {'a file' if folder else 'a folder'}; expected {'a folder' if folder else 'a file'}")
    parent = path if folder and path.exists() else path.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        fail(f"{option} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        fail(f"{option} {path}: cannot write into {parent} (permission denied)")


def main() -> None:
    """Console-script entry: typed library errors become one-line messages and exit code 1."""
    # Imported here so that `ros2_mos.cli.app` alone does not pull every command module.
    import ros2_mos.cli  # noqa: F401

    try:
        app()
    except MosError as exc:
        typer.secho(f"error: {exc}", err=True, fg=typer.colors.RED)
        sys.exit(1)
    except OSError as exc:  # a write the library did not wrap (a full disk, a vanished folder): one line all the same
        where = f"{exc.filename}: " if exc.filename else ""
        typer.secho(f"error: {where}{exc.strerror or exc}", err=True, fg=typer.colors.RED)
        sys.exit(1)
