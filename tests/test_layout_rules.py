"""The layout's rules, read from the source: no module imports another's underscore names, no
import cycle between modules, and every import between FLAAIR packages points down the layers
(model and messages at the bottom, then the node plumbing, the domain packages, the tools).
"""

from __future__ import annotations

import ast
import io
import tokenize
from collections import defaultdict
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"

# Lower number, lower layer: a package may import only packages on a lower layer.
LAYERS = {
    "flaair_model": 0,
    "flaair_msgs": 0,
    "flaair_common": 1,
    "flaair_sim": 2,
    "flaair_sensors": 2,
    "flaair_control": 3,
    "flaair_bridge": 3,
    "flaair_analysis": 4,
    "flaair_tools": 5,
}


def _source_files(*dirs: Path) -> list[Path]:
    return sorted(
        p
        for d in dirs
        for p in d.rglob("*.py")
        if "build" not in p.relative_to(ROOT).parts and p.name != "setup.py"
    )


def _module_name(path: Path) -> str:
    """`flaair_analysis.discrepancy.fitting` for
    src/flaair_analysis/flaair_analysis/discrepancy/fitting.py.
    """
    parts = list(path.relative_to(SRC).parts[1:])
    parts[-1] = parts[-1][:-3]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _package_of(path: Path, module: str) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def _import_target(package: str, node: ast.ImportFrom) -> str:
    """The absolute module a `from ... import` in `package` names."""
    if not node.level:
        return node.module or ""
    base = package.split(".")[: len(package.split(".")) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


@cache
def _parsed_nodes(text: str, filename: str) -> tuple[ast.AST, ...]:
    return tuple(ast.walk(ast.parse(text, filename)))


def _nodes(path: Path) -> tuple[ast.AST, ...]:
    """Every node of the module at `path`, parsed once per text (the rules walk each module
    several times: 9 s of 14 went to parsing and walking again).
    """
    return _parsed_nodes(path.read_text(), str(path))


def _imports(path: Path, module: str) -> list[tuple[str, list[str], int]]:
    """(absolute module, imported names, line) of each import statement in `path`."""
    package = _package_of(path, module)
    found = []
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            found += [(alias.name, [], node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            target = _import_target(package, node)
            found.append((target, [alias.name for alias in node.names], node.lineno))
    return found


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _module_graph() -> tuple[dict[str, Path], dict[str, set[str]]]:
    modules = {_module_name(p): p for p in _source_files(SRC)}
    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        for target, names, _line in _imports(path, name):
            for candidate in [target] + [f"{target}.{n}" for n in names]:
                if candidate in modules and candidate != name:
                    graph[name].add(candidate)
    return modules, graph


def _imported_modules(path: Path, module: str, known: set[str]) -> dict[str, str]:
    """{name bound in `path`: the FLAAIR (or test helper) module it names} for each import that
    binds a module: `import a.b as m`, `import a.b` (binds `a`), `from a import b` (b a module).
    """
    bound = {}
    for target, names, _line in _imports(path, module):
        if not names:  # import statements: re-read to get their aliases
            continue
        for name in names:
            if f"{target}.{name}" in known:
                bound[name] = f"{target}.{name}"
    for node in _nodes(path):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name in known or alias.name.split(".")[0] in known:
                    if alias.asname:
                        bound[alias.asname] = alias.name
                    else:
                        top = alias.name.split(".")[0]
                        bound[top] = top
        elif isinstance(node, ast.ImportFrom):
            for alias in node.names:
                if alias.asname and alias.name in bound:
                    bound[alias.asname] = bound.pop(alias.name)
    return bound


def _dotted(node: ast.AST) -> list[str] | None:
    """['a', 'b', 'c'] for the expression a.b.c (None if it is not a plain dotted name)."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return [node.id, *reversed(parts)]


def _attribute_chains(path: Path, module: str, known: set[str]) -> list[tuple[list[str], int]]:
    """(absolute dotted parts, line) of every attribute chain read off an imported module."""
    bound = _imported_modules(path, module, known)
    chains = []
    for node in _nodes(path):
        parts = _dotted(node) if isinstance(node, ast.Attribute) else None
        if parts and parts[0] in bound:
            chains.append((bound[parts[0]].split(".") + parts[1:], node.lineno))
    return chains


def _private_attributes(path: Path, module: str, known: set[str]) -> list[tuple[str, int]]:
    """(module._name, line) of every underscore name read off another module by attribute."""
    found = []
    for path_parts, lineno in _attribute_chains(path, module, known):
        for i in range(1, len(path_parts)):
            owner = ".".join(path_parts[:i])
            if owner in known and _private(path_parts[i]) and owner != module:
                found.append((f"{owner}.{path_parts[i]}", lineno))
                break
    return sorted(set(found), key=lambda f: f[1])


def _all_modules() -> dict[Path, str]:
    """Every source file with its module name: src by package, tests, bench and scripts by stem."""
    return {
        path: _module_name(path) if SRC in path.parents else path.stem
        for path in _source_files(SRC, ROOT / "tests", ROOT / "bench", ROOT / "scripts")
    }


# Reads of another module's underscore names the rule lets pass, each with its reason.
PRIVATE_READS_ALLOWED = {
    # the benchmark reports whether the plant's kernels came from numba's cache: their dispatcher
    # statistics, which no public function gives
    ("bench/bench_sim.py", "flaair_sim.core.plant._run"),
    ("bench/bench_sim.py", "flaair_sim.core.plant._run_batch"),
    # the health monitor's per-block kernels must be compiled for one argument type: their
    # dispatchers' signatures, which no public function gives
    ("tests/test_health_monitor.py", "flaair_control.core.health._extended"),
    ("tests/test_health_monitor.py", "flaair_control.core.health._crossing_kernel"),
}


def test_no_module_imports_another_modules_underscore_names() -> None:
    """Neither `from m import _name` nor `m._name` after `import m` / `from pkg import m`."""
    modules = _all_modules()
    known = set(modules.values())
    known |= {".".join(m.split(".")[:i]) for m in known for i in range(1, m.count(".") + 1)}
    offences = []
    for path, module in modules.items():
        for target, names, line in _imports(path, module):
            private = [n for n in names if _private(n)]
            if private or any(_private(part) for part in target.split(".")[1:]):
                offences.append(
                    f"{path.relative_to(ROOT)}:{line}: from {target} import "
                    f"{', '.join(private or names)}"
                )
        where = str(path.relative_to(ROOT))
        for name, line in _private_attributes(path, module, known):
            if (where, name) not in PRIVATE_READS_ALLOWED:
                offences.append(f"{where}:{line}: {name}")
    assert offences == [], "underscore names are private to their module:\n" + "\n".join(offences)


def test_no_import_cycle_between_modules() -> None:
    _modules, graph = _module_graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        for succ in sorted(graph[node]):
            if succ not in index:
                visit(succ)
                low[node] = min(low[node], low[succ])
            elif succ in stack:
                low[node] = min(low[node], index[succ])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    assert cycles == [], f"modules that import each other: {cycles}"


@pytest.mark.slow  # walks every module's imports
def test_every_import_between_packages_points_down_the_layers() -> None:
    modules, _graph = _module_graph()
    packages = {p.name for p in SRC.iterdir() if (p / "package.xml").exists()}
    unmatched = packages ^ set(LAYERS)
    assert not unmatched, f"a package without a layer (or a layer without a package): {unmatched}"
    upward = []
    for name, path in modules.items():
        own = name.split(".")[0]
        for target, _names, line in _imports(path, name):
            other = target.split(".")[0]
            if other in LAYERS and other != own and LAYERS[other] >= LAYERS[own]:
                upward.append(
                    f"{path.relative_to(ROOT)}:{line}: {own} (layer {LAYERS[own]}) "
                    f"imports {other} (layer {LAYERS[other]})"
                )
    assert upward == [], "imports must point down the layers:\n" + "\n".join(upward)


@pytest.mark.parametrize(
    "source, offence",
    [
        ("from .fitting import _Fold\n", "_Fold"),
        ("from flaair_sim.core.plant import prepare, _rk4\n", "_rk4"),
    ],
)
def test_the_underscore_rule_catches_an_offence(tmp_path: Path, source: str, offence: str) -> None:
    path = tmp_path / "module.py"
    path.write_text(source)
    names = [n for _t, ns, _l in _imports(path, "pkg.module") for n in ns if _private(n)]
    assert names == [offence]


@pytest.mark.parametrize(
    "source, offence",
    [
        (
            "from flaair_control.core import dsa\n\ndsa._tf_coefficients(p, True)\n",
            "flaair_control.core.dsa._tf_coefficients",
        ),
        ("import flaair_common.cdr as cdr\n\ncdr._KINDS['bool']\n", "flaair_common.cdr._KINDS"),
        ("import flaair_common.cdr\n\nflaair_common.cdr._pad(1, 4)\n", "flaair_common.cdr._pad"),
    ],
)
def test_the_underscore_rule_catches_a_read_by_attribute(
    tmp_path: Path, source: str, offence: str
) -> None:
    path = tmp_path / "module.py"
    path.write_text(source)
    known = {"flaair_common", "flaair_common.cdr", "flaair_control.core", "flaair_control.core.dsa"}
    assert [name for name, _line in _private_attributes(path, "pkg.module", known)] == [offence]


def _unexplained_inner_imports(path: Path) -> list[int]:
    """Lines of the imports inside a function of `path` that do not say why they are there: a
    comment starting `# deferred` just above (a comment of several lines, above the first of
    imports on consecutive lines) or at the end of one of the import's lines.
    """
    text = path.read_text()
    why = set()  # lines holding a `# deferred...` comment
    alone = set()  # lines holding nothing but a comment
    for token in tokenize.generate_tokens(io.StringIO(text).readline):
        if token.type == tokenize.COMMENT:
            if token.string.lstrip("# ").startswith("deferred"):
                why.add(token.start[0])
            if not token.line[: token.start[1]].strip():
                alone.add(token.start[0])
    inner = {
        (node.lineno, node.end_lineno or node.lineno): node
        for function in ast.walk(ast.parse(text, str(path)))
        if isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef)
        for node in ast.walk(function)
        if isinstance(node, ast.Import | ast.ImportFrom)
    }
    explained: set[int] = set()  # last lines of the explained imports
    unexplained = []
    for first, last in sorted(inner):
        above = first - 1
        while above in alone and above not in why:
            above -= 1
        if above in (why & alone) | explained or why & set(range(first, last + 1)):
            explained.add(last)
        else:
            unexplained.append(first)
    return unexplained


@pytest.mark.slow  # tokenizes every module of the project
@pytest.mark.timeout(60)
def test_every_import_inside_a_function_says_why() -> None:
    """Imports sit at the top of the module; one kept inside a function (a heavy dependency on one
    optional path, or an import cycle) carries `# deferred: why` (e.g. what it costs to load).
    """
    offences = [
        f"{path.relative_to(ROOT)}:{line}"
        for path in _source_files(SRC)
        for line in _unexplained_inner_imports(path)
    ]
    assert offences == [], (
        "an import inside a function without a `# deferred: why` comment (move it to the top "
        "of the module, or say why it waits):\n" + "\n".join(offences)
    )


@pytest.mark.parametrize(
    "source, offences",
    [
        ("def f():\n    import json\n", [2]),
        ("def f():\n    # parse it\n    import json\n", [3]),  # a comment that says no why
        ("def f():\n    x = 1  # deferred: 1 s\n    import json\n", [3]),  # another line's
        ("def f():\n    # deferred: 1 s, and\n    # more\n    import a\n    import b\n", []),
        ("def f():\n    # deferred: 1 s\n    import a\n    import b\n\n    import c\n", [6]),
        ("class C:\n    def f(self):\n        from a import (\n            b,\n        )\n", [3]),
        (
            "def f():\n    import a  # deferred: 1 s\n    from b import (  # deferred: 1 s\n"
            "        c,\n    )\n",
            [],
        ),
        ("import json\n\n\ndef f():\n    # deferred: 1 s\n    import a\n", []),
    ],
)
@pytest.mark.timeout(10)
def test_the_inner_import_rule_catches_an_offence(
    tmp_path: Path, source: str, offences: list[int]
) -> None:
    path = tmp_path / "module.py"
    path.write_text(source)
    assert _unexplained_inner_imports(path) == offences


CORE_PACKAGES = ("flaair_sensors", "flaair_control", "flaair_sim", "flaair_bridge")


def _core_modules() -> dict[str, Path]:
    return {
        _module_name(p): p for pkg in CORE_PACKAGES for p in _source_files(SRC / pkg / pkg / "core")
    }


def test_each_domain_package_keeps_its_pure_cores_in_core() -> None:
    """A core imports no rclpy and no shell: from its own package only other cores, and from other
    FLAAIR packages only their cores, the model and the node plumbing's pure modules.
    """
    cores = _core_modules()
    assert {name.split(".")[0] for name in cores} == set(CORE_PACKAGES)
    offences = []
    for name, path in cores.items():
        for target, _names, line in _imports(path, name):
            top, _, rest = target.partition(".")
            shell_of_domain = top in CORE_PACKAGES and not (
                rest == "core" or rest.startswith("core.")
            )
            if top == "rclpy" or shell_of_domain:
                offences.append(f"{path.relative_to(ROOT)}:{line}: imports {target}")
    assert offences == [], "a core may import no rclpy and no shell module:\n" + "\n".join(offences)


@pytest.mark.slow  # imports every core in a new interpreter
@pytest.mark.timeout(120)
def test_importing_every_core_loads_no_rclpy() -> None:
    """Transitively too: the cores run offline (replay,
    sweeps, analysis) on a machine with no ROS.
    """
    import subprocess
    import sys

    names = sorted(_core_modules())
    code = (
        f"import importlib, sys\nfor name in {names!r}:\n    "
        "importlib.import_module(name)\nprint(sorted(m for m in sys.modules if m.split('.')[0] "
        "in ('rclpy', 'rosidl_runtime_py', 'rmw')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=110, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


SCIENCE = SRC / "flaair_analysis" / "flaair_analysis"
# What the science package must not load, even transitively: ROS, plots, templates, the tools.
NOT_IN_SCIENCE = ("rclpy", "rosidl_runtime_py", "rmw", "flaair_msgs", "matplotlib", "jinja2")


@pytest.mark.slow  # imports the science in a new interpreter
@pytest.mark.timeout(120)
def test_importing_the_science_loads_no_ros_plots_or_templates() -> None:
    """`import flaair_analysis` and every module in it, in a fresh interpreter: no rclpy, no ROS
    messages, no matplotlib, no Jinja2, and nothing of the tools above it.
    """
    import subprocess
    import sys

    names = sorted(_module_name(p) for p in _source_files(SCIENCE))
    assert "flaair_analysis.discrepancy.workflow" in names and "flaair_analysis" in names
    code = (
        f"import importlib, sys\nfor name in {names!r}:\n    importlib.import_module(name)\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in "
        f"{(*NOT_IN_SCIENCE, 'flaair_tools')!r}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=110, check=True
    )
    assert out.stdout.strip() == "[]", out.stdout


# flaair_tools is split by job; inside it, too, imports point down these layers.
TOOLS_LAYERS = {
    "bagio": 0,
    "recorder": 1,
    "roscli": 1,
    "analysis": 1,
    "tables": 1,
    "multisine": 1,
    "discrepancy": 2,
    "sweeps": 2,
    "liveview": 2,
    "orchestration": 3,
    "cli": 4,
}


def test_flaair_tools_is_split_by_job_and_its_imports_point_down() -> None:
    tools = SRC / "flaair_tools" / "flaair_tools"
    jobs = {p.name for p in tools.iterdir() if (p / "__init__.py").exists()}
    jobs |= {p.stem for p in tools.glob("*.py") if p.name != "__init__.py"}
    unmatched = jobs ^ set(TOOLS_LAYERS)
    assert not unmatched, f"a job without a layer (or a layer without a job): {unmatched}"
    modules, _graph = _module_graph()
    upward = []
    for name, path in modules.items():
        parts = name.split(".")
        if parts[0] != "flaair_tools" or len(parts) < 2:
            continue
        for target, names, line in _imports(path, name):
            tparts = target.split(".")
            if tparts[0] != "flaair_tools":
                continue
            others = [tparts[1]] if len(tparts) > 1 else names
            for other in others:
                if (
                    other in TOOLS_LAYERS
                    and other != parts[1]
                    and TOOLS_LAYERS[other] >= TOOLS_LAYERS[parts[1]]
                ):
                    upward.append(f"{path.relative_to(ROOT)}:{line}: {parts[1]} imports {other}")
    assert upward == [], "imports inside flaair_tools must point down its layers:\n" + "\n".join(
        upward
    )


def _bound_names(tree: ast.Module) -> set[str]:
    """Names an `__init__` binds at its top level (imports, definitions, assignments)."""
    names: set[str] = set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            names |= {alias.asname or alias.name for alias in node.names}
        elif isinstance(node, ast.Import):
            names |= {alias.asname or alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.FunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return {n for n in names if not n.startswith("_")}


def _declared_all(tree: ast.Module) -> list[str] | None:
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(
            getattr(t, "id", "") == "__all__" for t in node.targets
        ):
            return [ast.literal_eval(e) for e in node.value.elts]  # type: ignore[attr-defined]
    return None


def _toc_gaps(init: Path, root: Path = ROOT) -> list[str]:
    """What a package's `__init__` leaves out of its table of contents: a docstring that names
    (in backticks) every module and subpackage beside it, and an `__all__` that lists every
    public name the `__init__` binds and names only what exists.
    """
    tree = ast.parse(init.read_text())
    doc = ast.get_docstring(tree) or ""
    exported = _declared_all(tree)
    where = str(init.relative_to(root))
    if not doc or exported is None:
        return [f"{where}: no docstring or no __all__"]
    package = init.parent
    children = {p.stem for p in package.glob("*.py") if p.name != "__init__.py"}
    children |= {p.name for p in package.iterdir() if (p / "__init__.py").exists()}
    gaps = [
        f"{where}: the docstring does not name `{child}`"
        for child in sorted(children)
        if not child.startswith("_") and f"`{child}`" not in doc and f"`{child}/`" not in doc
    ]
    bound = _bound_names(tree)
    gaps += [f"{where}: __all__ lacks {name}" for name in sorted(bound - set(exported))]
    gaps += [
        f"{where}: __all__ names {name}, which the package neither binds nor holds"
        for name in exported
        if name not in bound and name not in children
    ]
    return gaps


def test_every_package_init_is_a_complete_table_of_contents() -> None:
    """Each package's `__init__` says what it holds (a docstring naming every module beside it)
    and exports it (an `__all__` with every public name it binds, and nothing it does not hold).
    """
    gaps = []
    for path in _source_files(SRC):
        if path.name == "__init__.py" and "msg" not in path.parts:
            gaps += _toc_gaps(path)
    assert gaps == [], "incomplete tables of contents:\n" + "\n".join(gaps)


def test_the_table_of_contents_rule_catches_a_missing_module_and_name(tmp_path: Path) -> None:
    package = tmp_path / "pkg"
    package.mkdir()
    (package / "__init__.py").write_text(
        '"""Modules: `listed`."""\n\nfrom .listed import shown, hidden\n\n'
        '__all__ = ["shown", "gone"]\n'
    )
    (package / "listed.py").write_text("shown = hidden = 1\n")
    (package / "unlisted.py").write_text("")
    gaps = _toc_gaps(package / "__init__.py", root=tmp_path)
    assert gaps == [
        "pkg/__init__.py: the docstring does not name `unlisted`",
        "pkg/__init__.py: __all__ lacks hidden",
        "pkg/__init__.py: __all__ names gone, which the package neither binds nor holds",
    ]


# One address per public name: a name is defined in one module and re-exported only by the
# `__init__` of a package that holds that module; every import names one of those addresses.


def _module_level(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """The statements that bind a module's names: its body and the branches of its `if`, `try`
    and `with` statements (not what functions and classes bind).
    """
    for node in body:
        yield node
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            continue
        for field in ("body", "orelse", "finalbody"):
            yield from _module_level(getattr(node, field, []))
        for handler in getattr(node, "handlers", []):
            yield from _module_level(handler.body)


@cache
def _from_imports(path: Path, module: str) -> dict[str, tuple[str, str]]:
    """{name `path` binds at module level by `from m import n [as name]`: (absolute m, n)}."""
    package = _package_of(path, module)
    return {
        alias.asname or alias.name: (_import_target(package, node), alias.name)
        for node in _module_level(ast.parse(path.read_text(), str(path)).body)
        if isinstance(node, ast.ImportFrom) and node.module != "__future__"
        for alias in node.names
    }


def _re_exports(path: Path) -> list[str]:
    """The names `path`'s `__all__` lists that the module binds by an import (of any module)."""
    tree = ast.parse(path.read_text(), str(path))
    imported: set[str] = set()
    for node in _module_level(tree.body):
        if isinstance(node, ast.ImportFrom) and node.module != "__future__":
            imported |= {alias.asname or alias.name for alias in node.names}
        elif isinstance(node, ast.Import):
            imported |= {alias.asname or alias.name.split(".")[0] for alias in node.names}
    return sorted(set(_declared_all(tree) or []) & imported)


def test_no_module_re_exports_a_name_it_imports() -> None:
    """A module's `__all__` lists only names the module defines: a name it imports has its
    address where it is defined (and in that package's `__init__`), not a second one here.
    """
    offences = [
        f"{path.relative_to(ROOT)}: {', '.join(names)}"
        for path in _source_files(SRC)
        if path.name != "__init__.py" and (names := _re_exports(path))
    ]
    assert offences == [], "__all__ lists names imported from elsewhere:\n" + "\n".join(offences)


@pytest.mark.parametrize(
    "source, offences",
    [
        (
            "from .loop_state import Tick\n\n__all__ = ['Tick', 'step']\n\ndef step(): ...\n",
            ["Tick"],
        ),
        ("import numpy as np\n\n__all__ = ['np']\n", ["np"]),
        (
            "try:\n    from tomllib import loads\nexcept ImportError:\n    pass\n"
            "__all__ = ['loads']\n",
            ["loads"],
        ),
        ("from .effects import EFFECTS\n\nNAMES = tuple(EFFECTS)\n__all__ = ['NAMES']\n", []),
    ],
)
def test_the_one_address_rule_catches_a_re_export(
    tmp_path: Path, source: str, offences: list[str]
) -> None:
    path = tmp_path / "module.py"
    path.write_text(source)
    assert _re_exports(path) == offences


def _defining_module(modules: dict[str, Path], module: str, name: str) -> str:
    """The module that defines `name` as `module` binds it, followed through each
    `from m import name`; a module outside `modules` (a third party's) ends the chain.
    """
    seen = set()
    while module in modules and (module, name) not in seen:
        seen.add((module, name))
        source = _from_imports(modules[module], module).get(name)
        if source is None:
            return module
        module, name = source
    return module


def _exports(path: Path) -> set[str]:
    return set(_declared_all(ast.parse(path.read_text(), str(path))) or [])


def _init_offences(modules: dict[str, Path]) -> list[str]:
    """Each project name a package's `__init__` exports: defined in a module of that package,
    imported from that very module, and exported by no other `__init__`.
    """
    exporters: dict[tuple[str, str], list[str]] = defaultdict(list)
    offences = []
    for package, path in sorted(modules.items()):
        if path.name != "__init__.py":
            continue
        imported = _from_imports(path, package)
        for name in sorted(_exports(path)):
            if f"{package}.{name}" in modules or name not in imported:
                continue  # a module or subpackage of it, or a name the `__init__` defines
            home = _defining_module(modules, package, name)
            if home not in modules:
                continue  # a third party's name (flaair_tools.bagio: rosbags' QoS enums)
            if not home.startswith(f"{package}."):
                offences.append(f"{package} exports {name} of {home}, outside the package")
            elif imported[name][0] != home:
                offences.append(f"{package} exports {name} of {home} through {imported[name][0]}")
            exporters[(name, home)].append(package)
    offences += [
        f"{name} of {home} is exported by {' and '.join(packages)}"
        for (name, home), packages in sorted(exporters.items())
        if len(packages) > 1
    ]
    return offences


def test_a_name_is_re_exported_only_by_its_own_package_init() -> None:
    """A package's `__init__` re-exports only names of its own modules, imported from the module
    that defines each, and no two `__init__`s export the same name. The one pair the rule could
    allow, a parent package re-exporting its subpackage's names, does not occur (every parent
    exports its subpackages as modules), so it is not allowed either.
    """
    modules = {_module_name(p): p for p in _source_files(SRC)}
    offences = _init_offences(modules)
    assert offences == [], "names with a second address:\n" + "\n".join(offences)


def _second_address(modules: dict[str, Path], owner: str, name: str) -> bool:
    """Whether `owner.name` is a name `owner` merely imports (and, an `__init__`, does not
    export): not one of the name's addresses.
    """
    path = modules.get(owner)
    if path is None or f"{owner}.{name}" in modules or name not in _from_imports(path, owner):
        return False
    return not (path.name == "__init__.py" and name in _exports(path))


def _second_address_reads(
    path: Path, module: str, modules: dict[str, Path], known: set[str]
) -> list[tuple[str, int]]:
    """(m.name, line) of each name `path` reads off a module that only imports it, by
    `from m import name` or by attribute (`m.name` after `import m` / `from pkg import m`).
    """
    found = [
        (f"{target}.{name}", line)
        for target, names, line in _imports(path, module)
        for name in names
        if target != module and _second_address(modules, target, name)
    ]
    for path_parts, lineno in _attribute_chains(path, module, known):
        for i in range(1, len(path_parts)):
            owner = ".".join(path_parts[:i])
            if owner in modules and f"{owner}.{path_parts[i]}" not in modules:
                if _second_address(modules, owner, path_parts[i]):
                    found.append((f"{owner}.{path_parts[i]}", lineno))
                break
    return sorted(set(found), key=lambda f: (f[1], f[0]))


def test_every_import_names_an_address_of_the_name() -> None:
    """`from m import name` and `m.name` name the module that defines `name` or a package
    `__init__` that exports it, never a module that merely imports it (the name would keep a
    second address there, unlisted).
    """
    modules = {_module_name(p): p for p in _source_files(SRC)}
    everything = _all_modules()
    known = set(everything.values())
    known |= {".".join(m.split(".")[:i]) for m in known for i in range(1, m.count(".") + 1)}
    offences = [
        f"{path.relative_to(ROOT)}:{line}: {name}"
        for path, module in everything.items()
        for name, line in _second_address_reads(path, module, modules, known)
    ]
    assert offences == [], "import these from where they are defined:\n" + "\n".join(offences)


def test_the_one_address_rules_catch_a_second_address(tmp_path: Path) -> None:
    """`pkg.state` defines `Tick`; `pkg.loop` uses it; `other` re-exports it."""
    files = {
        "pkg/__init__.py": 'from .loop import Tick\n\n__all__ = ["Tick"]\n',
        "pkg/state.py": "class Tick: ...\n",
        "pkg/loop.py": "from .state import Tick\n\ndef step(t: Tick) -> None: ...\n",
        "other/__init__.py": 'from pkg.state import Tick\n\n__all__ = ["Tick"]\n',
        "user.py": (
            "import pkg.loop as loop\nfrom pkg import Tick\nfrom pkg.state import Tick\n"
            "from pkg.loop import Tick, step\n\nloop.step(loop.Tick())\n"
        ),
    }
    modules = {}
    for relative, text in files.items():
        path = tmp_path / relative
        path.parent.mkdir(exist_ok=True)
        path.write_text(text)
        modules[relative[:-3].replace("/__init__", "").replace("/", ".")] = path
    assert _init_offences(modules) == [
        "other exports Tick of pkg.state, outside the package",
        "pkg exports Tick of pkg.state through pkg.loop",
        "Tick of pkg.state is exported by other and pkg",
    ]
    reads = _second_address_reads(tmp_path / "user.py", "user", modules, set(modules))
    assert reads == [("pkg.loop.Tick", 4), ("pkg.loop.Tick", 6)]


def test_cores_share_one_note_type() -> None:
    """Every core's log lines are `flaair_model.notes.Note`:
    no module defines a note type of its own.
    """
    own = []
    for path in _source_files(SRC):
        for node in _nodes(path):
            if isinstance(node, ast.ClassDef) and node.name in ("Note", "Notice", "LogLine"):
                own.append(f"{path.relative_to(ROOT)}:{node.lineno}: class {node.name}")
    assert own == ["src/flaair_model/flaair_model/notes.py:18: class Note"], own


MAX_NODE_LINES = 150


def test_no_node_over_150_lines() -> None:
    """A node past 150 lines holds logic that belongs in a core (docs/ARCHITECTURE.md). A module
    has no line cap: it is split where its idea splits, not where a count says.
    """
    long = []
    for path in _source_files(SRC):
        n = len(path.read_text().splitlines())
        if path.name.endswith("_node.py") and n >= MAX_NODE_LINES:
            long.append(f"{path.relative_to(ROOT)}: {n} lines (limit {MAX_NODE_LINES})")
    assert long == [], "\n".join(long)


def test_every_core_starts_from_initial_state_of_its_params() -> None:
    """One shape: `initial_state(params, *, ...)`, the core's frozen parameters the one positional
    argument; anything else (a start time, a warm start) by keyword.
    """
    shapes = []
    for path in _source_files(SRC):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and node.name == "initial_state":
                positional = [a.arg for a in node.args.posonlyargs + node.args.args]
                if len(positional) != 1 or not positional[0].startswith("p") or node.args.vararg:
                    shapes.append(
                        f"{path.relative_to(ROOT)}:{node.lineno}: "
                        f"initial_state({', '.join(positional)})"
                    )
    assert shapes == [], "\n".join(shapes)
