"""Watching a run for motion its scene cannot produce physically.

A step that is far too large for a scene (``time.step = 1000`` in a crawl)
still gives finite numbers, just meaningless ones: the body is pushed
millions of body sizes in a step, or swells to many times its size. Two cheap
measures, read from the reduced state each step, tell such runs apart from
physical ones:

- the body's *spread* (root-mean-square distance of the vertices from their
  mean) against its rest spread: the forces of a scene (elasticity, muscles
  with ceilings, gravity, contact) stretch or squash a soft body by tens of
  percent, never by a factor of :data:`SPREAD_LIMIT`;
- the centre of mass's *push*: how far forces other than gravity move it in
  one step, ``h^2 |a - g|`` with ``a`` its acceleration (second difference).
  Elasticity and muscles are internal and never move it (momentum is
  conserved); contact and pins move it by a small fraction of the body's size
  a step when the step resolves the motion. More than :data:`PUSH_LIMIT`
  body sizes in one step is a step far too large for the scene. What holds
  the body's weight (up to a step of free fall) is no push: a ground in the
  steps that end on it, pins and drag in every step (a box resting on the
  ground at ``h = 0.5`` was "moved" 2.5 body sizes a step by it).

Measured on the examples and the default crawl: spread
ratios 0.74-1.33, pushes below 0.04 body sizes; with ``time.step = 1000`` the
built-in crawl's push reaches 2.7 body sizes (its reference contact lets it
through the ground).

A body can also stay put in the air: a contact that holds it up with
nothing under it (the reference contact at a large step keeps its points
where the step started them, above the ground: the tutorial's caterpillar
hangs there at h = 0.3). Given the lowest boundary vertex's height over the
ground each step, the monitor calls it *hovering* when for
:data:`HOVER_STEPS` steps in a row the body is clear of the ground by more
than :data:`HOVER_CLEARANCE` of its size, barely moves, and something other
than gravity holds it up (a push upwards of at least half a step of free
fall), with no pins and no mass-proportional damping (drag) to do it.

A body can sink into the ground too: the reference contact holds only
its sampled points, and only their velocity (a symmetric square at h = 0.2
sank 41 % of its size in its first step), and the Coulomb contact only its
candidates (three of them let a caterpillar fall through the ground). Given
the deepest boundary vertex's depth each step, relative to its body's size,
the monitor reports one deeper than the contact holds: twice the Coulomb
contact's allowance, or :data:`SINK_LIMIT` of the size under the reference
contact (whose feet sink a few percent by design).

A body can turn inside out: ARAP elasticity has no volume term, so a
material too soft for its body's weight, or a step too large, can fold
elements through themselves (a unit square of ``mu = 3e3`` under its weight:
140 of its 256 triangles, a vertex 85 % of its size below the ground while its
boundary vertices stayed on it). Given the full positions of a state (the
frames a run writes, its last state, and the states after a jolt: a hard
landing folds a body for a few steps, between frames), the monitor counts the elements
whose signed area or volume has turned from its rest sign, and reports more
than :data:`INVERTED_LIMIT` of them: a subspace cannot keep every sliver of a
real mesh the right way out (the examples' seal, elephant and ghost crawls
fold 5, 55 and 2 of their elements, at most 0.19 %; the summary counts them).

A third measure says when the muscles themselves are the cause: the largest
commanded activation as a fraction of its muscle's ceiling. Beyond 1 the
muscles ask for more deformation than ``max_s`` (a gait amplitude of 20
swells the body by itself at any time step); the monitor warns
(:class:`CeilingWarning`) and blames the muscles, not the time step, for a
spread or push it reports. Given the material's ``mu / (rho |g|)``, the size
its own weight strains a body by 100 %, it blames a material too soft for a
body more than :data:`~skfem_modal.units.FAR` times that size (a ghost with
``mu = 1e-3`` turns inside out under its weight at any time step).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from .contact import THIN_WORDS, thin
from .mesh import _signed_measures, connected_labels, part_boxes
from .units import FAR

__all__ = [
    "MotionMonitor",
    "MotionWarning",
    "CeilingWarning",
    "SPREAD_LIMIT",
    "PUSH_LIMIT",
    "HOVER_STEPS",
    "HOVER_CLEARANCE",
    "SINK_LIMIT",
    "INVERTED_LIMIT",
    "PIN_LIMIT",
    "JOLT",
    "JOLT_SPEED",
    "JOLT_STEPS",
]

#: A spread this many times the rest spread (or this many times smaller) is not physical.
SPREAD_LIMIT = 3.0
#: Forces other than gravity moving the centre of mass this many body sizes in one step are not physical.
PUSH_LIMIT = 1.0
#: A time step longer than this share of the gait's shortest period samples it at aliased phases (Nyquist's).
GAIT_STEPS = 0.5
# steps whose pushes are measured together (one batch of numpy calls instead of a few a step)
_PUSH_BATCH = 1024
#: Steps in a row a body held still in the air (see the module's text) counts as hovering.
HOVER_STEPS = 3
#: Clear of the ground by this much of its size, a body is in the air (the Coulomb contact's allowance is 2e-4).
HOVER_CLEARANCE = 1e-3
#: A vertex this far into the ground, of its body's size, has sunk under any contact (the reference's feet: 4-14 %).
SINK_LIMIT = 0.25
#: More than this fraction of the elements inside out is a body folded through itself (slivers of real meshes: 0.19 %).
INVERTED_LIMIT = 0.01
#: Pinned vertices this far from their pins, of the body's size, have let go (the default pins: below 4e-4).
PIN_LIMIT = 0.01
#: A step that changes the centre of mass's motion by more than this share of the body's size (beyond what
#: gravity and its support explain) is a jolt: a hard landing or a blow, after which a body can fold through
#: itself for a few steps between the frames written (a symmetric unit square dropped from 100 sizes at
#: h = 0.02: 66 % of its triangles for four steps). The examples' crawls stay below 0.002.
JOLT = 0.01
#: Summed over the steps an elastic wave takes to cross the body (a landing's jolt spreads over about that
#: long), a change of the centre of mass's velocity by more than this share of the wave speed sqrt(mu / rho)
#: (beyond gravity and its support) is a jolt at any time step: per step, the same landing at h = 0.001 was
#: 0.0033 of JOLT's 0.01, and the square folded through itself between the frames unreported. The square
#: dropped from 100 sizes lands at 4.4 wave speeds; the caterpillar's crawl swings by 0.22 of its own.
JOLT_SPEED = 0.5
#: States checked after a jolt for elements inside out: the next this many steps, or as many spread over the
#: crossing time when that is longer.
JOLT_STEPS = 10
# the longest window of steps summed for a jolt (a ring buffer of (bodies, dim) entries)
_WINDOW_MOST = 10_000


def _spread_beyond(ratio):
    """Whether spread ratios (to the rest's) are beyond :data:`SPREAD_LIMIT`, a bool or an array (NaN is beyond)."""
    return np.logical_not((ratio >= 1.0 / SPREAD_LIMIT) & (ratio <= SPREAD_LIMIT))


class MotionWarning(RuntimeWarning):
    """A run completed, but its motion is not physical for its scene."""


class CeilingWarning(MotionWarning):
    """A run drove its muscles beyond their ceilings (activations of more than 1 of the ceiling)."""


def _weight_held(gravity_step):
    """A step's free fall, held whole (pins, drag): its direction (1, dim) and length (1,), or None without gravity."""
    fall = float(np.linalg.norm(gravity_step))
    return None if fall == 0.0 else ((-gravity_step / fall)[None], np.array([fall]))


def _ground_holds(contact, gravity_step):
    """What a ground may hold of a step's free fall, as directions (k, dim) and how far along each (k,), or None.

    Its normal force holds the fall along the up axis; its friction, on an incline, the fall along the
    ground (a body resting there, or sliding slower than free). Neither is a push: a box resting on the
    ground at h = 0.5 was "moved 2.52 body sizes a step" by it. Nor is pins' or drag's holding the weight
    (:func:`_weight_held`).
    """
    if contact is None or not np.any(gravity_step):
        return None
    normal = np.zeros_like(gravity_step)
    normal[contact.up] = 1.0
    along = gravity_step - gravity_step[contact.up] * normal  # the fall along the ground
    held = [(normal, max(0.0, -float(gravity_step[contact.up])))]
    slide = float(np.linalg.norm(along))
    if slide > 0.0:
        held.append((-along / slide, slide))
    return np.array([d for d, _ in held]), np.array([m for _, m in held])


def _body_spread_rows(B, parts, dim: int):
    """Rows whose squares summed over each body's block are its vertices' mean squared distance from their mean.

    Parameters
    ----------
    B : ndarray, shape (n * dim, r)
    parts : ndarray of int, shape (n,)
        Each vertex's body.
    dim : int

    Returns
    -------
    rows : ndarray, shape (k, r)
        Each body's block: the triangular factor of its centred rows of ``B`` (over its vertex count's root).
        A factor, not the Gram matrix z^T G z - |mean|^2: that cancels as the squared coordinates grow (a box
        1e8 from the origin had a spread of 0 at rest, and the run stopped on a division by zero).
    starts : ndarray of int, shape (bodies,)
        Where each body's block starts (for :func:`numpy.add.reduceat`).
    """
    B3 = B.reshape(-1, dim, B.shape[1])
    blocks = []
    for body in range(int(parts.max()) + 1):
        rows = B3[parts == body]
        centred = (rows - rows.mean(axis=0)).reshape(-1, B.shape[1]) / np.sqrt(rows.shape[0])
        blocks.append(np.linalg.qr(centred, mode="r"))
    starts = np.cumsum([0] + [block.shape[0] for block in blocks[:-1]])
    return np.vstack(blocks), starts


def _body_com_rows(sim, parts, bodies: int) -> np.ndarray:
    """Each body's centre of mass as a linear map of the state, its rows stacked, shape (bodies * dim, r)."""
    if bodies == 1:
        return np.asarray(sim.com_rows)
    dofs = np.repeat(parts, sim.dim)  # (N,): each DOF's body
    space = sim.model.space
    return np.vstack([np.asarray(space.com_rows(np.where(dofs == q, sim.mass, 0.0))) for q in range(bodies)])


class MotionMonitor:
    """Spread and push of a run's body, fed one reduced state a step.

    Costs one ``(r, r)`` product a step (the spread is ``z^T G z`` with a
    Gram matrix made once), so it runs beside every step. The elements'
    check (:meth:`check_elements`) needs full positions: a run makes it on
    the frames it writes, its last state, and the states :meth:`update` asks
    for (those after a jolt, :data:`JOLT`).

    Parameters
    ----------
    sim : skfem_modal.sim.ModalMuscle
        Its basis ``B``, ``com``, ``h`` and rest state are used.
    gravity : array_like, shape (dim,), optional
        The scene's gravitational acceleration (the push leaves it out).
    weight_scale : float, optional
        ``mu / (rho |g|)``, the size its own weight strains a body of the material by 100 %
        (:func:`~skfem_modal.units.material_length_scales`): a body more than
        :data:`~skfem_modal.units.FAR` times as large collapses under its weight at any time step,
        and a spread is blamed on the material, not on the time step.
    gait_period : float, optional
        The shortest period of the muscles' gait: a time step longer than :data:`GAIT_STEPS` of it
        samples the gait at aliased phases (reported as ``gait``, from step 1).

    Examples
    --------
    >>> from skfem_modal.sim import ModalMuscle
    >>> from skfem_modal.mesh import beam2d
    >>> sim = ModalMuscle.from_mesh(beam2d(2.0, 0.5, 8, 2), n_muscles=1, n_weights=3, n_clusters=4, h=0.01)
    >>> monitor = MotionMonitor(sim)
    >>> z, z_dot, a = sim.rest_state()
    >>> monitor.update(1, z + 0.0, a)  # a state to check the elements of? (after a jolt)
    False
    >>> monitor.finish()["physical"]
    True
    """

    def __init__(self, sim, gravity=None, weight_scale=None, gait_period=None):
        dim = self.dim = sim.dim
        self.weight_scale = weight_scale
        # each body of the mesh (connected part) watched as one alone: of the whole mesh, a copy 1/1000 the
        # size of a body beside it was pushed 2.62 of its sizes in a step unreported (0.0013 of the whole mesh's),
        # and two squares, one pinned and one falling, "grew to 9.02 times" their rest spread
        self._parts = connected_labels(sim.mesh)
        self.bodies = int(self._parts.max()) + 1
        self._spread_rows = None  # the full space's state is the positions themselves
        if sim.B is not None:
            self._spread_rows, self._spread_starts = _body_spread_rows(np.asarray(sim.B), self._parts, dim)
        self._com_rows = _body_com_rows(sim, self._parts, self.bodies)  # (bodies * dim, r)
        self.h = float(sim.h)
        z_rest = sim.rest_state()[0]
        rest = sim.positions(z_rest)
        low, high = part_boxes(sim.mesh, self._parts, rest)
        self.sizes = (high - low).max(axis=1)  # (bodies,): each one's largest extent
        self.size = float(self.sizes.max())  # the largest body's: what the messages and the material compare
        self.rest_spread = self._spread(z_rest)
        g = np.zeros(dim) if gravity is None else np.asarray(gravity, dtype=np.float64)
        self._gravity_step = self.h**2 * g  # the second difference of free fall
        self._previous = self._coms(z_rest)  # (bodies, dim)
        self._velocity_step = np.zeros((self.bodies, dim))  # the last step's change of each centre of mass
        self.spread_ratio = [1.0, 1.0]  # least and largest
        self._push = 0.0  # largest, in body sizes, of the steps measured (the property measures the others)
        self._steps = []  # (step, on the ground, excess over free fall) of the steps whose push is not measured yet
        self.first_problem_step = {}
        self.gait_period = gait_period
        self._ceilings = np.asarray(sim.ceilings, dtype=np.float64) if sim.n_muscles else None
        self.ceiling_fraction = 0.0  # the largest |activation| / ceiling commanded
        # pins (on its own vertices) or drag may hold a body up in the air: then it is not hovering (pins on one
        # body had kept the other, free, from being seen hovering 0.05 above the ground)
        held = np.zeros(self.bodies, bool)
        held[self._parts[np.asarray(sim.pinned, dtype=np.int64)]] = True
        held |= sim.damping_mass > 0
        self._held = held
        fall = math.sqrt(float(self._gravity_step @ self._gravity_step))
        self._up = None if held.all() or fall == 0.0 else -self._gravity_step / fall
        self._fall = fall  # how far free fall moves a body in a step (its second difference)
        # what may hold the weight up (no push): pins or drag in every step, a ground in the steps on it
        self._always_held = _weight_held(self._gravity_step) if held.any() else None
        self._ground_held = _ground_holds(sim.model.contact, self._gravity_step)
        if self._aliases(gait_period):
            self.first_problem_step["gait"] = 1
        self._hovering = np.zeros(self.bodies, np.int64)  # steps in a row each body was held still in the air
        self._aloft = np.zeros(self.bodies, bool)  # (touching the ground: no body, without one)
        self.hover_clearance = 0.0  # how far above the ground, in body sizes, when it counted
        self.deepest = 0.0  # how far any vertex went into the ground, of its body's size
        self._elements = sim.mesh.t
        self._rest_sign = np.sign(_signed_measures(sim.mesh.p, sim.mesh.t))
        # each body's elements: more than INVERTED_LIMIT of a body's own is a fold (of the whole mesh's, a small
        # square beside a large pinned one had 52 % of its triangles inside out unreported)
        self._element_body = self._parts[sim.mesh.t[0]]
        self._inverted_limit = INVERTED_LIMIT * np.bincount(self._element_body, minlength=self.bodies)
        self.inverted = 0  # the most elements inside out in a state checked (:meth:`check_elements`)
        self._inverted_step = 0  # the step of that state
        self._checked = (-1, 0)  # the step of the last state checked, and its count (a frame and a jolt's alike)
        self._watched_until = -1  # the last step after a jolt whose state is to be checked
        self._watch = (0, 1)  # the jolt's step, and every how many steps its states are checked
        wave = math.sqrt(sim.mu / sim.rho) if sim.mu > 0 and sim.rho > 0 else 0.0
        crossing = np.ceil(self.sizes / (wave * self.h)) if wave > 0 else np.ones(self.bodies)
        self._window = np.clip(crossing, 1, _WINDOW_MOST).astype(np.int64)  # (bodies,): steps a wave crosses each
        self._jolt_sum = JOLT_SPEED * wave * self.h  # a velocity change summed over the window, times h
        self._sums = np.zeros((int(self._window.max()) + 1, self.bodies, dim))  # the excesses' running sums, a ring
        self._summed = 0  # steps summed
        self._bodies = np.arange(self.bodies)
        # the jolts' bounds on the squared norms (one comparison a step): a step's excess beyond a step of free
        # fall, and a window's beyond as many
        self._jolt_bound2 = (JOLT * self.sizes + self._fall) ** 2
        self._window_bound2 = (self._jolt_sum + self._window * self._fall) ** 2
        # every vertex of the states checked below the ground (absolute; relative to its part's size)
        self.deepest_vertex = self.deepest_vertex_relative = 0.0
        self._pinned = np.asarray(sim.pinned, dtype=np.int64)
        self._pins = sim.mesh.p.T[self._pinned]  # where the pinned vertices are held
        # their positions, linear in the state: read every step (in the frames only, pins that let go between
        # frames written every 600 steps went unreported)
        space = sim.model.space
        self._pin_rows = space.rows(space.dofs(self._pinned)) if self._pinned.size else None
        self.pin_drift = 0.0  # the farthest a pinned vertex was from its pin after a step
        self.pin_drift_checked = 0.0  # the same in the states checked (:meth:`check_elements`: the frames written)
        contact = sim.model.contact
        self._plane = contact  # the contact effect: its plane and each vertex's part size
        self._contact_terms = None  # with a ground: its model, allowance, candidates and boundary vertices
        self._sink_limit = math.inf  # of what each vertex's allowance is a share of (contact.boundary_lengths)
        if contact is not None:
            thin_part = bool(np.any(thin(contact.boundary_lengths, contact.boundary_sizes)))
            self._contact_terms = (sim.contact_model, sim.allowance, contact.vertices.size, contact.boundary_sizes.size)
            self._contact_terms += (thin_part,)
            self._sink_limit = 2.0 * sim.allowance if sim.contact_model == "coulomb" else SINK_LIMIT

    def _spread(self, z) -> np.ndarray:
        """Each body's spread in a state ``z`` (r,), shape (bodies,)."""
        return self._spreads(z[None])[0]

    def _spreads(self, states) -> np.ndarray:
        """Each body's root-mean-square distance of its vertices from their mean, of each state (T, r): (T, bodies)."""
        if self._spread_rows is None:
            x = states.reshape(states.shape[0], -1, self.dim)
            spreads = []
            for body in range(self.bodies):
                xb = x[:, self._parts == body]
                xb = xb - xb.mean(axis=1, keepdims=True)
                spreads.append(np.einsum("tnd,tnd->t", xb, xb) / xb.shape[1])
            return np.sqrt(np.stack(spreads, axis=1))
        rows = states @ self._spread_rows.T
        return np.sqrt(np.add.reduceat(rows * rows, self._spread_starts, axis=1))

    def update(self, step: int, z, a=None, clearance=None, depth=None, sunk=None) -> bool:
        """Take the state after ``step`` steps; True if its elements are to be checked (:meth:`check_elements`).

        Parameters
        ----------
        step : int
        z : ndarray, shape (r,)
        a : ndarray, shape (m,), optional
            The step's muscle activations (mode amplitudes), to compare with the ceilings.
        clearance : float or ndarray of shape (bodies,), optional
            How far the lowest boundary vertex (of each body of the mesh) is above the ground
            (negative: below it), with a ground: to tell a body held in the air.
        depth : float, optional
            How far the deepest boundary vertex is below the ground, of its body's size (0 if
            none is), with a ground.
        sunk : float, optional
            The same, of what each vertex's allowance is a share of (the contact's
            ``boundary_lengths``: its part's size, or :data:`~skfem_modal.contact.THIN`
            times a thin part's thickness), with a ground: to tell a body sinking into
            it (``depth`` if not given).

        Returns
        -------
        bool
            Whether the state is one of the :data:`JOLT_STEPS` after a jolt (:data:`JOLT`).
        """
        self._commanded(step, a)
        com = self._coms(z)
        change = com - self._previous
        excess = change - self._velocity_step - self._gravity_step  # (bodies, dim)
        jolted = self._jolted(excess) | self._jolted_over_window(excess)
        if jolted.any():
            span = int(self._window[jolted].max())
            self._watched_until = step + max(JOLT_STEPS, span)
            self._watch = (step, max(1, span // JOLT_STEPS))
        touching = self._aloft if clearance is None else clearance < HOVER_CLEARANCE * self.sizes
        # the pushes are measured in batches (what holds the weight, for all steps at once: :meth:`_pushes`)
        self._steps.append((step, touching, excess))
        if len(self._steps) >= _PUSH_BATCH:  # (a long run holds no more than a batch)
            self._measure_pushes()
        self._previous, self._velocity_step = com, change
        ratio = self._spread(z) / self.rest_spread
        low, high = float(ratio.min()), float(ratio.max())
        if low < self.spread_ratio[0]:
            self.spread_ratio[0] = low
        if high > self.spread_ratio[1]:
            self.spread_ratio[1] = high
        if _spread_beyond(ratio).any():
            self.first_problem_step.setdefault("spread", step)
        if clearance is not None and self._up is not None:
            self._watch_hovering(step, clearance / self.sizes, excess @ self._up, change)
        if depth is not None and depth > self.deepest:
            self.deepest = depth
        sunk = depth if sunk is None else sunk
        if sunk is not None and sunk > self._sink_limit:
            self.first_problem_step.setdefault("sink", step)
        if self._pin_rows is not None:
            drift = self._drift((self._pin_rows @ z).reshape(-1, self.dim))
            self.pin_drift = max(self.pin_drift, drift)
            if drift > PIN_LIMIT * self.size:  # (pins of 1e-6 let a beam fall 80 units, reported physical)
                self.first_problem_step.setdefault("pins", step)
        return step <= self._watched_until and (step - self._watch[0]) % self._watch[1] == 0

    def _jolted_over_window(self, excess) -> np.ndarray:
        """Whether each body's excesses summed over its window, this step's (bodies, dim) the last, are a jolt."""
        ring, summed = self._sums.shape[0], self._summed + 1
        self._summed = summed
        now = np.add(self._sums[(summed - 1) % ring], excess, out=self._sums[summed % ring])
        if self.bodies == 1:  # a plain index (the many bodies' gather costs 2.5 us a step)
            window = now - self._sums[(summed - int(self._window[0])) % ring]
        else:
            window = now - self._sums[(summed - self._window) % ring, self._bodies]
        return np.einsum("bd,bd->b", window, window) > self._window_bound2

    def check_elements(self, step: int, positions) -> int:
        """Count the elements inside out (signed measure against its rest sign) in the state after ``step`` steps;
        and how deep any vertex is below the ground.

        Parameters
        ----------
        step : int
        positions : ndarray, shape (n, dim)
            The state's vertex positions (full: a run passes the frames it writes).

        Returns
        -------
        int
            Elements inside out (a zero measure counts: the element is flat).
        """
        if step == self._checked[0]:  # (a frame written after a jolt)
            return self._checked[1]
        if self._pinned.size:
            self.pin_drift_checked = max(self.pin_drift_checked, self._drift(np.asarray(positions)[self._pinned]))
        per_body = self._inverted(positions)
        inverted = int(per_body.sum())
        self._checked = (step, inverted)
        if inverted > self.inverted:
            self.inverted = inverted
            self._inverted_step = step
        if (per_body > self._inverted_limit).any():
            self.first_problem_step.setdefault("inverted", step)
        if self._plane is not None:
            # an inner vertex is below the boundary's lowest only through elements inside out (a soft box
            # folded: 8.4 % of its size, its boundary 0.019 %), which the steps' boundary check does not see
            depths = self._plane.ground - np.asarray(positions)[:, self._plane.up]
            self.deepest_vertex = max(self.deepest_vertex, float(depths.max()))
            self.deepest_vertex_relative = max(self.deepest_vertex_relative, float((depths / self._plane.sizes).max()))
        return inverted

    def _drift(self, held) -> float:
        """The farthest of the pinned vertices at ``held`` (p, dim) from their pins."""
        return float(np.sqrt(((held - self._pins) ** 2).sum(axis=1)).max())

    def _jolted(self, excess):
        """Whether steps of these excesses over free fall (..., bodies, dim) are jolts (:data:`JOLT`), (..., bodies)."""
        return np.einsum("...d,...d->...", excess, excess) > self._jolt_bound2

    def _coms(self, z) -> np.ndarray:
        """Each body's centre of mass in a state ``z`` (r,), shape (bodies, dim)."""
        return (self._com_rows @ z).reshape(self.bodies, self.dim)

    def _inverted(self, positions) -> np.ndarray:
        """Each body's elements inside out in positions (n, dim), shape (bodies,)."""
        measures = _signed_measures(np.asarray(positions).T, self._elements)
        return np.bincount(self._element_body[measures * self._rest_sign <= 0.0], minlength=self.bodies)

    def run_problems(self, states, gait_period=None, positions=None) -> dict:
        """The first steps of a run from rest whose push or spread is not physical, all at once.

        What :meth:`update` finds step by step (``push`` and ``spread``; not the
        ceilings or hovering), from the run's states in one pass: a rollout keeps its
        states and asks once, at its end. Leaves the monitor as it was.

        Parameters
        ----------
        states : ndarray, shape (T + 1, r)
            The rest state (zero velocity), then the state after each step.
        gait_period : float, optional
            The shortest period of the run's gait (``gait`` if the time step aliases it).
        positions : callable, optional
            A state's vertex positions (``sim.positions``): with it, the elements of the
            last state and of those after each jolt (:data:`JOLT`) are checked too.

        Returns
        -------
        first_problem_step : dict
            ``push``, ``spread``, ``inverted`` (more than :data:`INVERTED_LIMIT` of the
            elements inside out in a state checked) and ``gait`` (1-based steps), each where
            it was first seen; empty if none was.
        """
        states = np.asarray(states, dtype=np.float64)
        coms = (states @ self._com_rows.T).reshape(states.shape[0], self.bodies, self.dim)
        change = np.diff(coms, axis=0)  # (T, bodies, dim): each centre of mass's motion a step
        excess = change - self._gravity_step
        excess[1:] -= change[:-1]
        touching = np.zeros(excess.shape[:2], bool)
        if self._plane is not None:  # each body's lowest boundary vertex within HOVER_CLEARANCE of the ground
            heights = self._plane.boundary(np.ascontiguousarray(states[1:].T))  # (boundary, T)
            lowest = -self._plane.deepest_of_each_body(-heights)  # (bodies, T)
            touching = (lowest.T - self._plane.ground) < HOVER_CLEARANCE * self.sizes
        push = self._pushes(excess, touching)
        ratio = self._spreads(states[1:]) / self.rest_spread
        found = {"push": np.flatnonzero(push > PUSH_LIMIT), "spread": np.flatnonzero(_spread_beyond(ratio).any(axis=1))}
        found = {name: int(steps[0]) + 1 for name, steps in found.items() if steps.size}
        if positions is not None:
            # the excesses summed over each body's window, as update sums them
            sums = np.concatenate([np.zeros((1,) + excess.shape[1:]), np.cumsum(excess, axis=0)])
            steps = np.arange(1, len(excess) + 1)[:, None]
            earlier = sums[np.maximum(steps - self._window, 0), np.arange(self.bodies)]
            window = sums[1:] - earlier
            over = np.einsum("tbd,tbd->tb", window, window) > self._window_bound2
            jolted = self._jolted(excess) | over  # (T, bodies)
            watched = set()
            for j in np.flatnonzero(jolted.any(axis=1)):
                span = int(self._window[jolted[j]].max())
                every = max(1, span // JOLT_STEPS)
                watched |= {min(int(j) + 1 + k, len(excess)) for k in range(0, max(JOLT_STEPS, span) + 1, every)}
            inverted = [
                step
                for step in sorted(watched | {len(excess)})
                if (self._inverted(positions(states[step])) > self._inverted_limit).any()
            ]
            if inverted:
                found["inverted"] = inverted[0]
        if self._aliases(gait_period):
            found["gait"] = 1
        return found

    def _aliases(self, gait_period) -> bool:
        """Whether the time step is too long for a gait of this shortest period (None: no gait)."""
        # (at exactly two steps a period too: a sine read at the same two phases, its zeros for a plain one)
        return gait_period is not None and self.h >= GAIT_STEPS * gait_period

    def _pushes(self, excess, touching) -> np.ndarray:
        """How far forces other than gravity moved a centre of mass, of its body's size, at most, for steps'
        ``excess`` (T, bodies, dim) over free fall, shape (T,); for the bodies ending a step on the ground
        (``touching``, (T, bodies) bool), what it may hold of the weight (:func:`_ground_holds`) left out,
        and in every step what pins or drag may."""
        for holds, where in ((self._always_held, self._held), (self._ground_held, touching)):
            if holds is not None:
                directions, most = holds
                held = np.clip(excess @ directions.T, 0.0, most) * np.expand_dims(where, -1)
                excess = excess - held @ directions
        return (np.sqrt(np.einsum("tbi,tbi->tb", excess, excess)) / self.sizes).max(axis=1)

    def _watch_hovering(self, step: int, clear, lift, change) -> None:
        """Count the steps in a row each body stays still, clear of the ground, held up by something.

        ``clear`` (bodies,): of each body's size; ``lift`` (bodies,) and ``change`` (bodies, dim).
        """
        still = (change * change).sum(axis=1) < self._fall * self._fall
        hovering = (clear > HOVER_CLEARANCE) & still & (lift > 0.5 * self._fall) & ~self._held
        self._hovering = (self._hovering + 1) * hovering
        if "hover" not in self.first_problem_step and self._hovering.max() == HOVER_STEPS:
            self.first_problem_step["hover"] = step - HOVER_STEPS + 1
            self.hover_clearance = float(np.broadcast_to(clear, hovering.shape)[self._hovering.argmax()])

    def _sinking(self) -> str:
        """What :meth:`finish` says of a body that went deeper into the ground than its contact holds."""
        step = self.first_problem_step["sink"]
        model, allowance, candidates, boundary, thin_part = self._contact_terms
        went = f"from step {step} (t = {step * self.h:g}) vertices went into the ground, up to {self.deepest:.3g} "
        went += "of the body's size"
        if model == "reference":
            return (
                f"{went}: the reference contact holds only its sampled points, and only their velocity; the Coulomb "
                'contact (ground.model = "coulomb") holds every vertex'
            )
        allowed = f"{allowance:.3g}"
        if thin_part:  # (a thin part's allowance is less than that share of its size)
            allowed += f" of its size, or of {THIN_WORDS}"
        if candidates < boundary:
            return (
                f"{went}, deeper than the Coulomb contact's allowance ({allowed}): it holds only its "
                f"contact candidates ({candidates} of the {boundary} boundary vertices: ground.contacts, "
                "ground.contacts_where), and "
                'the others sank; take them all (ground.contacts = "all", the default)'
            )
        return f"{went}, deeper than the Coulomb contact's allowance ({allowed}): the contact did not hold it"

    def _commanded(self, step: int, a) -> None:
        """The step's activations against the ceilings."""
        if a is not None and self._ceilings is not None:
            fraction = float(np.max(np.abs(a) / self._ceilings))
            if not fraction <= self.ceiling_fraction:  # larger, or NaN (a NaN activation is beyond any ceiling)
                self.ceiling_fraction = fraction
            if not fraction <= 1.0 + 1e-12:  # a gait at exactly its ceiling rounds to a hair above
                self.first_problem_step.setdefault("ceilings", step)

    def failed(self, step: int, a=None) -> None:
        """The step ``step`` failed (its state became non-finite): what it was commanded, for :meth:`finish`.

        Parameters
        ----------
        step : int
        a : ndarray, shape (m,), optional
            The failing step's muscle activations.
        """
        self._commanded(step, a)
        self.first_problem_step.setdefault("non_finite", step)

    @property
    def _too_soft(self) -> bool:
        return self.weight_scale is not None and self.size > FAR * self.weight_scale

    def _blame(self, overdriven: bool) -> str:
        """What makes a spread, push or inversion: the muscles beyond their ceilings, a material too soft, or
        the time step."""
        if overdriven:
            return (
                "the muscles, driven beyond their ceilings, cause it: keep the activations (muscles.gait.amplitude, "
                "muscles.table) within [-1, 1] of the ceilings, or raise muscles.max_s"
            )
        # an inside-out body that its weight strains by more than 100 %: the material (ARAP resists no folding)
        soft = self.weight_scale is not None and self.size > self.weight_scale and self.inverted
        if self._too_soft or soft:
            return (
                f"the material is too soft to carry the body's own weight (the body is "
                f"{self.size / self.weight_scale:.3g} times mu / (rho |g|) = {self.weight_scale:.3g}, the size its "
                "weight strains by 100 %): it collapses at any time step; a stiffer material (material.mu) or a "
                "lighter one (material.rho) holds it"
            )
        return (
            f"neither the muscles' ceilings nor the material's weight explain it: the time step h = {self.h:g} may "
            "be too large for this scene (try a smaller time.step); if a smaller one does the same, the scene asks "
            "more than the elements can take (several muscles at once, a violent landing)"
        )

    def _problems(self, overdriven: bool) -> list[str]:
        """A sentence for each problem seen (:meth:`finish`), but the ceilings' and the blame."""
        texts = []
        low, high = self.spread_ratio
        if "spread" in self.first_problem_step:
            step = self.first_problem_step["spread"]
            size = f"grew to {high:.3g} times" if high > SPREAD_LIMIT else f"shrank to {low:.3g} times"
            texts.append(
                f"from step {step} (t = {step * self.h:g}) the body {size} its rest size"
                + (" (a body of the mesh, in its own spread)" if self.bodies > 1 else "")
                + ("" if overdriven or self._too_soft else ": no force in this scene deforms it so far")
            )
        if "push" in self.first_problem_step:
            step = self.first_problem_step["push"]
            texts.append(
                f"from step {step} (t = {step * self.h:g}) forces other than gravity moved the centre of mass up to "
                f"{self.push:.3g} body sizes in one step"
                + (" (of a body of the mesh, in its own sizes)" if self.bodies > 1 else "")
                + ": the motion is not resolved"
            )
        if "inverted" in self.first_problem_step:
            step, n = self.first_problem_step["inverted"], self._elements.shape[1]
            of = " of a body of the mesh" if self.bodies > 1 else ""
            texts.append(
                f"from step {step} (t = {step * self.h:g}) more than {100 * INVERTED_LIMIT:g} % of the elements{of} "
                f"were inside out, up to {self.inverted} of the {n} ({100 * self.inverted / n:.3g} %, at "
                f"t = {self._inverted_step * self.h:g}) in the states checked (the frames written, the last, and "
                "those after each jolt): "
                "the body folded through itself"
                + (
                    ", so vertices inside it may be below the ground while its boundary is not"
                    if self._contact_terms is not None
                    else ""  # (said of a floating body, the ground was one it does not have)
                )
            )
        if "hover" in self.first_problem_step:
            step = self.first_problem_step["hover"]
            texts.append(
                f"from step {step} (t = {step * self.h:g}) the body stayed in the air, {self.hover_clearance:.3g} "
                "body sizes above the ground, held up against gravity with nothing under it (the reference "
                "contact at a large time step keeps its points where each step started them): the Coulomb contact "
                '(ground.model = "coulomb") or a smaller time.step lands it'
            )
        if "pins" in self.first_problem_step:
            step = self.first_problem_step["pins"]
            texts.append(
                f"from step {step} (t = {step * self.h:g}) the pinned vertices drifted from their pins, up to "
                f"{self.pin_drift:.3g} ({self.pin_drift / self.size:.3g} body sizes): the pins "
                "let go, too soft for the forces on them (pin_stiffness, [pinned] stiffness: the default holds)"
            )
        if "gait" in self.first_problem_step:
            period = self.gait_period
            texts.append(
                f"the gait's shortest period ({period:g}) is at most two time steps (h = {self.h:g}): the muscles "
                f"are sampled at aliased phases, not as the gait asks; a time.step of at most {period / 20:.2g} "
                "(twenty a period) resolves it"
            )
        if "sink" in self.first_problem_step:
            texts.append(self._sinking())
        if "non_finite" in self.first_problem_step:
            step = self.first_problem_step["non_finite"]
            texts.append(f"at step {step} (t = {step * self.h:g}) the state became non-finite")
        return texts

    @property
    def push(self) -> float:
        """The largest push so far, in body sizes."""
        self._measure_pushes()
        return self._push

    def _measure_pushes(self) -> None:
        """The pushes of the steps taken since the last measure, in one batch (``push`` in ``first_problem_step``)."""
        if self._steps:
            steps, touching, excess = zip(*self._steps)
            self._steps = []
            pushes = self._pushes(np.array(excess), np.array(touching))
            self._push = max(self._push, float(pushes.max()))
            pushed = np.flatnonzero(pushes > PUSH_LIMIT)
            if pushed.size:
                self.first_problem_step.setdefault("push", steps[pushed[0]])

    def finish(self, warn: bool = True) -> dict:
        """What was seen, for ``summary.json``; warns (:class:`MotionWarning`) if it was not physical.

        Parameters
        ----------
        warn : bool
            Whether to issue the warnings (the report lists them either way): a failed run's caller
            passes False.

        Returns
        -------
        report : dict
            ``physical``, ``warnings`` (sentences), ``largest_ceiling_fraction``
            (the largest activation over its ceiling), ``body_size`` (largest
            rest extent; of the largest body, in a mesh of several), ``spread_ratio`` (least and largest),
            ``largest_push_body_sizes`` (of each body's own size), ``deepest_body_sizes`` (the deepest any boundary
            vertex went into the ground after a step, or any vertex in a state checked, of its
            part's size: the summary's ``worst_penetration_relative``), ``inverted_elements`` (the
            most inside out in a state checked) and ``first_problem_step``.

        Warns
        -----
        CeilingWarning
            With ``warn``, when the muscles were driven beyond their ceilings: the first sentence of ``warnings``.
        MotionWarning
            With ``warn``, each other sentence of ``warnings``.
        """
        self._measure_pushes()
        overdriven = "ceilings" in self.first_problem_step
        texts = self._problems(overdriven)
        physical = not texts
        if texts and (overdriven or {"spread", "push", "inverted"} & set(self.first_problem_step)):
            texts.append(self._blame(overdriven))
        categories = [MotionWarning] * len(texts)
        if overdriven:
            step = self.first_problem_step["ceilings"]
            texts.insert(
                0,
                f"from step {step} (t = {step * self.h:g}) the muscles were driven up to {self.ceiling_fraction:.3g} "
                "times their ceilings (an activation beyond 1 asks an element to deform by more than muscles.max_s)",
            )
            categories.insert(0, CeilingWarning)
        if warn:
            for text, category in zip(texts, categories):
                warnings.warn(text, category, stacklevel=2)
        return {
            "physical": physical,
            "warnings": texts,
            "largest_ceiling_fraction": self.ceiling_fraction,
            "body_size": self.size,
            "spread_ratio": list(self.spread_ratio),
            "largest_push_body_sizes": self.push,
            # the steps' boundary vertices and every vertex of the states checked (the start's frame too), as the
            # summary's ground has it (no ground: none)
            "deepest_body_sizes": max(self.deepest, self.deepest_vertex_relative)
            if self._contact_terms is not None
            else None,
            "inverted_elements": self.inverted,
            "first_problem_step": dict(self.first_problem_step),
        }
