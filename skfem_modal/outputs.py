"""What a run, a study or a gait search writes into its folder, and clearing an earlier one out of it.

A run directory holds the files of :func:`~skfem_modal.run.run_scene` and the
pictures of :func:`~skfem_modal.plot.render_run`, under the names below; a
study's folder the report of :func:`~skfem_modal.study.run_study`; a search's
folder the checkpoint and files of :func:`~skfem_modal.optimize.run_search`
(and ``transfer.csv`` beside them). A new run into a folder that holds an
earlier one would mix the two (stale frames beside new ones, old pictures),
so the earlier one is removed first, when asked, and only its files:
anything else in the folder is left alone. A run, a study and a search never
share a folder.
"""

from __future__ import annotations

import os
import re
import tempfile

from .values import checked_flag

__all__ = [
    "OutputError",
    "named",
    "RUN_FILES",
    "PICTURES",
    "FRAMES_DIR",
    "STUDY_FILES",
    "SEARCH_FILES",
    "TRANSFER_FILE",
    "earlier_run",
    "earlier_study",
    "earlier_search",
    "check_output_folder",
    "check_writable",
    "check_output_file",
    "listed",
    "clear_earlier_run",
    "clear_earlier_study",
    "made_folder",
    "remove_if_empty",
]

#: The files of a run (the frame series' index, tables, summary).
RUN_FILES = ("frames.pvd", "com.csv", "amplitudes.csv", "summary.json")
#: The pictures ``render`` adds.
PICTURES = ("com.png", "amplitudes.png", "first_frame.png", "last_frame.png", "animation.gif", "animation.mp4")
#: The folder of the frames, ``frame_00000.vtu`` and on.
FRAMES_DIR = "frames"
#: The files of a study (``skfem-modal study``).
STUDY_FILES = ("study.csv", "modal.csv", "study.json", "study.md", "pareto.png")
#: What ``skfem-modal transfer`` writes beside a search's files (a replay of its best gait).
TRANSFER_FILE = "transfer.csv"
#: The files of a gait search (``skfem-modal optimize``), and ``skfem-modal transfer``'s beside them.
SEARCH_FILES = ("checkpoint.pkl", "history.csv", "best_gait.toml", "fitness.png", TRANSFER_FILE)


class OutputError(OSError):
    """An output could not be written while a command ran (a disk full, a folder removed): the message names it."""


def named(err: OSError, path) -> OSError:
    """``err`` naming ``path`` if it names no file (a write that fails names none).

    Parameters
    ----------
    err : OSError
    path : str or path-like
        The file the failed operation was for.

    Returns
    -------
    OSError
        ``err`` itself if it names a file, else one of its type, errno and message naming ``path``.

    Examples
    --------
    >>> str(named(OSError(28, "No space left on device"), "frames/frame_00003.vtu"))
    "[Errno 28] No space left on device: 'frames/frame_00003.vtu'"
    """
    return err if err.filename is not None else type(err)(err.errno, err.strerror, os.fspath(path))


def _names(files) -> re.Pattern:
    """A name of ``files``, or the temporary name of one being written (export.atomic_path: ".STEM.<8 hex>.EXT")."""
    stems = "|".join(re.escape(os.path.splitext(name)[0]) for name in files)
    return re.compile(rf"(?:{'|'.join(map(re.escape, files))})|\.(?:{stems})\.[0-9a-f]{{8}}\.\w+")


_TOP = _names(RUN_FILES + PICTURES)
_STUDY = _names(STUDY_FILES)
_SEARCH = _names(SEARCH_FILES)
_FRAME = re.compile(r"\.?frame_\d{5,}(?:\.[0-9a-f]{8})?\.vtu")


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


