"""The ``skfem-modal`` command.

Exit codes: 0 success; 2 bad input (usage, a mesh or scene error, a missing
file, an output folder holding an earlier run, a missing extra); 3 numerical
failure (a simulation that went non-finite, a modal analysis whose eigen solve
stalled or lost its precision, a gait search none of whose gaits moved
physically); 4 the workers were lost (a
worker process killed, the dask scheduler gone: a search keeps its
checkpoint and says how to resume); 5 outputs could not be written (a
run's as it went: the message names the file and the step; any command's
file on a disk full or over its quota); 130
interrupted (Ctrl-C, or SIGTERM: the same clean stop); 141 the reader of the
output went away (e.g. ``| head``).
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import sys
import time
import warnings

import numpy as np

from .checks import nothing_free
from .interrupts import EXIT_INTERRUPTED, Terminated, terminate_as_interrupt
from .outputs import OutputError, check_output_file
from .study import WorkersLost

EXIT_OK = 0
EXIT_BAD_INPUT = 2
EXIT_NUMERICAL = 3
EXIT_WORKERS_LOST = 4
EXIT_OUTPUTS = 5
EXIT_PIPE_CLOSED = 141  # 128 + SIGPIPE, as for other command-line tools
# what only writing meets: a command's output failed, whichever file it was (not its input)
_NO_ROOM = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})

#: Elastic modes ``modes`` finds besides the rigid motions, unless -k says otherwise.
ELASTIC_MODES = 6
#: Parts of a mesh beyond which ``modes`` asks for -k rather than find every part's rigid motions
MANY_PARTS = 100


def parse_mesh_spec(spec: str, merge: bool = False):
    """A mesh from a command-line spec: a file path, or ``NAME[:key=value,...]``.

    ``caterpillar:nx=280,ny=136`` builds the built-in caterpillar with those
    parameters (a list in brackets: ``box3d:size=[4,1,1]``); anything that is
    not a built-in name is read as a file
    (``merge``: its coincident vertices merged, as for a triangle soup).

    Parameters
    ----------
    spec : str
        A mesh file's path (any format meshio reads), or a built-in shape's name
        (:data:`~skfem_modal.mesh.BUILTIN_SHAPES`) with optional ``:key=value,...`` parameters: each
        value an integer, a float, ``true``/``false``, or a bracketed list of numbers.
    merge : bool
        Merge a mesh file's coincident vertices; refused for a built-in shape.

    Returns
    -------
    mesh : skfem.MeshTri or skfem.MeshTet

    Raises
    ------
    ValueError
        ``spec`` names a scene (``.toml``); a parameter that is not ``key=value``, given twice, not a
        number or unknown to the shape (:func:`~skfem_modal.mesh.builtin_mesh`); ``merge`` with a built-in
        shape; or a mesh file that cannot be read as a mesh (:func:`~skfem_modal.mesh.load_mesh`).
    FileNotFoundError
        No such mesh file.
    """
    from .mesh import BUILTIN_SHAPES, builtin_mesh, load_mesh

    if _is_scene(spec):
        raise ValueError(f"{spec} is a scene; this command takes a mesh: a mesh file or a built-in NAME")
    name, _, params = spec.partition(":")
    if name in BUILTIN_SHAPES:
        kwargs = {}
        # commas part the parameters, but not inside brackets: box3d:nx=4,size=[1,2,3]
        for item in filter(None, re.split(r",(?![^\[]*\])", params)):
            key, eq, value = (part.strip() for part in item.partition("="))
            if not eq:
                raise ValueError(f"mesh parameter {item!r} in {spec!r} must look like key=value")
            if key in kwargs:
                raise ValueError(f"mesh parameter {key!r} is given twice in {spec!r}")
            if value.startswith("[") and value.endswith("]"):
                kwargs[key] = [_number(v.strip(), f"mesh parameter {key!r}") for v in value[1:-1].split(",")]
            else:
                kwargs[key] = _number(value, f"mesh parameter {key!r}")
        if merge:
            raise ValueError(f"--merge is for mesh files; {name} is a built-in shape (its vertices are shared)")
        return builtin_mesh(name, **kwargs)
    return load_mesh(spec, merge=merge)


def _is_scene(path) -> bool:
    return path is not None and str(path).lower().endswith(".toml")


def _number(text: str, what: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    raise ValueError(f"{what} must be a number, got {text!r}")


def _say(args):
    """``print``, or nothing under ``-q``."""
    return (lambda *a: None) if args.quiet else print


def _material(args) -> tuple[float, float]:
    from .fem import lame_parameters

    if args.young is not None or args.poisson is not None:
        if args.young is None or args.poisson is None:
            raise ValueError("--young and --poisson go together")
        if args.mu is not None or args.lam is not None:
            raise ValueError("--young/--poisson and --mu/--lam both give the material: give one pair")
        return lame_parameters(args.young, args.poisson)
    return (1.0 if args.mu is None else args.mu), (1.0 if args.lam is None else args.lam)


def cmd_modes(args) -> int:
    """``skfem-modal modes``: a mesh's linear vibration modes, printed as a table and written for ParaView.

    ``args``: the options :func:`build_parser` parsed for ``modes`` (the mesh spec, ``-k``, the
    material, ``--fix``, ``--out``, ...). Returns :data:`EXIT_OK`; bad input (``--fix`` selecting no
    vertex or every one, a mesh of many parts without ``-k``, an inconsistent material) raises
    ``ValueError``, and an eigen solve that fails ``FloatingPointError``, for :func:`main` to turn into
    its exit code.
    """
    from .export import export_modes
    from .mesh import mesh_summary, vertices_where
    from .modal import (
        DEFAULT_MASS,
        actuation_limits,
        hinge_count,
        linear_modal_analysis,
        natural_frequencies,
        rigid_mode_count,
    )

    mu, lam = _material(args)
    check_output_file(args.out, "--out", ".vtu", "modes.vtu")
    mesh = parse_mesh_spec(args.mesh, args.merge)
    fixed = None
    if args.fix:
        fixed = np.unique(np.concatenate([vertices_where(mesh, cond) for cond in args.fix]))
        if fixed.size == 0:
            raise ValueError(f"--fix {' '.join(args.fix)} selects no vertex")
        everything = nothing_free(fixed.size, mesh.p.shape[1], f"--fix {' '.join(args.fix)}", "fix fewer")
        if everything:
            raise ValueError(everything)
    info = mesh_summary(mesh)
    mass = args.mass or DEFAULT_MASS[args.element]
    say = _say(args)
    say(
        f"{args.mesh}: {info['vertices']} vertices, {info['elements']} {info['element']} elements, "
        f"{info['dim']}D, {args.element}, {mass} mass" + (f", {fixed.size} fixed vertices" if fixed is not None else "")
    )
    n_rigid, n_hinges = rigid_mode_count(mesh, fixed), hinge_count(mesh, fixed)
    k = args.k
    if k is None:
        if info["parts"] > MANY_PARTS:
            raise ValueError(
                f"{args.mesh} falls into {info['parts']} separate parts: their {n_rigid} rigid motions come before "
                "any elastic mode (a triangle soup? --merge joins its coincident vertices); or ask for -k modes"
            )
        free = mesh.p.size - (0 if fixed is None else fixed.size * mesh.p.shape[0])
        k = min(n_rigid + n_hinges + ELASTIC_MODES, free)  # a small mesh has fewer
    start = time.perf_counter()
    values, modes = linear_modal_analysis(
        mesh, k, mu=mu, lam=lam, rho=args.rho, fixed=fixed, mass=mass, element=args.element
    )
    elapsed = time.perf_counter() - start
    freqs = natural_frequencies(values)
    ceilings = actuation_limits(mesh, modes, max_s=args.max_s, element=args.element)
    say(f"{k} modes in {elapsed:.3f} s; {n_rigid} rigid motions ({info['parts']} connected part(s))")
    if k <= n_rigid:
        say(f"all {k} are rigid motions: ask for more than {n_rigid} (-k) to see elastic modes")
    say(f"{'mode':>5}  {'eigenvalue':>16}  {'frequency [Hz]':>15}  {'ceiling':>10}  kind")
    kinds = (["rigid"] * n_rigid + ["hinge"] * n_hinges + ["elastic"] * k)[:k]
    for i, (val, f, c, kind) in enumerate(zip(values, freqs, ceilings, kinds)):
        # a rigid motion is no muscle: its "ceiling" only measures a rotation's gradient, or is infinite
        ceiling = "-" if kind == "rigid" or not np.isfinite(c) else f"{c:10.6g}"
        f = f if kind == "elastic" else 0.0  # round-off's sqrt is no frequency
        say(f"{i:5d}  {val:16.9e}  {f:15.6g}  {ceiling:>10}  {kind}")
    export_modes(args.out, mesh, modes, values, element=args.element)
    say(f"wrote {args.out} (ParaView: Warp By Vector on mode_NN)")
    return EXIT_OK


def _load_scene(path):
    from .scene import Scene

    return Scene.default() if path is None else Scene.from_toml(path)


def cmd_run(args) -> int:
    """``skfem-modal run``: run a scene (default: the built-in caterpillar crawl) into ``--out``, then render it
    with ``--render``.

    ``args``: the options :func:`build_parser` parsed for ``run``. Returns :data:`EXIT_OK`, or
    :data:`EXIT_NUMERICAL` when the simulation failed (said on stderr); bad input (a scene error, an
    earlier run in ``--out`` without ``--overwrite``, picture options without ``--render``) raises, for
    :func:`main` to turn into its exit code.
    """
    from .monitor import MotionWarning
    from .outputs import clear_earlier_run
    from .run import run_scene
    from .sim import SimulationError

    _picture_options(args)
    scene = _load_scene(args.scene)
    if args.render:
        _check_render(args)
    clear_earlier_run(args.out, args.overwrite, how="--overwrite")
    say = _say(args)
    say(f"scene: {scene.config['name']} ({scene.source}); effects: {', '.join(scene.effects)}")
    say(f"{scene.n_steps} steps of {scene.h:g}; writing to {args.out}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", MotionWarning)  # said below, once, in the command's words
            summary = run_scene(scene, args.out, every=args.every, progress=not args.quiet)
    except SimulationError as err:
        print(f"skfem-modal run: simulation failed: {err}", file=sys.stderr)
        return EXIT_NUMERICAL
    except KeyboardInterrupt as stop:
        if _written_status(args.out) != "completed":
            raise
        # the signal came while the last step's records were written (held until they were whole)
        skipped = "the closing lines and --render skipped" if args.render else "the closing lines skipped"
        print(
            f"skfem-modal run: {_stopped(stop)} after the last step: the run is whole (summary.json says "
            f"completed); {skipped}",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    for text in summary["motion"]["warnings"]:
        print(f"skfem-modal run: warning: {text}", file=sys.stderr)
    step = summary["timings"]["step_ms"]
    travel = (np.round(summary["com"]["travel"], 4) + 0.0).tolist()  # (+ 0.0: no "-0.0" for a body that stayed)
    say(
        f"precompute {summary['timings']['precompute_total_s']:.3f} s; step median {step['median']:.3f} ms, "
        f"p90 {step['p90']:.3f} ms ({summary['backend']}); iterations per step {summary['iterations']['mean']:.2f}"
    )
    say(f"centre of mass travel {travel}")
    if summary["ground"]:
        ground = summary["ground"]
        share = 100 * ground["worst_penetration_relative"]
        of = (
            f"{share:.2g} % of the body's size"
            if summary["mesh"]["parts"] == 1
            else f"relative to the size of each vertex's own part, at most {share:.2g} %"
        )
        deepest = ground["worst_penetration"]
        allowed = "" if ground.get("allowance") is None else f", allowance {100 * ground['allowance']:.2g} %"
        if ground.get("worst_penetration_of_allowance") is not None:
            # (of the boundary vertices: a vertex inside a body folded through itself can go deeper)
            boundary = 100 * ground["worst_penetration_of_allowance"]
            of += f"; the deepest boundary vertex {boundary:.3g} % of its allowance"
        say(f"deepest any vertex went below the ground ({ground['model']} contact{allowed}): {deepest:.3g} ({of})")
    say(f"wrote {args.out}/frames.pvd ({summary['frames']['count']} frames), com.csv, amplitudes.csv, summary.json")
    return _render(args.out, args, say) if args.render else EXIT_OK


class _RenderUnavailable(Exception):
    """Rendering cannot work here (a missing extra or plugin); said before any work."""


def _check_render(args) -> None:
    from .plot import picture_size_problem, render_problems

    problem = picture_size_problem(args.size, args.format)
    if problem:
        raise ValueError(f"--size {problem}")
    problems = render_problems(args.backend, args.format)
    if problems:
        raise _RenderUnavailable("cannot render: " + "; ".join(problems))


def _render(run_dir, args, say) -> int:
    from .plot import render_run

    _check_render(args)
    written = render_run(run_dir, backend=args.backend, fmt=args.format, max_frames=args.max_frames, size=args.size)
    backend = written.pop("backend")
    say(f"rendered with {backend}: " + ", ".join(os.path.basename(p) for p in written.values()))
    return EXIT_OK


def cmd_render(args) -> int:
    """``skfem-modal render``: pictures and an animation of the run in ``args.run_dir``.

    ``args``: the options :func:`build_parser` parsed for ``render`` (the backend, format, frames and
    size). Returns :data:`EXIT_OK`; rendering that cannot work here (a missing extra) raises before any
    work, as does a run folder that cannot be read.
    """
    say = _say(args)
    return _render(args.run_dir, args, say)


def cmd_info(args) -> int:
    """``skfem-modal info``: what a scene or a mesh holds (sizes, effects, material), or the scene file
    reference (``--scene-reference``), printed.

    ``args``: the options :func:`build_parser` parsed for ``info``; its ``target`` a scene ``.toml``
    (default: the built-in scene), a mesh file or a built-in shape spec (:func:`parse_mesh_spec`).
    Returns :data:`EXIT_OK`; ``--merge`` with a scene, or a scene or mesh that cannot be read, raises
    (``ValueError``, ``FileNotFoundError``), for :func:`main` to turn into its exit code.
    """
    from .contact import ALLOWANCE, THIN_WORDS
    from .mesh import mesh_summary
    from .scene import schema_markdown

    if args.scene_reference:
        print(schema_markdown())
        return EXIT_OK
    target = args.target
    if target is None or _is_scene(target):
        if args.merge:
            raise ValueError(
                "--merge is for mesh files; a scene merges its mesh file's vertices with mesh.merge = true"
            )
        scene = _load_scene(target)
        mesh = scene.mesh
        info = mesh_summary(mesh)
        c = scene.config
        dim = info["dim"]
        r = c["subspace"]["weights"] * (dim + 1) * dim
        # more columns than DOFs span them all: the run keeps as many as there are DOFs (with a warning)
        subspace = f"subspace {r}" if r <= mesh.p.size else f"subspace {mesh.p.size} (of {r} columns: the whole space)"
        print(f"scene: {c['name']} ({scene.source})")
        print(
            f"mesh: {info['vertices']} vertices, {info['elements']} {info['element']} elements, {dim}D, "
            f"measure {info['measure']:.6g}, {info['parts']} part(s)"
        )
        print(f"bounds: {_shown(info['bounds'][0])} .. {_shown(info['bounds'][1])}")
        print(f"effects: {', '.join(scene.effects)}")
        mat = scene.material()
        print("material: " + ", ".join(f"{k} = {v:g}" for k, v in mat.items()))
        print(
            f"sizes: {mesh.p.size} DOFs, {subspace}, {c['subspace']['clusters']} clusters, "
            f"{c['muscles']['count']} muscles"
        )
        print(
            f"time: {scene.n_steps} steps of {scene.h:g} ({scene.n_steps * scene.h:g} in all), "
            f"at most {c['time']['iterations']} iterations per step"
        )
        if c["muscles"]["count"]:
            print(f"muscles: {_drive(c['muscles'])}")
        if c["ground"] is not None:
            g = c["ground"]
            which = _contact_points(scene)
            rule = (
                f"friction {0.5 if g['friction'] is None else g['friction']:g}, "
                f"allowance {100 * (ALLOWANCE if g['allowance'] is None else g['allowance']):.2g} % of the size"
                + (f", or of {THIN_WORDS}" if _thin(scene) else "")
                + (", the active set's friction (exact_friction = false)" if g["exact_friction"] is False else "")
                if g["model"] == "coulomb"
                else f"stickiness {1.0 if g['stickiness'] is None else g['stickiness']:g}, "
                f"push_out {0.0 if g['push_out'] is None else g['push_out']:g}"
            )
            print(
                f"ground: height {scene.ground_height():.6g} along axis {scene.up}, {g['model']} contact at "
                f"{which}, {rule}"
            )
        if c["pinned"] is not None:
            print(f"pinned: {scene.pinned_vertices().size} vertices")
        return EXIT_OK
    mesh = parse_mesh_spec(target, args.merge)
    info = mesh_summary(mesh)
    print(
        f"mesh: {info['vertices']} vertices, {info['elements']} {info['element']} elements, {info['dim']}D, "
        f"measure {info['measure']:.6g}, {info['parts']} part(s)"
    )
    print(f"bounds: {_shown(info['bounds'][0])} .. {_shown(info['bounds'][1])}")
    return EXIT_OK


def _drive(muscles: dict) -> str:
    """What drives a scene's muscles, in words: its gait (and ramp), its table, or nothing."""
    gait = muscles["gait"]
    if muscles["table"] is not None:
        return f"the table {muscles['table']}"
    if gait is None:
        return "at rest (no gait, no table)"
    phase = gait["phase"] or [0.0] * len(gait["amplitude"])
    ramp = f", ramped in over {gait['ramp']:g}" if gait["ramp"] else ", at full amplitude from the start"
    return (
        f"sine gait, amplitudes {[float(a) for a in gait['amplitude']]} of the ceilings, periods "
        f"{[float(t) for t in gait['period']]}, phases {[float(p) for p in phase]}{ramp}"
    )


