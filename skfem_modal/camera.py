"""How the frames of a run are looked at: camera, framing, colour, floor.

Both picture backends (pyvista and matplotlib) draw through the same
orthographic camera, so a run looks the same whichever draws it:

- *up* is the scene's up axis (the ground's, else against gravity, else the
  last axis), drawn upwards on screen, so the ground is a floor for y-up and
  z-up scenes alike;
- a 3D body is seen from the front, turned by :data:`AZIMUTH` and raised by
  :data:`ELEVATION` degrees; a 2D body straight on;
- every frame is framed at the same scale, large enough for the body in any
  frame; the camera stands still when the whole motion fits in about one
  view, and otherwise follows the body, moving only when it nears the edge;
- colour is the *deformation*: each vertex's distance from where the best
  rigid motion of the rest shape puts it (the rigid motion itself is what
  the camera and the floor show), on one fixed range for the whole run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .units import up_axis

__all__ = ["up_vector", "Camera", "deformation", "frame_windows", "grid_spacing", "AZIMUTH", "ELEVATION"]

#: Degrees the 3D camera is turned about the up axis, from straight in front.
AZIMUTH = 30.0
#: Degrees the 3D camera looks down.
ELEVATION = 20.0
#: Free space around the body, as a fraction of its size.
MARGIN = 0.12
#: A camera that stands still may show up to this many times the area a following one would.
STILL_CAMERA_LIMIT = 1.6


def up_vector(summary: dict) -> np.ndarray:
    """The scene's up direction, a unit vector of length ``dim``.

    The ground's up axis when there is a ground (the run's ``settings.up``,
    which gravity chose when the scene left ``ground.up`` out: on an incline
    not gravity's own direction), else against gravity, else the last axis
    (y in 2D, z in 3D).

    Parameters
    ----------
    summary : dict
        A run's ``summary.json``.

    Returns
    -------
    up : ndarray, shape (dim,)
    """
    dim = summary["mesh"]["dim"]
    scene = summary["scene"]
    up = np.zeros(dim)
    ground = scene.get("ground")
    gravity = (scene.get("gravity") or {}).get("acceleration")
    if ground is not None:
        # the ground's axis as the run had it (a scene's ground.up is null when gravity says it: on an
        # incline, gravity's own direction would tilt the floor away from the simulated one)
        axis = (summary.get("settings") or {}).get("up", ground.get("up"))
        up[up_axis(gravity, dim) if axis is None else axis] = 1.0
    elif gravity is not None and np.any(gravity):
        up = -np.asarray(gravity, float) / np.linalg.norm(gravity)
    else:
        up[-1] = 1.0
    return up


@dataclass(frozen=True)
class Camera:
    """An orthographic camera: screen right, screen up, and towards the viewer (orthonormal, 3D).

    Screen coordinates of a point ``x`` are ``(x . right, x . screen_up)``;
    ``x . towards`` is its depth (larger is nearer).

    Parameters
    ----------
    right, screen_up, towards : ndarray, shape (3,)
        Unit vectors, orthogonal.
    """

    right: np.ndarray
    screen_up: np.ndarray
    towards: np.ndarray

    @classmethod
    def looking_at(cls, up, dim: int) -> Camera:
        """The camera of a body whose up direction is ``up`` (length ``dim``, padded to 3D)."""
        up3 = np.zeros(3)
        up3[:dim] = up
        if dim == 2:
            return cls(np.array([up3[1], -up3[0], 0.0]), up3, np.array([0.0, 0.0, 1.0]))
        # straight in front: the first axis not along up runs to the right
        first = np.eye(3)[int(np.argmin(np.abs(up3)))] if abs(up3[0]) > 0.9 else np.eye(3)[0]
        first = first - (first @ up3) * up3
        first /= np.linalg.norm(first)
        front = np.cross(first, up3)
        az, el = np.radians(AZIMUTH), np.radians(ELEVATION)
        towards = np.cos(el) * (np.cos(az) * front + np.sin(az) * first) + np.sin(el) * up3
        right = np.cross(up3, towards)
        right /= np.linalg.norm(right)
        return cls(right, np.cross(towards, right), towards)

    def screen(self, points) -> np.ndarray:
        """Screen coordinates of ``points``, shape (n, 2).

        ``points``: array_like, shape (n, 2) or (n, 3); 2D points lie in the plane z = 0.
        """
        points = np.asarray(points, float)
        basis = np.stack([self.right, self.screen_up])[:, : points.shape[1]]
        return points @ basis.T

    def depth(self, points) -> np.ndarray:
        """Depth of ``points`` along the view, larger nearer, shape (n,).

        ``points``: array_like, shape (n, 2) or (n, 3); 2D points lie in the plane z = 0.
        """
        points = np.asarray(points, float)
        return points @ self.towards[: points.shape[1]]


def deformation(rest, positions, parts=None) -> np.ndarray:
    """Each vertex's distance from the best rigid motion of the rest shape (of its body's, with ``parts``).

    The rigid motion (rotation and translation) is the least-squares fit of
    the rest shape onto ``positions`` (Kabsch), so a body that only moves
    and turns has zero deformation everywhere.

    Parameters
    ----------
    rest, positions : ndarray, shape (n, dim)
    parts : ndarray of int, shape (n,), optional
        Each vertex's body (connected part, :func:`~skfem_modal.mesh.connected_labels`): each body is
        fitted alone (one fit for all coloured a still body beside a turning one as deformed).

    Returns
    -------
    distance : ndarray, shape (n,)

    Examples
    --------
    >>> rest = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    >>> turned = rest @ np.array([[0.0, 1.0], [-1.0, 0.0]]) + 5.0
    >>> bool(deformation(rest, turned).max() < 1e-12)
    True

    Two bodies, one still and one turned: each fitted alone, neither is deformed.

    >>> two, moved = np.vstack([rest, rest + 3.0]), np.vstack([rest, turned + 3.0])
    >>> bool(deformation(two, moved).max() > 0.1), bool(deformation(two, moved, np.repeat([0, 1], 3)).max() < 1e-12)
    (True, True)
    """
    rest = np.asarray(rest, float)
    positions = np.asarray(positions, float)
    if parts is not None and parts.max() > 0:
        distance = np.empty(rest.shape[0])
        for part in range(parts.max() + 1):
            inside = parts == part
            distance[inside] = deformation(rest[inside], positions[inside])
        return distance
    rest_c = rest - rest.mean(axis=0)
    pos_c = positions - positions.mean(axis=0)
    u, _, vt = np.linalg.svd(rest_c.T @ pos_c)
    flip = np.ones(rest.shape[1])
    flip[-1] = np.sign(np.linalg.det(u @ vt)) or 1.0
    rotation = (u * flip) @ vt  # rest_c @ rotation best matches pos_c
    return np.linalg.norm(pos_c - rest_c @ rotation, axis=1)


def frame_windows(boxes, aspect: float, follow_vertically: bool) -> tuple[np.ndarray, float]:
    """The screen window of each frame: where it is centred, and its half height.

    Parameters
    ----------
    boxes : ndarray, shape (k, 2, 2)
        Per frame, the lowest and highest screen coordinates of what must be
        seen (the body, and the floor under it).
    aspect : float
        Width over height of the picture.
    follow_vertically : bool
        Whether a following camera also moves up and down (3D, where moving
        away from the viewer moves up the screen); otherwise its height stays.

    Returns
    -------
    centres : ndarray, shape (k, 2)
    half_height : float
        The same for every frame.
    """
    boxes = np.asarray(boxes, float)
    extent = (boxes[:, 1] - boxes[:, 0]).max(axis=0)  # the largest the body gets, per screen axis
    size = float(extent.max())
    lo, hi = boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)
    need = extent / 2 + MARGIN * size
    if not follow_vertically:  # the whole height of the motion in view: the floor stays put on screen
        need[1] = (hi[1] - lo[1]) / 2 + MARGIN * size
    half_height = max(need[1], need[0] / aspect)
    half_width = half_height * aspect
    still = (hi - lo) / 2 + MARGIN * size
    still_height = max(still[1], still[0] / aspect)
    if still_height <= np.sqrt(STILL_CAMERA_LIMIT) * half_height:
        return np.tile((lo + hi) / 2, (len(boxes), 1)), still_height
    # follow: move only as far as keeps the body inside a dead zone around the centre
    slack = np.array([half_width, half_height]) - (extent / 2 + MARGIN * size)
    centres = np.empty((len(boxes), 2))
    centre = boxes[0].mean(axis=0)
    for k, box in enumerate(boxes):
        centre = np.clip(centre, box.mean(axis=0) - slack, box.mean(axis=0) + slack)
        centres[k] = centre
    if not follow_vertically:
        centres[:, 1] = (lo[1] + hi[1]) / 2
    return centres, half_height


def grid_spacing(size: float) -> float:
    """A round spacing (1, 2 or 5 times a power of ten) near a quarter of ``size``, for floor lines.

    Examples
    --------
    >>> grid_spacing(2.0), grid_spacing(300.0)
    (0.5, 100.0)
    """
    target = size / 4
    power = 10.0 ** np.floor(np.log10(target))
    return float(min((1, 2, 5, 10), key=lambda m: abs(np.log(m * power / target))) * power)