def check_output_file(path, option: str, suffix: str, example: str) -> None:
    """Refuse, before any work, an output file that could not be written where it is asked to.

    Parameters
    ----------
    path : str or path-like
    option : str
        What names it for the user (``--out``, ``--screenshot``).
    suffix : str
        The file's required ending (``.vtu``, ``.png``).
    example : str
        A file name to suggest inside a folder given instead of a file.

    Raises
    ------
    ValueError
        A folder, another suffix, or a folder that refuses a new file (tried: root passes the
        permissions of a read-only folder, and /proc refuses all the same).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise ValueError(f"{option} {path} is a directory; give a file name, e.g. {os.path.join(path, example)}")
    if not path.lower().endswith(suffix):
        raise ValueError(f"{option} {path}: expected a {suffix} file")
    folder = os.path.dirname(os.path.abspath(path))
    while not os.path.exists(folder):  # made when the file is written
        folder = os.path.dirname(folder)
    try:
        if not os.path.isdir(folder):
            raise NotADirectoryError
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError:
        raise ValueError(f"{option} {path}: {folder} is not a folder this user can write in") from None


def check_writable(directory, what: str = "the output folder", advice: str = "choose another output folder") -> None:
    """Raise PermissionError, naming the folder, if a folder cannot be made where it is (or in it).

    Tried, not read off the permissions (root passes those, and /proc refuses all the
    same): an empty folder is made and removed. Found at the end, a search's output
    folder was refused after its precompute, the error naming only the path.

    Parameters
    ----------
    directory : str or path-like
        The folder (or where it would be made: the nearest folder of its path that exists is tried).
    what : str
        What the error calls it.
    advice : str
        What the error says to do.

    Raises
    ------
    PermissionError
        Nothing can be written there.
    """
    directory = os.fspath(directory)
    existing = os.path.abspath(directory)
    while not os.path.exists(existing):
        existing = os.path.dirname(existing)
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".skfem_modal-", dir=existing))
    except OSError as err:
        raise PermissionError(
            f"{what} {directory!r} cannot be written: {existing!r} refuses a new folder ({err.strerror}); {advice}"
        ) from None


def made_folder(directory: str) -> str | None:
    """Make ``directory`` (and its parents) for a study's or a search's files: the topmost folder made, or None.

    What the work made and then left empty (it failed before writing) is for :func:`remove_if_empty`.
    """
    top, existing = None, os.path.abspath(directory)
    while not os.path.exists(existing):
        top, existing = existing, os.path.dirname(existing)
    os.makedirs(directory, exist_ok=True)
    return top


def remove_if_empty(directory: str, made: str | None) -> None:
    """After work that failed: remove ``directory`` and the parents :func:`made_folder` ``made`` for it, if empty.

    A search that failed in its first generation left an empty folder behind, to be mistaken for a result.
    """
    if made is None:
        return
    folder = os.path.abspath(directory)
    while True:
        try:
            os.rmdir(folder)  # refuses a folder that holds anything
        except OSError:
            return
        if folder == made or os.path.dirname(folder) == folder:
            return
        folder = os.path.dirname(folder)


def earlier_study(directory) -> list[str]:
    """The files an earlier study wrote in ``directory`` (sorted; empty when there are none)."""
    return sorted(p for p in _found(os.fspath(directory), _STUDY) if os.path.isfile(p))


def earlier_search(directory) -> list[str]:
    """The files an earlier gait search (or its transfer) wrote in ``directory`` (sorted; empty when none)."""
    return sorted(p for p in _found(os.fspath(directory), _SEARCH) if os.path.isfile(p))


#: Each kind of output folder, and how to find what an earlier one of that kind wrote.
_KINDS = {"run": earlier_run, "study": earlier_study, "search": earlier_search}


def listed(directory: str, found: list[str]) -> str:
    """What ``found`` holds, in words: the names in ``directory`` and how many frames."""
    frames = sum(os.path.basename(os.path.dirname(p)) == FRAMES_DIR for p in found)
    named = [os.path.basename(p) for p in found if os.path.dirname(p) == directory]
    return ", ".join(named + ([f"{frames} frames"] if frames else []))


def check_output_folder(directory, kind: str) -> list[str]:
    """Refuse an output folder that would mix outputs; the files of an earlier output of this kind in it.

    Parameters
    ----------
    directory : str or path-like
    kind : {"run", "study", "search"}

    Returns
    -------
    found : list of str
        What an earlier ``kind`` wrote there (empty: nothing).

    Raises
    ------
    ValueError
        ``directory`` is empty (or blank).
    FileExistsError
        ``directory`` (or a folder on its path) is a file, or it holds
        another kind's output: a run, a study and a search never share a folder;
        or (a run) it holds a file named ``frames``, where a run writes its frames.
    PermissionError
        Nothing can be written there (a folder made in it, or in the nearest
        folder of its path that exists, is refused).
    """
    directory = os.fspath(directory)
    if not directory.strip():  # (the current folder's files would be written, then "No such file" after the work)
        raise ValueError(f"the output folder {directory!r} has no name: give a folder's name")
    blocking = _file_in_the_way(directory)
    if blocking is not None:
        what = "is" if blocking == directory else f"cannot be made: {blocking!r} is"
        raise FileExistsError(
            f"the output folder {directory!r} {what} a file, not a folder: choose another output folder"
        )
    check_writable(directory)
    frames = os.path.join(directory, FRAMES_DIR)
    if kind == "run" and os.path.exists(frames) and not os.path.isdir(frames):  # (a run writes its frames there)
        raise FileExistsError(
            f"the output folder {directory!r} holds a file named {FRAMES_DIR!r}, where a run writes its frames: "
            "move it, or choose another output folder"
        )
    if kind == "run" and os.path.isdir(frames):  # before anything is removed or run: a frames/ made read-only
        check_writable(frames, "the output folder's frames")
    for other, earlier in _KINDS.items():
        others = earlier(directory) if other != kind else []
        if others:
            raise FileExistsError(
                f"{directory!r} holds a {other} ({listed(directory, others)}): a {kind} there would mix with it; "
                "choose another directory"
            )
    return _KINDS[kind](directory)


def _clear(directory: str, overwrite: bool, how: str, own: str) -> int:
    """Refuse (:func:`check_output_folder`), or remove the earlier ``own`` output's files."""
    overwrite = checked_flag(overwrite, "overwrite")  # ("no" is true: it removed an earlier run's files)
    found = check_output_folder(directory, own)
    if not found:
        return 0
    if not overwrite:
        raise FileExistsError(
            f"{directory!r} holds an earlier {own} ({listed(directory, found)}); "
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
        holds a study or a search, or when ``directory`` (or a folder on its
        path) is a file, not a folder: none is ever removed.
    """
    return _clear(os.fspath(directory), overwrite, how, "run")


def clear_earlier_study(directory, overwrite: bool, *, how: str = "overwrite=True") -> int:
    """Make ``directory`` ready for a new study: refuse, or remove the earlier study's files.

    As :func:`clear_earlier_run`, for :data:`STUDY_FILES`; a folder holding a
    run or a search is refused whatever ``overwrite``.

    Parameters
    ----------
    directory : str or path-like
    overwrite : bool
        Remove the files of an earlier study; other files stay. Without it, an earlier study is an error.
    how : str
        How the caller asks to overwrite, for the error message (e.g. the command-line flag).

    Returns
    -------
    removed : int
        Files removed.

    Raises
    ------
    FileExistsError
        The directory holds an earlier study and ``overwrite`` is false; or, whatever ``overwrite``, it
        holds a run or a search, or ``directory`` (or a folder on its path) is a file.
    PermissionError
        Nothing can be written there.
    """
    return _clear(os.fspath(directory), overwrite, how, "study")