def _thin(scene) -> bool:
    """Whether a part of the scene's mesh is thin enough that its allowance is a share of its thickness."""
    from .contact import allowance_lengths, thin
    from .mesh import part_sizes

    return bool(np.any(thin(allowance_lengths(scene.mesh), part_sizes(scene.mesh))))


def _contact_points(scene) -> str:
    """Which contact vertices a scene's run uses, in words: how many, of how many, and why."""
    from .mesh import boundary_vertices

    available = boundary_vertices(scene.mesh)
    pool = "boundary vertices"
    if scene.contact_candidates() is not None:
        available = np.intersect1d(available, scene.contact_candidates())
        pool += " where contacts_where holds"
    used, asked = scene.contact_vertices().size, scene.contact_count()
    if used < available.size:
        return f"{used} of the {available.size} {pool}"
    more = f" (contacts = {asked} asks for more: all are used)" if asked is not None and asked > used else ""
    return f"all {used} {pool}{more}"


def _scene_data(path, default):
    """A scene file's dict and the folder its relative paths start from (``default`` without a file).

    The file is checked first: every scene error before anything runs.
    """
    if path is None:
        return default, None
    from .scene import Scene, read_scene_file

    data, base_dir = read_scene_file(path), os.path.dirname(os.path.abspath(path))
    Scene.from_dict(data, base_dir=base_dir, source=path)
    return data, base_dir


