"""skfem_modal: linear modal analysis and modal-muscle soft bodies on scikit-fem.

The data flow runs one way: a mesh (:mod:`~skfem_modal.mesh`) gives FEM
operators (:mod:`~skfem_modal.fem`), which give linear modes
(:mod:`~skfem_modal.modal`) used as muscles, a skinning subspace and element
clusters, a reduced simulator (:class:`ModalMuscle`, stepped by
:func:`simulate`; scenes: :class:`Scene`, :func:`run_scene`), and files for
ParaView (:mod:`~skfem_modal.export`).
"""

import importlib as _importlib
from importlib.util import find_spec as _find_spec

#: Where each public name lives: imported on first use, so the command line starts (and a Ctrl-C
#: during its start is handled) before numpy, scipy and scikit-fem are loaded.
_EXPORTS = {
    "export_modes": "export",
    "deformation_jacobian": "fem",
    "element_volumes": "fem",
    "gravity_force": "fem",
    "lame_parameters": "fem",
    "mass_matrix": "fem",
    "node_positions": "fem",
    "quadrature_volumes": "fem",
    "stiffness_matrix": "fem",
    "MeshError": "mesh",
    "beam2d": "mesh",
    "beam3d": "mesh",
    "body_size": "mesh",
    "boundary_vertices": "mesh",
    "box3d": "mesh",
    "builtin_mesh": "mesh",
    "caterpillar": "mesh",
    "check_mesh": "mesh",
    "creature": "mesh",
    "farthest_point_sampling": "mesh",
    "hanging_vertices": "mesh",
    "load_mesh": "mesh",
    "make_mesh": "mesh",
    "mirror": "mesh",
    "normalize_and_center": "mesh",
    "tangled_elements": "mesh",
    "vertices_where": "mesh",
    "actuation_limits": "modal",
    "linear_modal_analysis": "modal",
    "mode_sign_convention": "modal",
    "muscle_modes": "modal",
    "natural_frequencies": "modal",
    "rigid_mode_count": "modal",
    "rigid_motions": "modal",
    "sine_gait": "muscles",
    "FullSpaceSimulator": "reference",
    "run_scene": "run",
    "Scene": "scene",
    "SceneError": "scene",
    "ModalMuscle": "sim",
    "SimulationError": "sim",
    "StepRecord": "sim",
    "simulate": "sim",
    "ScaleWarning": "units",
    "scale_mismatch": "units",
    "up_axis": "units",
    "hinge_count": "modal",
}

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
    "hinge_count",
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


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        if not name.startswith("_") and _find_spec(f".{name}", __name__) is not None:
            return _importlib.import_module(f".{name}", __name__)  # a submodule: sm.mesh as after import sm.mesh
        raise AttributeError(f"module 'skfem_modal' has no attribute {name!r}")
    value = getattr(_importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # found once
    return value


def __dir__():
    # the public names and the module's own dunders, not its helpers (_importlib, _EXPORTS)
    return sorted({name for name in globals() if name.startswith("__") or not name.startswith("_")} | set(_EXPORTS))
