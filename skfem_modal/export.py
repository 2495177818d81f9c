"""ParaView / VTK output: ``.vtu`` files and ``.pvd`` time series.

Points are always written in 3D (a 2D mesh gets z = 0) and vector fields as
3-component arrays, which is what ParaView's *Warp By Vector* expects. Every
file is written to a temporary name beside its target and renamed into place,
so an interrupted write never leaves a half-written file behind.

The ``.vtu`` files are VTK XML, binary and zlib-compressed in 32 KiB blocks
(the layout meshio writes and reads, and ParaView reads), written here
directly: a series' constant parts (connectivity, offsets, cell types, cell
data) are encoded once (:class:`VtuPiece`), and each frame compresses only
its points and point data, at zlib's fastest level. meshio, writing every
part of every frame at its default level, took 260 ms a frame of the seal's
38689 tetrahedra, ten times the simulation's own time in a run.
"""

from __future__ import annotations

import base64
import contextlib
import math
import os
import secrets
import sys
import zlib

import numpy as np

from .fem import scalar_basis
from .mesh import _signed_measures, check_mesh
from .outputs import named
from .values import is_real, is_whole

__all__ = [
    "pad3",
    "vtk_cells",
    "VtuPiece",
    "write_vtu",
    "export_modes",
    "atomic_path",
    "written_whole",
    "FrameWriter",
]


def pad3(x: np.ndarray) -> np.ndarray:
    """Pad positions or vectors of shape (n, 2) to (n, 3) with zeros.

    Parameters
    ----------
    x : ndarray, shape (n, 2) or (n, 3)

    Returns
    -------
    x3 : ndarray, shape (n, 3)
    """
    x = np.asarray(x, dtype=np.float64)
    if x.shape[1] == 3:
        return x
    return np.hstack([x, np.zeros((x.shape[0], 3 - x.shape[1]))])


# VTK's quadratic cells list the corners, then these corner pairs' midpoints
_VTK_QUADRATIC_EDGES = {
    2: [(0, 1), (1, 2), (2, 0)],
    3: [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3)],
}


def vtk_cells(mesh, element: str = "P1"):
    """Cells of ``mesh`` in meshio/VTK form, every one positively oriented.

    VTK takes a cell's vertex order as its orientation: a tetrahedron is
    positive when its fourth vertex lies on the side its first three see
    counter-clockwise, a triangle when its vertices go counter-clockwise
    (seen from +z). scikit-fem sorts each element's vertex indices, which
    turns about half of them inside out, and ParaView's *Integrate
    Variables* (or pyvista's ``volume``) then sums to about zero. Here the
    first two corners of each negative element are swapped (and, for
    quadratic cells, the edge nodes follow); ``mesh`` itself is not changed,
    and cells already positive keep their order.

    Parameters
    ----------
    mesh : skfem.MeshTri or skfem.MeshTet
    element : {"P1", "P2"}
        P2 gives quadratic cells (``triangle6`` / ``tetra10``) over the P2
        nodes, with the node order VTK expects.

    Returns
    -------
    cell_type : str
    cells : ndarray of int, shape (nT, nodes_per_cell)
    """
    dim = mesh.p.shape[0]
    inside_out = _signed_measures(mesh.p, mesh.t) < 0.0  # (nT,)
    if element == "P1":
        cells = np.array(mesh.t.T)
        cells[inside_out, :2] = cells[inside_out, 1::-1]
        return ("triangle" if dim == 2 else "tetra"), cells
    basis = scalar_basis(mesh, element)
    dofs = np.array(basis.element_dofs)  # (nloc, nT): corners first, then edge nodes
    dofs[:2, inside_out] = dofs[1::-1, inside_out]
    locs = basis.doflocs[:, dofs]  # (dim, nloc, nT)
    corners = dofs[: dim + 1]
    edge_nodes = dofs[dim + 1 :]
    columns = [c for c in corners]
    for a, b in _VTK_QUADRATIC_EDGES[dim]:
        mid = (locs[:, a] + locs[:, b]) / 2.0  # (dim, nT)
        dist = ((locs[:, dim + 1 :] - mid[:, None, :]) ** 2).sum(axis=0)  # (n_edge_nodes, nT)
        pick = np.argmin(dist, axis=0)
        columns.append(edge_nodes[pick, np.arange(dofs.shape[1])])
    return ("triangle6" if dim == 2 else "tetra10"), np.stack(columns, axis=1)