def cmd_study(args) -> int:
    """``skfem-modal study``: the accuracy/cost study of a scene (default: the floating caterpillar), its report
    written to ``--out`` (:func:`~skfem_modal.study.run_study`).

    ``args``: the options :func:`build_parser` parsed for ``study``. Returns :data:`EXIT_OK`; an earlier
    study in ``--out`` without ``--overwrite`` raises ``FileExistsError``, and workers lost
    :class:`~skfem_modal.study.WorkersLost`, for :func:`main` to turn into its exit code.
    """
    from .outputs import clear_earlier_study
    from .study import FLOATING_CATERPILLAR, run_study

    data, base_dir = _scene_data(args.scene, FLOATING_CATERPILLAR)
    clear_earlier_study(args.out, args.overwrite, how="--overwrite")  # refused before anything is said
    say = _say(args)
    say(f"study ({'quick' if args.quick else 'full'}) of {data.get('name', args.scene)}; writing to {args.out}")
    report = run_study(
        data,
        args.out,
        preset="quick" if args.quick else "full",
        base_dir=base_dir,
        workers=args.workers,
        scheduler=args.scheduler,
        progress=not args.quiet,
        overwrite=args.overwrite,
        how="--overwrite",
    )
    for reason in report["left_out"].values():
        say(f"not run for this scene: {reason}")
    for line in report["recommendation"]:
        say(line)
    written = [report[key] for key in ("markdown", "csv", "modal_csv", "json", "png") if key in report]
    say("wrote " + ", ".join(written))
    return EXIT_OK


