"""Load the reference implementation (SimKit + the tutorial's ModalMuscle class) for benchmarks.

SimKit (PyPI, the ``bench`` extra) provides the functions; the ModalMuscle
class that assembles them lives only in the tutorial, which ships with this
project's reference material (``../shared/reference/modal_muscles_tutorial.txt``).
It is read from there and executed at run time, unchanged, so the benchmarks
time exactly the reference's code; none of it is copied into this project.
"""

from __future__ import annotations

import os
import warnings

import numpy as np

DEFAULT_TUTORIAL = os.path.join(
    os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "reference", "modal_muscles_tutorial.txt"
)


def available(tutorial: str = DEFAULT_TUTORIAL) -> str | None:
    """Why the reference cannot be loaded, or None when it can."""
    try:
        import simkit  # noqa: F401
    except ImportError:
        return "SimKit is not installed (pip install -e '.[bench]')"
    if not os.path.isfile(tutorial):
        return f"the tutorial is not at {tutorial}"
    return None


def load_modal_muscle(tutorial: str = DEFAULT_TUTORIAL):
    """The tutorial's ModalMuscle class, executed from the tutorial text."""
    warnings.filterwarnings("ignore")
    np.seterr(all="ignore")
    text = open(tutorial, encoding="utf-8").read()
    start = text.index("class ModalMuscle:")
    end = text.index("Building the reduced model")
    source = text[start:end]
    namespace = {}
    exec(  # noqa: S102 - the reference implementation, run as published
        "import numpy as np\nimport scipy as sp\nimport scipy.sparse as sps\nimport simkit as sk\n"
        "from simkit.clustered_plastic_stretch_tensor import clustered_plastic_stretch_tensor\n"
        "from simkit.fast_sandwich_transform_clustered import fast_sandwich_transform_clustered\n"
        "from simkit.solvers import block_coord\n" + source,
        namespace,
    )
    return namespace["ModalMuscle"]


def oriented(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Cells with a positive orientation (SimKit's volumes are signed)."""
    cells = np.array(cells, copy=True)
    e = points[cells[:, 1:]] - points[cells[:, :1]]
    if cells.shape[1] == 4:
        negative = np.linalg.det(e) < 0
    else:
        negative = e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0] < 0
    cells[negative, 0], cells[negative, 1] = cells[negative, 1], cells[negative, 0].copy()
    return cells
