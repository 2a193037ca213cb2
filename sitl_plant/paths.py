"""Where both programs write: one rule for every output file and run folder.

The rule: **missing parent folders are created** (as ``mkdir -p`` would, and as a run folder
always was); anything that still stands in the way — a parent that is a file, a folder where a
file should go, a file where a folder should go, no permission — is an ``OutputPathError``
naming the option and the path, which the command lines print as one line.
"""

from __future__ import annotations

from pathlib import Path

from sitl_plant.errors import UserError


class OutputPathError(UserError, OSError):
    """An output file or folder cannot be created where the user asked for it."""


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def output_file(path: str | Path, what: str) -> Path:
    """Make ``path`` ready to be written as a file: its missing parent folders are created.

    Parameters
    ----------
    path : str or Path
        The file to be written (it may exist: it will be replaced).
    what : str
        Who asked for it, for the message: ``"--log"``, ``"output"``.

    Returns
    -------
    Path
        ``path`` as a ``Path``.

    Raises
    ------
    OutputPathError
        ``path`` is a folder, or its parent folder cannot be created.
    """
    path = Path(path)
    if path.is_dir():
        raise OutputPathError(f"{what} {path}: is a folder; give a file name")
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputPathError(f"{what} {path}: cannot create the folder {parent}: a file of that name is in the way") from None
    except OSError as exc:
        raise OutputPathError(f"{what} {path}: cannot create the folder {parent}: {_reason(exc)}") from None
    return path


def output_folder(path: str | Path, what: str) -> Path:
    """Create the folder ``path`` (and its missing parents) if it does not exist.

    Raises
    ------
    OutputPathError
        ``path`` or one of its parents is a file, or the folder cannot be created.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputPathError(f"{what} {path}: is a file, not a folder") from None
    except NotADirectoryError:
        raise OutputPathError(f"{what} {path}: cannot create it: a file stands where one of its parent folders should be") from None
    except OSError as exc:
        raise OutputPathError(f"{what} {path}: cannot create it: {_reason(exc)}") from None
    return path