def _direction(text: str, dim: int) -> np.ndarray:
    """A travel direction from ``x``, ``-z``, ... or a comma-separated vector (``1,0,-1``)."""
    axes = {"x": 0, "y": 1, "z": 2}
    name = text.strip().lower()
    if name.lstrip("+-") in axes:
        axis = axes[name.lstrip("+-")]
        if axis >= dim:
            raise ValueError(f"--direction {text} is not an axis of this {dim}D scene")
        direction = np.zeros(dim)
        direction[axis] = -1.0 if name.startswith("-") else 1.0
        return direction
    try:
        direction = np.array([float(v) for v in name.split(",")])
    except ValueError:
        direction = np.zeros(0)
    if direction.shape != (dim,) or not np.all(np.isfinite(direction)) or not np.any(direction):
        raise ValueError(
            f"--direction must be x, y or z with an optional sign, or {dim} comma-separated numbers "
            f"not all zero, got {text!r}"
        )
    return direction


def _resume_command(argv) -> str:
    """The command line that resumes an interrupted search (the same options, --resume instead of --overwrite)."""
    import shlex

    words = [w for w in argv if not _is_option(w, "--overwrite")]
    resumed = any(_is_option(w, "--resume") for w in words)
    return shlex.join(["skfem-modal", *words] + ([] if resumed else ["--resume"]))


def _next_command(argv, generations: int) -> str:
    """What to run after a search stopped: resume its checkpoint, or (none made yet) start it again."""
    import shlex

    if generations:
        return f"resume it with: {_resume_command(argv)}"
    return f"start it again with: {shlex.join(['skfem-modal', *(w for w in argv if not _is_option(w, '--resume'))])}"


def _is_option(word: str, option: str) -> bool:
    """Whether ``word`` is ``option`` as argparse took it: whole, or a prefix of it (``--overw``)."""
    return word.startswith("--") and len(word) > 2 and option.startswith(word)


#: Options whose value may start with "-" (``--direction -x``): argparse would read it as an option.
_SIGNED_VALUES = {"--direction": re.compile(r"-(?:[xyz]|[0-9.])", re.IGNORECASE)}
# a negative number as a value (argparse's own takes -1 and -0.5 but not -1e6, -inf or -nan, which it read as options)
_NEGATIVE_NUMBER = re.compile(r"-(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?$|-inf(?:inity)?$|-nan$", re.IGNORECASE)


def _joined_signed_values(argv: list[str], single=None) -> list[str]:
    """``--direction -x`` as ``--direction=-x`` (and ``-1,0``): argparse reads it as the option's value
    (then checked and refused, or taken, by name).

    ``single``: the options that take one value (default: those of :func:`build_parser`); a word after a flag,
    an option of several values or ``--`` is left alone. (Negative numbers need no joining: the parsers of
    :func:`build_parser` take every one as a value, :data:`_NEGATIVE_NUMBER`.)
    """
    single = _single_value_options(build_parser()) if single is None else single
    words = []
    for word in argv:
        if word == "--" and "--" not in words:
            words.append(word)
            continue
        option = words[-1] if words and "--" not in words and words[-1] in single else None
        pattern = _SIGNED_VALUES.get(option)
        if pattern is not None and pattern.match(word):
            words[-1] = f"{words[-1]}={word}"
        else:
            words.append(word)
    return words


def _single_value_options(parser) -> set[str]:
    """The long options of ``parser`` and of its commands that take exactly one value."""
    return {
        name
        for p in _all_parsers(parser)
        for action in p._actions
        if action.nargs is None and action.option_strings
        for name in action.option_strings
        if name.startswith("--")
    }


def _commands(parser) -> dict:
    """The parsers of ``parser``'s commands, by name."""
    return {
        name: p for a in parser._actions if isinstance(a, argparse._SubParsersAction) for name, p in a.choices.items()
    }


