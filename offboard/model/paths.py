"""Where both programs write: one rule for every output file, one for run folders.

- An **output file** (``--log``, ``--plot``, ``--output``, ``mission convert``'s output) goes into
  a folder that exists: a missing folder is refused, never created, so a typo in a path does not
  leave stray folders behind (and, run as root, ``/nonexistent/dir/x.plan`` creates nothing).
- A **run folder** (``--run-dir``) is created with its parents, as it always was
  (``runs/fly-<mission>-<time>`` from a fresh clone).

Anything in the way is an ``OutputPathError`` naming the option and the path, which the command
lines print as one line (exit 2).
"""

from __future__ import annotations

from pathlib import Path

from offboard.model.errors import UserError


class OutputPathError(UserError, OSError):
    """An output file or folder cannot be created where the user asked for it.

    ``reason`` is the message without the option and path (for callers that word their own).
    """

    def __init__(self, message: str, reason: str) -> None:
        super().__init__(message)
        self.reason = reason


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def output_file_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be written as a file (None when it can be tried)."""
    path = Path(path)
    parent = path.parent
    if path.is_dir():
        return "is a folder; give a file name"
    if parent.exists() and not parent.is_dir():
        return f"{parent} is a file, not a folder"
    if not parent.exists():
        return f"the folder {parent} does not exist (create it first: mkdir -p {parent})"
    return None


def output_file(path: str | Path, what: str) -> Path:
    """Check that ``path`` can be written as a file: its folder exists, it is not a folder.

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
        ``path`` is a folder, or its folder does not exist or is a file.
    """
    path = Path(path)
    problem = output_file_problem(path)
    if problem is not None:
        raise OutputPathError(f"{what} {path}: {problem}", problem)
    return path


def output_folder(path: str | Path, what: str) -> Path:
    """Create the run folder ``path`` (and its missing parents) if it does not exist.

    Raises
    ------
    OutputPathError
        ``path`` or one of its parents is a file, or the folder cannot be created.
    """
    path = Path(path)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        reason = "is a file, not a folder"
        raise OutputPathError(f"{what} {path}: {reason}", reason) from None
    except NotADirectoryError:
        reason = "cannot create it: a file stands where one of its parent folders should be"
        raise OutputPathError(f"{what} {path}: {reason}", reason) from None
    except OSError as exc:
        reason = f"cannot create it: {_reason(exc)}"
        raise OutputPathError(f"{what} {path}: {reason}", reason) from None
    return path
