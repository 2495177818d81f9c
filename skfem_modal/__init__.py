"""skfem_modal: linear modal analysis and modal-muscle soft bodies on scikit-fem.

The data flow runs one way: a mesh (:mod:`~skfem_modal.mesh`) gives FEM
operators (:mod:`~skfem_modal.fem`), which give linear modes
(:mod:`~skfem_modal.modal`) used as muscles, a skinning subspace and element
clusters, a reduced simulator (:class:`ModalMuscle`, stepped by
:func:`simulate`; scenes: :class:`Scene`, :func:`run_scene`), and files for
ParaView (:mod:`~skfem_modal.export`).
"""

from .export import export_modes
from .fem import (
    deformation_jacobian,
    element_volumes,
    gravity_force,
    lame_parameters,
    mass_matrix,
    node_positions,
    quadrature_volumes,
    stiffness_matrix,
)
from .mesh import (
    MeshError,
    beam2d,
    beam3d,
    body_size,
    boundary_vertices,
    box3d,
    builtin_mesh,
    caterpillar,
    check_mesh,
    creature,
    farthest_point_sampling,
    hanging_vertices,
    load_mesh,
    make_mesh,
    mirror,
    normalize_and_center,
    tangled_elements,
    vertices_where,
)
from .modal import (
    actuation_limits,
    linear_modal_analysis,
    mode_sign_convention,
    muscle_modes,
    natural_frequencies,
    rigid_mode_count,
    rigid_motions,
)
from .muscles import sine_gait
from .reference import FullSpaceSimulator
from .run import run_scene
from .scene import Scene, SceneError
from .sim import ModalMuscle, SimulationError, StepRecord, simulate
from .units import ScaleWarning, scale_mismatch, up_axis

__version__ = "0.1.0"

__all__ = [
    "export_modes",
    "deformation_jacobian",
    "element_volumes",
    "gravity_force",
    "lame_parameters",
    "mass_matrix",
    "node_positions",
    "quadrature_volumes",
    "stiffness_matrix",
    "MeshError",
    "beam2d",
    "beam3d",
    "body_size",
    "boundary_vertices",
    "box3d",
    "builtin_mesh",
    "caterpillar",
    "check_mesh",
    "creature",
    "farthest_point_sampling",
    "load_mesh",
    "make_mesh",
    "mirror",
    "normalize_and_center",
    "tangled_elements",
    "hanging_vertices",
    "vertices_where",
    "actuation_limits",
    "linear_modal_analysis",
    "mode_sign_convention",
    "natural_frequencies",
    "rigid_mode_count",
    "rigid_motions",
    "muscle_modes",
    "sine_gait",
    "ModalMuscle",
    "FullSpaceSimulator",
    "SimulationError",
    "StepRecord",
    "simulate",
    "Scene",
    "SceneError",
    "run_scene",
    "ScaleWarning",
    "scale_mismatch",
    "up_axis",
]