def _unknown_before_a_command(parser, given) -> None:
    """With no command word given, an option the program does not know is the error to say, not the command
    missing (``skfem-modal --bogus`` said only that a command is required)."""
    (choices,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    choices.required = False
    try:
        _, unknown = parser.parse_known_args(given)
    finally:
        choices.required = True
    if unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")


def _all_parsers(parser) -> list:
    """``parser`` and the parsers of its commands."""
    return [parser, *_commands(parser).values()]


def cmd_optimize(args) -> int:
    """``skfem-modal optimize``: the CMA-ES gait search (:func:`~skfem_modal.optimize.run_search`) into ``--out``.

    ``args``: the options :func:`build_parser` parsed for ``optimize``, and ``args.argv`` (the command line's
    words, for the command that resumes a stopped search). Returns :data:`EXIT_OK`; a search stopped by
    Ctrl-C returns :data:`~skfem_modal.interrupts.EXIT_INTERRUPTED`, and one that lost its workers
    :data:`EXIT_WORKERS_LOST`, each saying on stderr (even with ``-q``) what its checkpoint holds and how to
    resume it or start it again. Bad input (a scene error, a ``--direction`` that is no direction of the
    scene, a search in ``--out`` without ``--resume`` or ``--overwrite``) raises, for :func:`main`.
    """
    from .optimize import GaitSpace, SearchInterrupted, SearchStop, run_search
    from .scene import DEFAULT_SCENE, Scene

    data, base_dir = _scene_data(args.scene, DEFAULT_SCENE)
    scene = Scene.from_dict(data, base_dir=base_dir)
    direction = _direction(args.direction, scene.dim)
    space = GaitSpace(scene.config["muscles"]["count"], args.amplitude_max, *args.period_range)
    say = _say(args)
    banner = (
        f"CMA-ES over {3 * space.m} gait parameters ({args.objective} along {direction.tolist()}): "
        f"{args.generations} generations of {args.popsize}, seed {args.seed}, writing to {args.out}"
    )
    try:
        result = run_search(
            data,
            args.out,
            generations=args.generations,
            popsize=args.popsize,
            sigma0=args.sigma0,
            seed=args.seed,
            steps=args.steps,
            base_dir=base_dir,
            direction=direction,
            objective=args.objective,
            space=space,
            tip_limit_degrees=args.tip_limit,
            tip_weight=args.tip_weight,
            samples=args.samples,
            jitter=args.jitter,
            resume=args.resume,
            overwrite=args.overwrite,
            workers=args.workers,
            scheduler=args.scheduler,
            blas_threads=args.blas_threads,
            progress=not args.quiet,
            announce=lambda: say(banner),  # once every setting is checked: an error is said alone
        )
    except SearchStop as stop:
        # said even with --quiet: the one thing a stopped search's user needs
        print(f"skfem-modal optimize: {stop}", file=sys.stderr)
        print(_next_command(args.argv, stop.generations), file=sys.stderr)
        return EXIT_INTERRUPTED if isinstance(stop, SearchInterrupted) else EXIT_WORKERS_LOST
    best = result["best"]
    if best["physical"] == 0.0:  # (said even with --quiet, as an error is)
        print(
            f"skfem-modal optimize: no gait moved the body physically: every one of the {result['rollouts']} rollouts, "
            "the start gait's included, went non-finite or tore the body apart (the motion monitor's rules); "
            f"{result['best_scene']} holds the start gait, which failed too: give the scene a gait that runs, "
            "or search smaller amplitudes (--amplitude-max)",
            file=sys.stderr,
        )
        return EXIT_NUMERICAL
    if result["converged"]:
        say(
            f"converged after {result['generations']} of {args.generations} generations: CMA-ES's steps fell below "
            "1e-11 of the search box (its candidates are one gait), so the rest would roll the same gait out again"
        )
    say(
        f"best: travel {best['travel']:.4g}, alignment {best['alignment']:.3g} (fitness {best['fitness']:.4g}"
        + (f", travel spread {best['travel_spread']:.3g} over {args.samples} samples" if args.samples > 1 else "")
        + (f") in generation {best['generation']}; " if best["generation"] else ") in the gait it started from; ")
        + f"{result['rollouts']} rollouts in {result['seconds']:.1f} s"
    )
    play = f"skfem-modal run {result['best_scene']} --out OUT"
    say(f"wrote {result['best_scene']} (play it: {play}), {result['history_csv']}")
    return EXIT_OK


def cmd_transfer(args) -> int:
    """``skfem-modal transfer``: replay a finished search's best gait with more accurate settings, and print
    how much of its travel survives (a markdown table, none with ``-q``;
    :func:`~skfem_modal.transfer.transfer_search` writes ``transfer.csv`` in the search's folder).

    ``args``: the options :func:`build_parser` parsed for ``transfer`` (the search folder,
    ``--full-space-limit``). Returns :data:`EXIT_OK`; a search stopped before its generations were done
    is said in a warning (its best so far is replayed); a folder without a finished search raises.
    """
    from .transfer import transfer_search

    def say(label):
        if not args.quiet:
            print(f"  replaying: {label}", file=sys.stderr, flush=True)

    result = transfer_search(args.search, full_space_limit=args.full_space_limit, progress=say)
    if result["unfinished"]:
        warnings.warn(result["unfinished"], UserWarning, stacklevel=1)
    if not args.quiet:
        print(
            "| setting | elements | coordinates | clusters | iterations (mean) | travel | survives | alignment "
            "| largest tilt | s |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for r in result["rows"]:
            survives = f"{r['survives']:.2f}" if r.get("physical", True) else "not physical"
            if r.get("tipped") and r.get("physical", True):
                survives += " (tipped over)"
            print(
                f"| {r['setting']} | {r['elements']} | {r['coordinates']} | {r['clusters']} | "
                f"{r['iterations']} ({r['mean_iterations']:.1f}) | {r['travel']:.4g} | {survives} | "
                f"{r['alignment']:.3f} | {r['max_tilt_degrees']:.1f} | {r['seconds']:.1f} |"
            )
        if not result["rows"][0].get("physical", True):
            print(
                "the searched gait's own replay is not physical (a body torn apart, or gone non-finite): what "
                "survives of its travel says nothing of the gait"
            )
        if any(r.get("tipped") for r in result["rows"]):
            print(
                f"tipped over: the body tilted more than the search's tip limit ({result['tip_limit_degrees']:.4g} "
                "degrees) in that replay, so its travel is partly a tumble's; its fitness (transfer.csv) has the "
                "penalty"
            )
        for sentence in result["not_replayed"]:
            print(f"{sentence} (--full-space-limit)")
        searched = result["rows"][0]["travel"]
        if searched < 0:
            print(
                f"the search's own travel is {searched:.4g}, backwards: survives is each replay's travel along the "
                f"direction over {-searched:.4g}, negative backwards (-1: as the search's)"
            )
        print(f"wrote {result['csv']}")
    return EXIT_OK


class _OneLineErrors(argparse.ArgumentParser):
    """A parser whose errors are one line, as the command line's other bad input (argparse's add a usage block)."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (options: {self.prog} --help)\n")


class _HelpWithDefaults(argparse.HelpFormatter):
    """Help that ends each option with its default, where it has one worth saying."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        # by identity: a default of 0 (--seed) is worth saying, though 0 == False
        if (
            not action.option_strings
            or "default" in text
            or any(default is no for no in (None, False, argparse.SUPPRESS))
        ):
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (tuple, list)) else "%(default)s"
        return f"{text} (default: {shown})"


def _popsize(text: str) -> int:
    value = _positive_int(text)
    if value < 2:
        raise argparse.ArgumentTypeError(f"expected at least 2 (CMA-ES ranks the candidates), got {text!r}")
    return value


def _jitter(text: str) -> float:
    value = _non_negative_float(text)
    if value >= 0.5:  # a copy's period could then be scaled to zero or below
        raise argparse.ArgumentTypeError(f"expected a number in [0, 0.5), got {text!r}")
    return value


def _positive_int(text: str) -> int:
    value = int(text) if text.lstrip("+-").isdigit() else None
    if value is None or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _float_in(low: float, what: str, *, open_low: bool):
    """An argparse type: a finite number above ``low`` (``open_low``) or at least ``low``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = np.nan
        if not (np.isfinite(value) and (value > low if open_low else value >= low)):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return value

    return parse


_positive_float = _float_in(0.0, "a positive finite number", open_low=True)
_non_negative_float = _float_in(0.0, "a finite number >= 0", open_low=False)
_finite_float = _float_in(-np.inf, "a finite number", open_low=True)


def _seed(text: str) -> int:
    from .optimize import SEED_MAX, _check_seed

    try:
        value = int(text)
        _check_seed(value)  # the library's one rule
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to {SEED_MAX}, got {text!r}") from None
    return value


def _size(text: str, problem_of) -> tuple[int, int]:
    width, x, height = text.lower().partition("x")
    if not (x and width.isdigit() and height.isdigit()):
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT in pixels, got {text!r}")
    size = int(width), int(height)
    problem = problem_of(size)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return size


def _picture_size(text: str) -> tuple[int, int]:
    from .plot import picture_size_problem

    return _size(text, picture_size_problem)


def _window_size(text: str) -> tuple[int, int]:
    from .play import window_size_problem

    return _size(text, window_size_problem)


def cmd_play(args) -> int:
    """``skfem-modal play``: the live window on a scene (:func:`~skfem_modal.play.play`).

    ``args``: the options :func:`build_parser` parsed for ``play``. Returns :data:`EXIT_OK`, or
    :data:`EXIT_BAD_INPUT` when the window cannot open here (:class:`~skfem_modal.play.PlayError`, said on
    stderr).
    """
    from .play import PlayError, play

    say = _say(args)
    try:
        play(
            args.scene,
            gait_on=not args.no_gait,
            frames=args.frames,
            screenshot=args.screenshot,
            off_screen=args.off_screen,
            window_size=args.size,
            follow=not args.no_follow,
            say=say,
        )
    except PlayError as err:
        print(f"skfem-modal play: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_OK


def _modes_options(p) -> None:
    p.add_argument(
        "mesh",
        nargs="?",
        default="caterpillar",
        help="mesh file (any format meshio reads) or built-in NAME[:key=value,...] "
        "(caterpillar, beam2d, beam3d, box3d, creature; parameters and defaults: "
        "skfem-modal info --scene-reference); default: caterpillar",
    )
    p.add_argument(
        "-k",
        type=_positive_int,
        help="number of modes, rigid ones included "
        f"(default: the rigid motions, any hinges and {ELASTIC_MODES} elastic modes)",
    )
    # (checked as the options are read, before the mesh is: a bad --rho was named 'rho' after loading it)
    p.add_argument("--mu", type=_positive_float, help="Lame shear modulus (default 1)")
    p.add_argument("--lam", type=_finite_float, help="Lame first parameter (default 1)")
    p.add_argument("--young", type=float, help="Young's modulus (with --poisson, instead of --mu/--lam)")
    p.add_argument("--poisson", type=float, help="Poisson's ratio (2D meshes: plane strain)")
    p.add_argument("--rho", type=_positive_float, default=1.0, help="density")
    p.add_argument("--element", choices=["P1", "P2"], default="P1", help="linear or quadratic elements")
    p.add_argument(
        "--mass",
        choices=["lumped", "consistent"],
        default=None,
        help="mass matrix (default: lumped for P1, consistent for P2: each element's frequencies converge fastest)",
    )
    p.add_argument(
        "--fix",
        action="append",
        metavar="COND",
        help="pin the vertices where COND holds, e.g. 'x <= 0' or 'x == min' (repeatable)",
    )
    p.add_argument(
        "--max-s", type=_positive_float, default=2.0, help="gradient change (Frobenius norm) that defines the ceilings"
    )
    p.add_argument("--out", default="modes.vtu", help="output .vtu file")
    _merge_option(p)


def _merge_option(p) -> None:
    p.add_argument(
        "--merge",
        action="store_true",
        help="merge the mesh file's coincident vertices (a triangle soup, as OBJ and STL exports write)",
    )


#: The picture options and their defaults (``run`` takes them only with ``--render``).
RENDER_DEFAULTS = {"backend": "auto", "format": "gif", "max_frames": 120, "size": "1280x720"}


def _render_options(p, unset: bool = False) -> None:
    """The picture options; ``unset``: default None, so that :func:`_picture_options` tells which were given."""
    default = (lambda name: None) if unset else RENDER_DEFAULTS.get

    def said(text, name):  # (the help's default, which argparse leaves out for None)
        return f"{text} (default: {RENDER_DEFAULTS[name]}, with --render)" if unset else text

    p.add_argument(
        "--backend",
        choices=["auto", "pyvista", "matplotlib"],
        default=default("backend"),
        help=said("auto: pyvista where off-screen OpenGL works, else matplotlib", "backend"),
    )
    p.add_argument(
        "--format", choices=["gif", "mp4"], default=default("format"), help=said("animation format", "format")
    )
    p.add_argument(
        "--max-frames",
        type=_positive_int,
        default=default("max_frames"),
        help=said("frames in the animation, at most", "max_frames"),
    )
    p.add_argument(
        "--size",
        type=_picture_size,
        default=default("size"),
        metavar="WxH",
        help=said("picture size in pixels (text and lines grow with it)", "size"),
    )


def _picture_options(args) -> None:
    """``run``'s picture options: refused without ``--render`` (they would change nothing), else defaults filled."""
    given = [f"--{name.replace('_', '-')}" for name in RENDER_DEFAULTS if getattr(args, name) is not None]
    if given and not args.render:
        raise ValueError(
            f"{', '.join(given)} {'sets' if len(given) == 1 else 'set'} the pictures, which run draws only with "
            "--render: add --render (or leave them out)"
        )
    for name, value in RENDER_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, _picture_size(value) if name == "size" else value)


