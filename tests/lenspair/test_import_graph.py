"""The dependency graph drawn from the imports stays honest.

Every module of the installed package is parsed (``ast``, nothing is
imported) and its module-level imports (those that run when the module is
imported: top level, ``if``/``try`` blocks and class bodies, not function
bodies nor ``if TYPE_CHECKING:`` blocks) become edges between modules:

* ``lenspair.core`` is the foundation: it imports no stage and no face module;
* the stages (``lenspair.capture``, ``.rectify``, ``.dataset``, ``.model``,
  ``.simulate``) never import the face (``lenspair.cli``,
  ``lenspair.commands``, ``lenspair.demo*``);
* no module imports itself through a chain of module-level imports.

Two more structural rules are checked the same way: error classes live in
each package's ``errors.py``, and an import left inside a function says why.
"""

import ast
import graphlib
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
STAGES = ("capture", "rectify", "dataset", "model", "simulate")


def _package_dirs() -> dict[str, Path]:
    with (ROOT / "pyproject.toml").open("rb") as handle:
        mapping: dict[str, str] = tomllib.load(handle)["tool"]["setuptools"]["package-dir"]
    return {name: ROOT / folder for name, folder in mapping.items()}


def _modules() -> dict[str, Path]:
    """Dotted module name -> source file, for every module the wheel installs."""
    modules: dict[str, Path] = {}
    package_dirs = _package_dirs()
    for name, folder in package_dirs.items():
        for source in folder.rglob("*.py"):
            relative = source.relative_to(folder).with_suffix("")
            parts = [name, *relative.parts]
            if parts[-1] == "__init__":
                parts.pop()
            dotted = ".".join(parts)
            # a folder mapped by a more specific package-dir entry is walked by that entry
            if any(
                other != name and other.startswith(name + ".") and source.is_relative_to(path)
                for other, path in package_dirs.items()
            ):
                continue
            modules[dotted] = source
    return modules


MODULES = _modules()


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _module_level_imports(body: list[ast.stmt]) -> Iterator[ast.Import | ast.ImportFrom]:
    """Import statements that run at import time (not in functions or TYPE_CHECKING)."""
    for node in body:
        if isinstance(node, ast.Import | ast.ImportFrom):
            yield node
        elif isinstance(node, ast.If):
            if not _is_type_checking(node.test):
                yield from _module_level_imports(node.body)
            yield from _module_level_imports(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, node.orelse, node.finalbody):
                yield from _module_level_imports(block)
            for handler in node.handlers:
                yield from _module_level_imports(handler.body)
        elif isinstance(node, ast.With | ast.ClassDef):
            yield from _module_level_imports(node.body)


