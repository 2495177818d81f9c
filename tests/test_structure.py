"""The package's shape: functions and classes small enough to read (the core's own rule).

Lines of code: lines with code on them, docstrings, comments and blank lines
not counted. At most two functions over 80 such lines, no class over 400.
"""

import ast
import importlib
import inspect
import pathlib
import pkgutil
import re
import textwrap

import skfem_modal

PACKAGE = pathlib.Path(skfem_modal.__file__).parent
LONGEST_FUNCTION, LONG_FUNCTIONS_ALLOWED, LONGEST_CLASS = 80, 2, 400


def _docstring_lines(node) -> set:
    """Line numbers of the docstrings of ``node`` and of everything defined inside it."""
    lines = set()
    for inner in ast.walk(node):
        if isinstance(inner, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and ast.get_docstring(inner):
            first = inner.body[0]
            lines.update(range(first.lineno, first.end_lineno + 1))
    return lines


def code_lines(node, source_lines) -> int:
    """Lines of code of a function or class (docstrings, comments and blank lines excluded)."""
    skipped = _docstring_lines(node)
    first = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])])
    texts = (source_lines[number - 1].strip() for number in range(first, node.end_lineno + 1) if number not in skipped)
    return sum(1 for text in texts if text and not text.startswith("#"))


def definitions():
    """``(kind, "module.name", lines of code)`` of every function and class of the package."""
    found = []
    for path in sorted(PACKAGE.glob("*.py")):
        source = path.read_text()
        lines = source.splitlines()
        for node in ast.walk(ast.parse(source)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                kind = "class" if isinstance(node, ast.ClassDef) else "function"
                found.append((kind, f"{path.stem}.{node.name}", code_lines(node, lines)))
    return found


def test_counting_skips_docstrings_comments_and_blank_lines():
    source = 'def f(x):\n    """Doc.\n\n    More.\n    """\n    # why\n\n    y = x\n    return y\n'
    (node,) = ast.parse(source).body
    assert code_lines(node, source.splitlines()) == 3


def test_at_most_two_functions_over_80_lines_of_code():
    found = definitions()
    assert sum(kind == "function" for kind, _, _ in found) > 300  # the whole package was read
    long = sorted((n, name) for kind, name, n in found if kind == "function" and n > LONGEST_FUNCTION)
    assert len(long) <= LONG_FUNCTIONS_ALLOWED, f"functions over {LONGEST_FUNCTION} lines of code: {long}"


def test_no_class_over_400_lines_of_code():
    found = definitions()
    assert sum(kind == "class" for kind, _, _ in found) > 20
    long = sorted((n, name) for kind, name, n in found if kind == "class" and n > LONGEST_CLASS)
    assert not long, f"classes over {LONGEST_CLASS} lines of code: {long}"


# ------------------------------------------------------------ the public API's docstrings

_SECTIONS = {"Returns", "Yields", "Raises", "Attributes", "Examples", "Notes", "See Also", "Warns", "References"}


def documented_parameters(doc, section="Parameters") -> set | None:
    """The names a numpydoc section lists (``a, b : type`` lists two), None without the section."""
    lines = inspect.cleandoc(doc or "").splitlines()
    if section not in lines:
        return None
    names = set()
    for line in lines[lines.index(section) + 2 :]:
        if line in _SECTIONS | {"Parameters"}:
            break
        entry = re.match(r"(\*{0,2}\w+(?:, \*{0,2}\w+)*)(?: :|$)", line)
        if entry and not line.startswith(" "):
            names |= {name.strip().lstrip("*") for name in entry.group(1).split(",")}
    return names


def named_in(doc) -> set:
    """The names a docstring gives: entries of its Parameters and Attributes sections, and ````name```` in its text."""
    listed = (documented_parameters(doc) or set()) | (documented_parameters(doc, "Attributes") or set())
    return listed | set(re.findall(r"``(\w+)", doc or ""))


def _callables_of(namespace, names):
    """``(name, docstring, function)`` of the functions, classes (their constructors) and methods among ``names``.

    A method that overrides another without a docstring of its own has the one it overrides (as
    ``help`` and Sphinx show it).
    """
    for name in names:
        obj = getattr(namespace, name)
        if inspect.isclass(obj):
            yield name, obj.__doc__, obj.__init__
            for method_name, method in vars(obj).items():
                function = getattr(method, "__func__", method)
                if not method_name.startswith("_") and inspect.isfunction(function):
                    yield f"{name}.{method_name}", inspect.getdoc(getattr(obj, method_name)), function
        elif inspect.isfunction(obj):
            yield name, obj.__doc__, obj


def public_callables():
    """The package root's public callables (:func:`_callables_of`)."""
    yield from _callables_of(skfem_modal, skfem_modal.__all__)


def module_callables():
    """Every public module's own public callables, ``("module.name", docstring, function)``."""
    for info in pkgutil.iter_modules(skfem_modal.__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"skfem_modal.{info.name}")
        names = [n for n, obj in vars(module).items() if not n.startswith("_") and _defined_in(obj, module)]
        for name, doc, function in _callables_of(module, names):
            yield f"{info.name}.{name}", doc, function


def _defined_in(obj, module) -> bool:
    return (inspect.isclass(obj) or inspect.isfunction(obj)) and obj.__module__ == module.__name__


def undocumented(doc, parameters) -> tuple[list, list]:
    """``(missing, extra)``: parameters a docstring does not give, and names its Parameters section lists in vain.

    With a Parameters section it must list exactly ``parameters``. Without one (a method of one obvious
    argument, a record whose constructor takes its attributes) each parameter must be an entry of its
    Attributes section or named in ````double backquotes```` in its text.
    """
    parameters = [p for p in parameters if p not in ("self", "cls") and not p.startswith("_")]
    listed = documented_parameters(doc)
    if listed is not None:
        return [p for p in parameters if p not in listed], sorted(listed - set(parameters))
    return [p for p in parameters if p not in named_in(doc) | {"args", "kwargs"}], []


def _wrong_parameters(callables):
    """``(sections, named, wrong)``: callables with a Parameters section, without one but with several
    parameters named in their text, and a line for each whose docstring does not give its parameters."""
    sections, named, wrong = 0, 0, []
    for name, doc, function in callables:
        if function is object.__init__:
            continue
        parameters = list(inspect.signature(function).parameters)
        has_section = documented_parameters(doc) is not None
        sections += has_section
        named += not has_section and len(parameters) > 1
        missing, extra = undocumented(doc, parameters)
        if missing or extra or not doc:
            wrong.append(
                f"{name}: not documented {missing}, documented but not taken {extra}"
                + ("" if doc else ", no docstring")
            )
    return sections, named, wrong


def test_documented_parameters_are_the_signatures():
    """The root's public callables document their parameters by name (:func:`undocumented`)."""
    sections, named, wrong = _wrong_parameters(public_callables())
    assert sections >= 40 and named >= 10, (sections, named)  # (the package's API, not an empty walk)
    assert not wrong, "\n".join(wrong)


def test_every_public_function_of_every_module_documents_its_parameters():
    """Beyond the root: each public module's own public functions, classes and methods (:func:`undocumented`)."""
    sections, named, wrong = _wrong_parameters(module_callables())
    assert sections >= 150 and named >= 30, (sections, named)
    assert not wrong, f"{len(wrong)} callables:\n" + "\n".join(wrong)


def test_the_docstring_check_finds_a_misnamed_parameter():
    doc = "Do.\n\nParameters\n----------\nz, z_dot : ndarray, shape (r,)\nh : float\n    Step.\n\n"
    doc += "Returns\n-------\nx : int\n"
    assert documented_parameters(doc) == {"z", "z_dot", "h"}
    assert documented_parameters("One line.") is None
    assert undocumented(doc, ["z", "z_dot", "time"]) == (["time"], ["h"])  # h documented, time taken
    record = "A record.\n\nAttributes\n----------\ntime_ : float\nz : ndarray\n"
    assert undocumented(record, ["self", "time", "z"]) == (["time"], [])
    assert undocumented("Positions of a state ``z``.", ["self", "z"]) == ([], [])


def test_the_readme_module_table_names_every_module():
    """Each module of the package has its row in the README's module table (a new module gets one)."""
    readme = (PACKAGE.parent / "README.md").read_text()
    rows = [line for line in readme.splitlines() if line.startswith("| `")]
    named = set(re.findall(r"`(\w+\.py)`", "\n".join(rows)))
    modules = {path.name for path in PACKAGE.glob("*.py") if path.name != "__init__.py"}
    assert len(modules) > 40 and not modules - named, sorted(modules - named)


def _returns_a_value(function) -> bool:
    """Whether ``function``'s own body (not a function inside it) has a ``return`` of something other than None."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(function))).body[0]
    inner = {
        id(node) for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.Lambda)) and node is not tree
    }
    skipped = {id(n) for node in ast.walk(tree) if id(node) in inner for n in ast.walk(node)}
    return any(
        isinstance(node, ast.Return) and node.value is not None and not (
            isinstance(node.value, ast.Constant) and node.value.value is None)
        for node in ast.walk(tree) if id(node) not in skipped
    )  # fmt: skip


def test_a_documented_function_that_returns_says_what():
    """A public callable with a Parameters section that returns a value has a Returns (or Yields) section."""
    checked, wrong = 0, []
    for name, doc, function in module_callables():
        if function.__name__ == "__init__" or documented_parameters(doc) is None:
            continue
        checked += 1
        lines = set(inspect.cleandoc(doc).splitlines())
        if _returns_a_value(function) and not lines & {"Returns", "Yields"}:
            wrong.append(name)
    assert checked > 150 and not wrong, (checked, wrong)


def test_the_return_check_reads_only_the_function_itself():
    def outer(x):
        def inner():
            return x

        return None

    assert not _returns_a_value(outer) and _returns_a_value(_adds_one)


def _adds_one(x):
    """(A function that returns a value, for the test above.)"""
    return x + 1