def _run_options(p) -> None:
    p.add_argument("scene", nargs="?", help="scene .toml file (default: the built-in caterpillar crawl)")
    p.add_argument("--out", default="out", help="output directory")
    p.add_argument(
        "--overwrite", action="store_true", help="replace an earlier run in --out (only its files are removed)"
    )
    p.add_argument("--every", type=_positive_int, help="write every k-th frame (default: the scene's output.every)")
    p.add_argument("--render", action="store_true", help="also draw pictures and an animation (plot extra)")
    _render_options(p, unset=True)


def _info_options(p) -> None:
    p.add_argument("target", nargs="?", help="scene .toml, mesh file or built-in NAME (default: the built-in scene)")
    p.add_argument("--scene-reference", action="store_true", help="print the scene file reference (markdown)")
    _merge_option(p)


def _pool_options(p, workers: int, workers_help: str, what: str) -> None:
    """--workers and --scheduler: where a command's many runs go (a local pool, or dask)."""
    p.add_argument("--workers", type=_positive_int, default=workers, help=workers_help)
    p.add_argument("--scheduler", help=f"address of a dask.distributed scheduler to run the {what} on")


def _study_options(p) -> None:
    p.add_argument("scene", nargs="?", help="scene .toml (default: the floating caterpillar)")
    p.add_argument("--out", default="study", help="output directory")
    p.add_argument(
        "--overwrite", action="store_true", help="replace an earlier study in --out (only its files are removed)"
    )
    p.add_argument("--quick", action="store_true", help="the short preset (about a minute on 2 cores)")
    _pool_options(p, 1, "processes of the local pool (1: clean timings)", "sweep")


