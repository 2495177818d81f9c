"""What a run writes into its directory, and clearing an earlier run out of it.

A run directory holds the files of :func:`~skfem_modal.run.run_scene` and the
pictures of :func:`~skfem_modal.plot.render_run`, under the names below. A new
run into a directory that holds an earlier one would mix the two (stale frames
beside new ones, old pictures), so the earlier run is removed first, when
asked, and only its files: anything else in the directory is left alone.
"""

from __future__ import annotations

import os
import re

__all__ = ["RUN_FILES", "PICTURES", "FRAMES_DIR", "earlier_run", "clear_earlier_run"]

#: The files of a run (the frame series' index, tables, summary).
RUN_FILES = ("frames.pvd", "com.csv", "amplitudes.csv", "summary.json")
#: The pictures ``render`` adds.
PICTURES = ("com.png", "amplitudes.png", "first_frame.png", "last_frame.png", "animation.gif", "animation.mp4")
#: The folder of the frames, ``frame_00000.vtu`` and on.
FRAMES_DIR = "frames"

_STEMS = "|".join(re.escape(os.path.splitext(name)[0]) for name in RUN_FILES + PICTURES)
# a name of ours, or the temporary name of one being written (export.atomic_path: ".STEM.<8 random characters>.EXT")
_TOP = re.compile(rf"(?:{'|'.join(map(re.escape, RUN_FILES + PICTURES))})|\.(?:{_STEMS})\.[0-9a-f]{{8}}\.\w+")
_FRAME = re.compile(r"\.?frame_\d{5}(?:\.[0-9a-f]{8})?\.vtu")


def earlier_run(directory) -> list[str]:
    """The files an earlier run or render wrote in ``directory``.

    Parameters
    ----------
    directory : str or path-like

    Returns
    -------
    paths : list of str
        Sorted; frames inside ``frames/`` are included. Empty when the
        directory does not exist or holds nothing of a run.
    """
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        return []
    found = [os.path.join(directory, n) for n in os.listdir(directory) if _TOP.fullmatch(n)]
    frames = os.path.join(directory, FRAMES_DIR)
    if os.path.isdir(frames):
        found += [os.path.join(frames, n) for n in os.listdir(frames) if _FRAME.fullmatch(n)]
    return sorted(p for p in found if os.path.isfile(p))


def _file_in_the_way(directory: str) -> str | None:
    """The path itself or the nearest folder on its path that exists as something other than a folder, or None."""
    path = os.path.abspath(directory)
    while True:
        if os.path.exists(path):
            return None if os.path.isdir(path) else (directory if path == os.path.abspath(directory) else path)
        parent = os.path.dirname(path)
        if parent == path:
            return None
        path = parent


def clear_earlier_run(directory, overwrite: bool, *, how: str = "overwrite=True") -> int:
    """Make ``directory`` ready for a new run: refuse, or remove the earlier run's files.

    Parameters
    ----------
    directory : str or path-like
    overwrite : bool
        Remove the files of an earlier run (and ``frames/`` if that leaves it
        empty); other files stay. Without it, an earlier run is an error.
    how : str
        How the caller asks to overwrite, for the error message (e.g. the
        command-line flag).

    Returns
    -------
    removed : int
        Files removed.

    Raises
    ------
    FileExistsError
        The directory holds an earlier run and ``overwrite`` is false; the
        message says what it holds. Also when ``directory`` (or a folder on
        its path) is a file, not a folder, whatever ``overwrite``: it is never removed.
    """
    directory = os.fspath(directory)
    blocking = _file_in_the_way(directory)
    if blocking is not None:
        what = "is" if blocking == directory else f"cannot be made: {blocking!r} is"
        raise FileExistsError(
            f"the output folder {directory!r} {what} a file, not a folder: choose another output folder"
        )
    found = earlier_run(directory)
    if not found:
        return 0
    if not overwrite:
        frames = sum(os.path.basename(os.path.dirname(p)) == FRAMES_DIR for p in found)
        named = [os.path.basename(p) for p in found if os.path.dirname(p) == directory]
        raise FileExistsError(
            f"{directory!r} holds an earlier run ({', '.join(named)}{', ' if named else ''}{frames} frames); "
            f"pass {how} to replace it (only its files are removed) or choose another directory"
        )
    for path in found:
        os.remove(path)
    frames_dir = os.path.join(directory, FRAMES_DIR)
    if os.path.isdir(frames_dir) and not os.listdir(frames_dir):
        os.rmdir(frames_dir)
    return len(found)