def atomic_path(path: str | os.PathLike):
    """A new, empty temporary file beside ``path``; rename it onto ``path`` when complete.

    Created with the permissions of any new file (``0o666`` less the umask),
    so the renamed file is readable as the user expects.

    Returns
    -------
    tmp : str
        Same directory and extension as ``path``, a hidden name.
    """
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    stem, ext = os.path.splitext(os.path.basename(path))
    while True:
        tmp = os.path.join(directory, f".{stem}.{secrets.token_hex(4)}{ext}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
        except FileExistsError:
            continue
        except OSError as error:  # named as the caller knows it, not by the hidden name
            raise type(error)(error.errno, error.strerror, path) from None
        return tmp


@contextlib.contextmanager
def written_whole(path):
    """A temporary path beside ``path`` to write; renamed onto ``path`` when the block ends, removed if it fails.

    Examples
    --------
    >>> import tempfile, os
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     with written_whole(os.path.join(tmp, "notes.txt")) as partial, open(partial, "w") as f:
    ...         _ = f.write("done")
    ...     os.listdir(tmp)
    ['notes.txt']
    """
    tmp = atomic_path(path)
    try:
        try:
            yield tmp
            os.replace(tmp, os.fspath(path))
        except OSError as error:  # named as the caller knows it, not by the hidden name (a write names none)
            if error.errno is not None and (error.filename is None or os.fspath(error.filename) == tmp):
                raise type(error)(error.errno, error.strerror, os.fspath(path)) from None
            raise
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


#: VTK's cell type numbers of the cells written here
_VTK_CELL_TYPES = {"triangle": 5, "tetra": 10, "triangle6": 22, "tetra10": 24}
_VTK_KINDS = {"f": "Float", "i": "Int", "u": "UInt"}
_BLOCK = 32768  # bytes of a compressed block, as VTK and meshio write them
_BYTE_ORDER = "LittleEndian" if sys.byteorder == "little" else "BigEndian"


def _data_array(name: str, values, level: int) -> str:
    """One binary ``<DataArray>``: a header of block sizes, then the zlib-compressed blocks, each base64."""
    values = np.asarray(values)
    if values.dtype == bool:
        values = values.astype(np.uint8)
    if values.dtype.kind not in _VTK_KINDS or values.dtype.itemsize > 8 or values.ndim not in (1, 2):
        raise ValueError(
            f"data {name!r}: expected numbers (floats or integers) of shape (n,) or (n, c) for a .vtu file, "
            f"got {values.dtype} of shape {values.shape}"
        )
    values = np.ascontiguousarray(values.astype(values.dtype.newbyteorder("="), copy=False))
    kind = f"{_VTK_KINDS[values.dtype.kind]}{8 * values.dtype.itemsize}"
    raw = values.tobytes()
    blocks = [zlib.compress(raw[i : i + _BLOCK], level) for i in range(0, len(raw), _BLOCK)]
    last = len(raw) - (len(blocks) - 1) * _BLOCK if blocks else 0
    header = np.array([len(blocks), _BLOCK, last] + [len(b) for b in blocks], dtype=np.uint32)
    encoded = base64.b64encode(header.tobytes()).decode() + base64.b64encode(b"".join(blocks)).decode()
    components = f' NumberOfComponents="{values.shape[1]}"' if values.ndim == 2 else ""
    return f'<DataArray type="{kind}" Name="{name}"{components} format="binary">\n{encoded}\n</DataArray>\n'


def _vectors(value) -> np.ndarray:
    value = np.asarray(value)
    return pad3(value) if value.ndim == 2 and value.shape[1] == 2 else value


class VtuPiece:
    """The constant parts of ``.vtu`` files of one mesh, encoded once; :meth:`write` adds a state's points.

    Parameters
    ----------
    cell_type : {"triangle", "tetra", "triangle6", "tetra10"}
    cells : ndarray of int, shape (nT, nodes_per_cell)
    cell_data : dict of str to ndarray of shape (nT,) or (nT, c), optional
    """

    def __init__(self, cell_type: str, cells, cell_data=None):
        if cell_type not in _VTK_CELL_TYPES:
            raise ValueError(f"cell type {cell_type!r}: expected one of {', '.join(_VTK_CELL_TYPES)}")
        cells = np.asarray(cells, dtype=np.int64)
        nT, per = cells.shape
        self.n_cells = nT
        offsets = np.arange(per, per * nT + 1, per, dtype=np.int64)
        types = np.full(nT, _VTK_CELL_TYPES[cell_type], dtype=np.uint8)
        self._cells = (
            "<Cells>\n"
            + _data_array("connectivity", cells.ravel(), 6)
            + _data_array("offsets", offsets, 6)
            + _data_array("types", types, 6)
            + "</Cells>\n"
        )
        arrays = "".join(_data_array(name, _vectors(value), 6) for name, value in (cell_data or {}).items())
        self._cell_data = f"<CellData>\n{arrays}</CellData>\n" if arrays else ""

    def write(self, path, points, point_data=None, field_data=None) -> None:
        """Write one ``.vtu`` file atomically.

        Parameters
        ----------
        path : str or path-like
        points : ndarray, shape (n, 2) or (n, 3)
            Padded to 3D.
        point_data : dict of str to ndarray of shape (n,) or (n, c), optional
            Vectors with 2 components are padded to 3.
        field_data : dict of str to array_like, optional
            Written in ASCII with ``repr``, so the values read back exactly.
        """
        points = pad3(points)
        # the state's own arrays at zlib's fastest level: a frame's time goes here (the cells went once)
        arrays = "".join(_data_array(name, _vectors(value), 1) for name, value in (point_data or {}).items())
        parts = [
            '<?xml version="1.0"?>\n',
            f'<VTKFile type="UnstructuredGrid" version="0.1" byte_order="{_BYTE_ORDER}" header_type="UInt32" '
            'compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n',
            _field_data(field_data) if field_data else "",
            f'<Piece NumberOfPoints="{points.shape[0]}" NumberOfCells="{self.n_cells}">\n',
            "<Points>\n" + _data_array("Points", points, 1) + "</Points>\n",
            self._cells,
            f"<PointData>\n{arrays}</PointData>\n" if arrays else "",
            self._cell_data,
            "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n",
        ]
        with written_whole(path) as tmp, open(tmp, "w", encoding="ascii") as f:
            f.write("".join(parts))


def write_vtu(path, points, cell_type: str, cells, point_data=None, cell_data=None, field_data=None):
    """Write one ``.vtu`` file atomically (see :class:`VtuPiece`).

    Parameters
    ----------
    path : str or path-like
    points : ndarray, shape (n, 2) or (n, 3)
        Padded to 3D.
    cell_type : str
        ``"triangle"``, ``"tetra"``, ``"triangle6"`` or ``"tetra10"``.
    cells : ndarray of int, shape (nT, k)
    point_data : dict of str to ndarray of shape (n,) or (n, c), optional
        Vectors with 2 components are padded to 3.
    cell_data : dict of str to ndarray of shape (nT,) or (nT, c), optional
    field_data : dict of str to ndarray, optional
    """
    VtuPiece(cell_type, cells, cell_data).write(path, points, point_data, field_data)


def _field_data(field_data: dict) -> str:
    """A VTK ``<FieldData>`` block, values in ASCII with ``repr`` (they read back exactly)."""
    arrays = []
    for name, value in field_data.items():
        value = np.atleast_1d(np.asarray(value, dtype=np.float64)).ravel()
        text = " ".join(repr(float(v)) for v in value)
        arrays.append(
            f'<DataArray type="Float64" Name="{name}" NumberOfTuples="{value.size}" '
            f'format="ascii">\n{text}\n</DataArray>\n'
        )
    return "<FieldData>\n" + "".join(arrays) + "</FieldData>\n"


def export_modes(path, mesh, modes, eigenvalues=None, element: str | None = None) -> None:
    """Write modes to a ``.vtu`` file, each as a 3-component point vector.

    In ParaView, open the file, apply *Warp By Vector* and pick a mode
    (``mode_00``, ``mode_01``, ...). P2 modes are written on quadratic cells.

    Parameters
    ----------
    path : str or path-like
        Output ``.vtu`` file; its directory is created if needed.
    mesh : skfem.MeshTri or skfem.MeshTet
    modes : ndarray, shape (n_nodes * dim, k)
        Interleaved modes, e.g. from :func:`~skfem_modal.linear_modal_analysis`.
    eigenvalues : array_like, shape (k,), optional
        Stored as field data ``eigenvalues`` and ``frequency_hz``.
    element : {"P1", "P2"}, optional
        Inferred from the number of rows when omitted.
    """
    from .modal import natural_frequencies

    if not os.fspath(path).lower().endswith(".vtu"):
        raise ValueError(
            f"export_modes writes VTK XML (.vtu), which ParaView reads by its suffix: name it NAME.vtu, got {path!r}"
        )
    check_mesh(mesh)
    modes = np.asarray(modes, dtype=np.float64)
    if modes.ndim == 1:
        modes = modes[:, None]
    dim, n = mesh.p.shape
    if element is None:
        if modes.ndim == 2 and modes.shape[0] not in (n * dim, scalar_basis(mesh, "P2").N * dim):
            nodes = scalar_basis(mesh, "P2").N
            raise ValueError(
                f"modes must have shape ({n * dim}, k) for P1 or ({nodes * dim}, k) for P2 on this mesh, "
                f"got {modes.shape}"
            )
        element = "P1" if modes.shape[0] == n * dim else "P2"
    cell_type, cells = vtk_cells(mesh, element)
    points = mesh.p.T if element == "P1" else scalar_basis(mesh, element).doflocs.T
    if modes.ndim != 2 or modes.shape[0] != points.shape[0] * dim:
        raise ValueError(
            f"modes must have shape ({points.shape[0] * dim}, k) for {element} on this mesh, got {modes.shape}"
        )
    if not np.all(np.isfinite(modes)):
        raise ValueError("modes contain non-finite values")
    width = max(2, len(str(modes.shape[1] - 1)))
    point_data = {f"mode_{i:0{width}d}": modes[:, i].reshape(-1, dim) for i in range(modes.shape[1])}
    field_data = {}
    if eigenvalues is not None:
        ev = np.asarray(eigenvalues, dtype=np.float64).ravel()
        if ev.size != modes.shape[1]:
            raise ValueError(f"got {ev.size} eigenvalues for {modes.shape[1]} modes")
        field_data = {"eigenvalues": ev, "frequency_hz": natural_frequencies(ev)}
    write_vtu(path, points, cell_type, cells, point_data=point_data, field_data=field_data)


_PVD_HEAD = (
    '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n  <Collection>\n'
)
_PVD_FOOT = "  </Collection>\n</VTKFile>\n"


class FrameWriter:
    """Stream simulation frames to disk as a ParaView time series.

    Writes ``DIRECTORY/NAME/frame_00000.vtu, ...`` and the index
    ``DIRECTORY/NAME.pvd`` with each frame's exact time (``repr`` of the float).
    Every frame is written when it arrives, never held in memory, and the
    ``.pvd`` is valid after every frame, so an interrupted run leaves a
    readable series of the frames so far.

    Parameters
    ----------
    directory : str or path-like
    mesh : skfem.MeshTri or skfem.MeshTet
        Rest shape (connectivity, and the reference for displacements).
    name : str
        Base name of the series.
    cell_data : dict of str to ndarray of shape (nT,), optional
        Constant per-element arrays written in every frame (e.g. cluster labels).

    Examples
    --------
    >>> import tempfile, os
    >>> from skfem_modal.mesh import beam2d
    >>> m = beam2d(nx=2, ny=1)
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     with FrameWriter(tmp, m) as frames:
    ...         _ = frames.write(0.0, m.p.T)
    ...         _ = frames.write(0.1, m.p.T + 0.01)
    ...     sorted(os.listdir(os.path.join(tmp, "frames")))
    ['frame_00000.vtu', 'frame_00001.vtu']
    """

    def __init__(self, directory, mesh, name: str = "frames", cell_data=None):
        check_mesh(mesh)
        self.directory = os.fspath(directory)
        self.name = name
        self.frame_dir = os.path.join(self.directory, name)
        self.rest = np.ascontiguousarray(mesh.p.T)
        nT = mesh.t.shape[1]
        for key, value in (cell_data or {}).items():
            if np.shape(value)[:1] != (nT,):
                raise ValueError(f"cell data {key!r} needs one value per element ({nT}), got {np.shape(value)}")
        self.piece = VtuPiece(*vtk_cells(mesh), cell_data)  # (bad data refused before any folder is made)
        os.makedirs(self.frame_dir, exist_ok=True)
        self.count = 0
        self.times: list[float] = []
        self.pvd_path = os.path.join(self.directory, f"{name}.pvd")
        self._pvd = open(self.pvd_path, "w", encoding="ascii")
        self._pvd.write(_PVD_HEAD)
        self._body_end = self._pvd.tell()
        self._pvd.write(_PVD_FOOT)
        self._pvd.flush()

    def write(self, time: float, positions, point_data=None, field_data=None) -> str:
        """Write one frame.

        Parameters
        ----------
        time : float
            Finite, after the last frame's.
        positions : ndarray, shape (n, dim)
            Finite.
        point_data : dict of str to ndarray of shape (n,) or (n, c), optional
            Extra per-vertex arrays (``displacement`` is always written: not one of them).
        field_data : dict of str to array_like, optional
            Per-frame values (e.g. muscle activations), written exactly.

        Returns
        -------
        path : str
            The frame's ``.vtu`` file.

        Raises
        ------
        ValueError, TypeError
            Naming the argument, before anything is written.
        """
        if isinstance(time, np.ndarray) and time.ndim == 0:
            time = time.item()
        if not is_real(time):
            raise TypeError(f"time must be a number, got {time!r}")
        try:
            seconds = float(time)
        except OverflowError:  # an integer beyond a float's range
            seconds = math.inf
        if not math.isfinite(seconds):
            raise ValueError("time must fit a float" if is_whole(time) else f"time must be finite, got {time!r}")
        if self.times and not time > self.times[-1]:
            raise ValueError(f"time must come after the last frame's ({self.times[-1]!r}), got {time!r}")
        positions = np.asarray(positions, dtype=np.float64)
        if positions.shape != self.rest.shape:
            raise ValueError(f"positions must have shape {self.rest.shape}, got {positions.shape}")
        if not np.isfinite(positions).all():
            raise ValueError("positions must be finite")
        n = self.rest.shape[0]
        for key, value in (point_data or {}).items():
            if key == "displacement":
                raise ValueError("point_data 'displacement' is written with every frame: name yours otherwise")
            if np.shape(value)[:1] != (n,) or np.ndim(value) > 2:
                raise ValueError(f"point data {key!r} needs shape ({n},) or ({n}, c), got {np.shape(value)}")
        data = {"displacement": positions - self.rest}
        data.update(point_data or {})
        filename = f"frame_{self.count:05d}.vtu"
        path = os.path.join(self.frame_dir, filename)
        fields = {"time": float(time), **(field_data or {})}
        try:
            self.piece.write(path, positions, data, fields)
        except OSError as err:
            raise named(err, path) from None
        try:
            self._pvd.seek(self._body_end)
            self._pvd.write(
                f'    <DataSet timestep="{float(time)!r}" group="" part="0" file="{self.name}/{filename}"/>\n'
            )
            self._body_end = self._pvd.tell()
            self._pvd.write(_PVD_FOOT)
            self._pvd.flush()
        except OSError as err:
            raise named(err, self.pvd_path) from None
        self.times.append(float(time))
        self.count += 1
        return path

    def close(self) -> None:
        """Close the ``.pvd`` index (it is complete after every frame already)."""
        if not self._pvd.closed:
            self._pvd.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