def _optimize_options(p) -> None:
    p.add_argument("scene", nargs="?", help="scene .toml (default: the built-in caterpillar crawl)")
    p.add_argument("--generations", type=_positive_int, default=20, help="CMA-ES generations")
    p.add_argument("--popsize", type=_popsize, default=12, help="candidates per generation (at least 2)")
    p.add_argument("--seed", type=_seed, default=0, help="the same seed gives the same search (0 to 4294967294)")
    p.add_argument(
        "--sigma0", type=_positive_float, default=0.2, help="CMA-ES's first step size, a share of the search box"
    )
    p.add_argument("--steps", type=_positive_int, help="rollout length in steps (default: the scene's)")
    p.add_argument(
        "--direction",
        default="x",
        help="travel direction: x, -x, y, -y, z, -z or a vector such as 1,0,-1 (any direction, in 3D too)",
    )
    p.add_argument(
        "--objective",
        choices=["travel", "aligned"],
        default="travel",
        help="travel: the centre of mass's travel; aligned: travel x alignment of the body with the direction "
        "(the paper's)",
    )
    p.add_argument(
        "--amplitude-max",
        type=_positive_float,
        default=1.0,
        help="largest amplitude (beyond 1: a warning), a fraction of the muscle's ceiling",
    )
    p.add_argument(
        "--period-range",
        type=_positive_float,
        nargs=2,
        default=(0.3, 2.0),
        metavar=("MIN", "MAX"),
        help="shortest and longest gait period",
    )
    p.add_argument(
        "--tip-limit",
        type=_non_negative_float,
        default=60.0,
        help="tilt in degrees beyond which the tipping penalty starts",
    )
    p.add_argument(
        "--tip-weight",
        type=_non_negative_float,
        default=10.0,
        help="body sizes lost per half turn of tilt past the limit",
    )
    p.add_argument(
        "--samples",
        type=_positive_int,
        default=1,
        help="rollouts per candidate: its gait and jittered copies, fitness their mean",
    )
    p.add_argument("--jitter", type=_jitter, default=0.01, help="relative size of the copies' changes (below 0.5)")
    p.add_argument("--out", default="search", help="output directory")
    resume = p.add_mutually_exclusive_group()
    resume.add_argument("--resume", action="store_true", help="continue the search checkpointed in --out")
    resume.add_argument("--overwrite", action="store_true", help="start again, replacing the search in --out")
    _pool_options(p, 2, "processes of the local pool", "rollouts")
    p.add_argument("--blas-threads", type=_positive_int, default=1, help="BLAS threads per worker")


def _play_options(p) -> None:
    p.add_argument("scene", nargs="?", help="scene .toml file (default: the built-in caterpillar crawl)")
    p.add_argument(
        "--frames",
        type=_positive_int,
        metavar="N",
        help="scripted: draw N frames with the gait on, print the frame rate, close",
    )
    p.add_argument("--screenshot", metavar="PATH", help="save the last frame as a PNG")
    p.add_argument("--off-screen", action="store_true", help="render without a window (needs --frames)")
    p.add_argument("--size", type=_window_size, default="960x600", metavar="WxH", help="window size in pixels")
    p.add_argument("--no-gait", action="store_true", help="start with the sliders driving the muscles")
    p.add_argument("--no-follow", action="store_true", help="keep the camera still as the body travels")


def _transfer_options(p) -> None:
    p.add_argument("search", nargs="?", default="search", help="the folder of a finished search (default: search)")
    p.add_argument(
        "--full-space-limit",
        type=_positive_int,
        default=10_000,
        help="largest mesh (elements) also replayed in the full space",
    )


def _render_command_options(p) -> None:
    p.add_argument("run_dir", help="directory written by 'skfem-modal run'")
    _render_options(p)


