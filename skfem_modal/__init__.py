"""skfem_modal: linear modal analysis and modal-muscle soft bodies on scikit-fem.

The data flow runs one way: a mesh (:mod:`~skfem_modal.mesh`) gives FEM
operators (:mod:`~skfem_modal.fem`), which give linear modes
(:mod:`~skfem_modal.modal`) used as muscles, a skinning subspace and element
clusters, a reduced simulator, and files for ParaView
(:mod:`~skfem_modal.export`).
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
    boundary_vertices,
    box3d,
    builtin_mesh,
    caterpillar,
    check_mesh,
    creature,
    farthest_point_sampling,
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
    natural_frequencies,
    rigid_mode_count,
    rigid_motions,
)
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
    "vertices_where",
    "actuation_limits",
    "linear_modal_analysis",
    "mode_sign_convention",
    "natural_frequencies",
    "rigid_mode_count",
    "rigid_motions",
    "ScaleWarning",
    "scale_mismatch",
    "up_axis",
]