def _resolve(name: str) -> str | None:
    """The project module that importing ``name`` loads last, or None for third-party."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imported(module: str, node: ast.Import | ast.ImportFrom) -> set[str]:
    if isinstance(node, ast.Import):
        targets = [alias.name for alias in node.names]
    else:
        base = node.module or ""
        if node.level:
            is_package = MODULES[module].name == "__init__.py"
            anchor = module.split(".")
            anchor = anchor if is_package else anchor[:-1]
            anchor = anchor[: len(anchor) - (node.level - 1)]
            base = ".".join([*anchor, base]) if base else ".".join(anchor)
        # ``from package import module`` imports the module; ``from module import name`` the module
        targets = [f"{base}.{alias.name}" for alias in node.names]
    resolved = {_resolve(target) for target in targets}
    return {target for target in resolved if target is not None and target != module}


def _graph() -> dict[str, set[str]]:
    graph = {}
    for module, source in MODULES.items():
        tree = ast.parse(source.read_text(encoding="utf-8"), filename=str(source))
        edges: set[str] = set()
        for node in _module_level_imports(tree.body):
            edges |= _imported(module, node)
        graph[module] = edges
    return graph


GRAPH = _graph()


def _is_face(module: str) -> bool:
    return module in (
        "lenspair.cli",
        "lenspair.__main__",
        "lenspair.commands",
    ) or module.startswith(("lenspair.commands.", "lenspair.demo"))


def _stage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in STAGES else None


def test_the_graph_covers_every_layer() -> None:
    # guards the parser: were the mapping or resolution wrong, the rules would hold vacuously
    assert {"lenspair.cli", "lenspair.core.config", "lenspair.capture.recording"} <= set(GRAPH)
    assert {"lenspair.model.evaluation.tradeoff", "lenspair.simulate.effects.raindrops"} <= set(
        GRAPH
    )
    assert "lenspair.capture.euroc" in GRAPH["lenspair.capture.recording"]
    assert "lenspair.core.errors" in GRAPH["lenspair.capture.errors"]
    assert any(_is_face(target) for target in GRAPH["lenspair.__main__"])


def test_relative_and_package_imports_resolve() -> None:
    node = ast.parse("from . import euroc\nfrom .errors import CaptureError").body
    module = "lenspair.capture.recording"
    assert _imported(module, node[0]) == {"lenspair.capture.euroc"}  # type: ignore[arg-type]
    assert _imported(module, node[1]) == {"lenspair.capture.errors"}  # type: ignore[arg-type]
    assert _resolve("numpy.linalg") is None


def test_core_imports_no_stage_and_no_face() -> None:
    core = {module: edges for module, edges in GRAPH.items() if module.startswith("lenspair.core")}
    assert core
    bad = {
        f"{module} -> {target}"
        for module, edges in core.items()
        for target in edges
        if _stage(target) or _is_face(target)
    }
    assert not bad, f"lenspair.core must import no stage or face module: {sorted(bad)}"


@pytest.mark.parametrize("stage", STAGES)
def test_stages_import_no_face(stage: str) -> None:
    bad = {
        f"{module} -> {target}"
        for module, edges in GRAPH.items()
        if _stage(module) == stage
        for target in edges
        if _is_face(target)
    }
    assert not bad, f"stage packages must not import the CLI/demo: {sorted(bad)}"


def test_there_are_no_import_cycles() -> None:
    try:
        graphlib.TopologicalSorter(GRAPH).prepare()
    except graphlib.CycleError as error:
        cycle = error.args[1]
        pytest.fail(f"module-level import cycle: {' -> '.join(cycle)}")


def test_the_cycle_check_sees_a_cycle() -> None:
    with pytest.raises(graphlib.CycleError):
        graphlib.TopologicalSorter({"a": {"b"}, "b": {"c"}, "c": {"a"}}).prepare()


def _unexplained_function_imports() -> list[str]:
    """In-function imports of lenspair or torch with no comment saying why they are there."""
    found = []
    for module, source in MODULES.items():
        lines = source.read_text(encoding="utf-8").splitlines()
        tree = ast.parse("\n".join(lines), filename=str(source))
        for function in ast.walk(tree):
            if not isinstance(function, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            for node in ast.walk(function):
                if not isinstance(node, ast.Import | ast.ImportFrom):
                    continue
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else []
                names += (
                    [alias.name for alias in node.names] if isinstance(node, ast.Import) else []
                )
                if not any(name.split(".")[0] in ("lenspair", "torch") for name in names):
                    continue
                # the comment sits on the import's line or on one of the lines just above it
                # (a block of imports shares one comment)
                above = node.lineno - 1
                while above > 0 and lines[above - 1].strip().startswith(("from ", "import ")):
                    above -= 1
                here = lines[node.lineno - 1]
                if "#" not in here and not lines[above - 1].strip().startswith(("#", "try:  #")):
                    found.append(f"{module}:{node.lineno}")
    return found


def test_imports_inside_functions_say_why() -> None:
    # allowed reasons: breaking a circle, keeping torch out of --help, optional dependencies
    unexplained = _unexplained_function_imports()
    assert not unexplained, f"in-function imports without a comment saying why: {unexplained}"


def test_command_help_does_not_import_torch() -> None:
    code = (
        "import sys\n"
        "from lenspair.cli import COMMANDS, build_parser\n"
        "for name in COMMANDS:\n"
        "    build_parser(name)\n"
        "print('torch' in sys.modules)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert result.stdout.strip() == "False", "building a command's --help imported torch"


def test_error_classes_live_in_errors_modules() -> None:
    misplaced = []
    for module, source in MODULES.items():
        if module.rpartition(".")[2] == "errors":
            continue
        tree = ast.parse(source.read_text(encoding="utf-8"), filename=str(source))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                bases = [ast.unparse(base).rpartition(".")[2] for base in node.bases]
                if any(base.endswith(("Error", "Exception")) for base in bases):
                    misplaced.append(f"{module}.{node.name}")
    assert not misplaced, f"error classes outside an errors.py: {misplaced}"
