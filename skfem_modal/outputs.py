"""What a run or a study writes into its folder, and clearing an earlier one out of it.

A run directory holds the files of :func:`~skfem_modal.run.run_scene` and the
pictures of :func:`~skfem_modal.plot.render_run`, under the names below; a
study's folder the report of :func:`~skfem_modal.study.run_study`. A new run
into a folder that holds an earlier one would mix the two (stale frames
beside new ones, old pictures), so the earlier one is removed first, when
asked, and only its files: anything else in the folder is left alone. A run
and a study never share a folder.
"""

from __future__ import annotations

import os
import re

__all__ = [
    "RUN_FILES",
    "PICTURES",
    "FRAMES_DIR",
    "STUDY_FILES",
    "earlier_run",
    "earlier_study",
    "clear_earlier_run",
    "clear_earlier_study",
]

#: The files of a run (the frame series' index, tables, summary).
RUN_FILES = ("frames.pvd", "com.csv", "amplitudes.csv", "summary.json")
#: The pictures ``render`` adds.
PICTURES = ("com.png", "amplitudes.png", "first_frame.png", "last_frame.png", "animation.gif", "animation.mp4")
#: The folder of the frames, ``frame_00000.vtu`` and on.
FRAMES_DIR = "frames"
#: The files of a study (``skfem-modal study``).
STUDY_FILES = ("study.csv", "modal.csv", "study.json", "study.md", "pareto.png")


def _names(files) -> re.Pattern:
    """A name of ``files``, or the temporary name of one being written (export.atomic_path: ".STEM.<8 hex>.EXT")."""
    stems = "|".join(re.escape(os.path.splitext(name)[0]) for name in files)
    return re.compile(rf"(?:{'|'.join(map(re.escape, files))})|\.(?:{stems})\.[0-9a-f]{{8}}\.\w+")


_TOP = _names(RUN_FILES + PICTURES)
_STUDY = _names(STUDY_FILES)
_FRAME = re.compile(r"\.?frame_\d{5}(?:\.[0-9a-f]{8})?\.vtu")


def _found(directory: str, names: re.Pattern) -> list[str]:
    """The files directly in ``directory`` whose names match."""
    if not os.path.isdir(directory):
        return []
    return [os.path.join(directory, n) for n in os.listdir(directory) if names.fullmatch(n)]


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
    found = _found(directory, _TOP)
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


def earlier_study(directory) -> list[str]:
    """The files an earlier study wrote in ``directory`` (sorted; empty when there are none)."""
    return sorted(p for p in _found(os.fspath(directory), _STUDY) if os.path.isfile(p))


def _listed(directory: str, found: list[str]) -> str:
    """What ``found`` holds, in words: the names in ``directory`` and how many frames."""
    frames = sum(os.path.basename(os.path.dirname(p)) == FRAMES_DIR for p in found)
    named = [os.path.basename(p) for p in found if os.path.dirname(p) == directory]
    return ", ".join(named + ([f"{frames} frames"] if frames else []))


def _clear(directory, overwrite: bool, how: str, own: str, found: list[str], other: str, others: list[str]) -> int:
    """Refuse, or remove ``found`` (the earlier ``own`` output); ``others`` (another kind, ``other``) always refuses."""
    blocking = _file_in_the_way(directory)
    if blocking is not None:
        what = "is" if blocking == directory else f"cannot be made: {blocking!r} is"
        raise FileExistsError(
            f"the output folder {directory!r} {what} a file, not a folder: choose another output folder"
        )
    if others:
        raise FileExistsError(
            f"{directory!r} holds a {other} ({_listed(directory, others)}): a {own} there would mix with it; "
            "choose another directory"
        )
    if not found:
        return 0
    if not overwrite:
        raise FileExistsError(
            f"{directory!r} holds an earlier {own} ({_listed(directory, found)}); "
            f"pass {how} to replace it (only its files are removed) or choose another directory"
        )
    for path in found:
        os.remove(path)
    frames_dir = os.path.join(directory, FRAMES_DIR)
    if os.path.isdir(frames_dir) and not os.listdir(frames_dir):
        os.rmdir(frames_dir)
    return len(found)


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
        message says what it holds. Also, whatever ``overwrite``, when it
        holds a study, or when ``directory`` (or a folder on its path) is a
        file, not a folder: neither is ever removed.
    """
    directory = os.fspath(directory)
    return _clear(directory, overwrite, how, "run", earlier_run(directory), "study", earlier_study(directory))


def clear_earlier_study(directory, overwrite: bool, *, how: str = "overwrite=True") -> int:
    """Make ``directory`` ready for a new study: refuse, or remove the earlier study's files.

    As :func:`clear_earlier_run`, for :data:`STUDY_FILES`; a folder holding a
    run is refused whatever ``overwrite``.
    """
    directory = os.fspath(directory)
    return _clear(directory, overwrite, how, "study", earlier_study(directory), "run", earlier_run(directory))