#: The subcommands, in the order ``--help`` lists them: name, help, its options, what runs it,
#: and what ``-q`` says (the last option; None: no ``-q``).
_COMMANDS = (
    ("modes", "linear vibration modes of a mesh, written for ParaView", _modes_options, cmd_modes, "print nothing"),
    (
        "run",
        "run a scene (default: the tutorial's caterpillar crawl)",
        _run_options,
        cmd_run,
        "no progress, no messages (warnings and errors only)",
    ),
    ("info", "what a scene or mesh holds: sizes, effects, material", _info_options, cmd_info, None),
    (
        "study",
        "accuracy against cost: the reduced simulator against the full-space reference",
        _study_options,
        cmd_study,
        "print nothing",
    ),
    (
        "optimize",
        "search the gait that travels furthest (CMA-ES)",
        _optimize_options,
        cmd_optimize,
        "print nothing but errors and how to resume",
    ),
    ("play", "a live window: sliders (or the gait) drive the muscles", _play_options, cmd_play, "print nothing"),
    (
        "transfer",
        "replay a search's best gait with more accurate settings: how much travel survives",
        _transfer_options,
        cmd_transfer,
        "print nothing",
    ),
    ("render", "pictures and an animation of a finished run", _render_command_options, cmd_render, "print nothing"),
)


def build_parser() -> argparse.ArgumentParser:
    """The ``skfem-modal`` argument parser, one subparser a subcommand (:data:`_COMMANDS`)."""
    from . import __version__

    parser = _OneLineErrors(
        prog="skfem-modal",
        description="Linear modal analysis and modal-muscle soft-body simulation on scikit-fem.",
        formatter_class=_HelpWithDefaults,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for name, summary, add_options, run, quiet in _COMMANDS:
        p = sub.add_parser(name, help=summary, formatter_class=_HelpWithDefaults)
        add_options(p)
        if quiet is not None:
            p.add_argument("-q", "--quiet", action="store_true", help=quiet)
        p.set_defaults(func=run)
    for each in _all_parsers(parser):
        # (argparse's own test of a negative number, which decides whether a word is a value: see _NEGATIVE_NUMBER)
        each._negative_number_matcher = _NEGATIVE_NUMBER
    return parser


def main(argv=None) -> int:
    """Entry point of the ``skfem-modal`` console script.

    Parameters
    ----------
    argv : list of str, optional
        The command line's words after the program name (default: ``sys.argv[1:]``).

    Returns
    -------
    code : int
        The exit code (the module docs list them): the command's own, or the one its error maps to, the
        error said on stderr as ``skfem-modal COMMAND: ...``.

    Raises
    ------
    SystemExit
        From the parser: ``--help`` and ``--version`` (code 0), and a usage error (code
        :data:`EXIT_BAD_INPUT`, said in one line).
    """
    parser = build_parser()
    given = list(sys.argv[1:] if argv is None else argv)
    if not set(given) & set(_commands(parser)):
        _unknown_before_a_command(parser, given)
    args, unknown = parser.parse_known_args(_joined_signed_values(given, _single_value_options(parser)))
    if unknown:  # said by the parser they were given to: the command's (naming it and its help), or the top's
        before = given[: given.index(args.command)] if args.command in given else []
        said_by = parser if any(word in before for word in unknown) else _commands(parser)[args.command]
        said_by.error(f"unrecognized arguments: {' '.join(unknown)}")
    args.argv = given
    try:
        with warnings.catch_warnings(), terminate_as_interrupt():
            warnings.showwarning = _warning_printer(args.command)
            code = args.func(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's last flush
        return code
    except BrokenPipeError:
        return _reader_gone()
    except WorkersLost as lost:  # a study's; a search's says how to resume (cmd_optimize)
        print(f"skfem-modal {args.command}: {lost}", file=sys.stderr)
        return EXIT_WORKERS_LOST
    except OutputError as err:  # (an OSError) a file a run writes as it goes: a disk full
        print(f"skfem-modal {args.command}: outputs failed: {err}", file=sys.stderr)
        return EXIT_OUTPUTS
    except (ValueError, TypeError, OSError, _RenderUnavailable) as err:
        # MeshError and SceneError are ValueErrors; OSError: missing files, an output folder in use
        if isinstance(err, OSError) and err.errno in _NO_ROOM:  # a render's, a study's, a search's file
            print(f"skfem-modal {args.command}: outputs failed: {_no_room(err)}", file=sys.stderr)
            return EXIT_OUTPUTS
        print(f"skfem-modal {args.command}: error: {err}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except FloatingPointError as err:  # the modal analysis's: an eigen solve that stalled or lost its precision
        print(f"skfem-modal {args.command}: numerical failure: {err}", file=sys.stderr)
        return EXIT_NUMERICAL
    except KeyboardInterrupt as stop:
        # Ctrl-C, or SIGTERM (e.g. from timeout): the command has stopped as it does on Ctrl-C
        print(f"skfem-modal {args.command}: {_stopped(stop)}", file=sys.stderr)
        return EXIT_INTERRUPTED


def _shown(values) -> list:
    """Numbers for a printed line, to 4 significant digits (rounded to 4 decimals, a box 2e-6 across read 0)."""
    return [float(f"{value:.4g}") for value in values]


def _stopped(stop: KeyboardInterrupt) -> str:
    """How a command was stopped, in words: by SIGTERM or by Ctrl-C."""
    return "terminated (SIGTERM)" if isinstance(stop, Terminated) else "interrupted"


def _written_status(out) -> str | None:
    """The ``status`` a run's ``summary.json`` in ``out`` holds, None if there is none to read."""
    try:
        with open(os.path.join(out, "summary.json"), encoding="utf-8") as f:
            return json.load(f).get("status")
    except (OSError, ValueError, AttributeError):
        return None


def _no_room(err: OSError) -> str:
    """A write that found no room, in words: the file (when named) and why, without the errno."""
    return f"could not write {err.filename}: {err.strerror}" if err.filename else str(err.strerror)


def _warning_printer(command: str):
    """``warnings.showwarning`` for the command line: every warning as ``skfem-modal COMMAND: warning: ...``.

    The library's warnings (scales, rounded durations, settings without effect,
    numpy's overflows) name the problem in their message; the file and source
    line that raised them mean nothing to a user of the command. Each is said
    once (a study builds a scene's simulator once per setting).
    """
    said = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = f"skfem-modal {command}: warning: {message}"
        if text not in said:
            said.add(text)
            print(text, file=sys.stderr, flush=True)

    return show


def _reader_gone() -> int:
    """The reader of our output went away (``| head``): stop quietly, as other tools do."""
    try:
        # what is still buffered for stdout goes nowhere, not into a second error at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # no real file behind sys.stdout
        pass
    return EXIT_PIPE_CLOSED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
