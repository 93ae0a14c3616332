"""Layering of the package: a module imports only from its own layer or the layers below it.

Every ``import`` and ``from ... import`` of every module under ``geodem/`` (those inside functions
too) is read with ``ast``; nothing is imported. Modules named by string (the registry's built-in
lists, :data:`geodem.registry.BUILTINS`) are not imports and are not checked here.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "geodem"

#: bottom to top; a module may import its own layer and any layer below it
LAYERS = (
    # base: pure helpers with no geodem imports above them
    ("geodem.threads", "geodem.extras", "geodem.registry", "geodem.machine", "geodem.materials",
     "geodem.materials_library"),
    ("geodem.core",),  # state, contact law, neighbour rows, groups, time step, checks
    ("geodem.backends",),
    # the time-step loop drives a backend and the coupled fields (and restores them)
    ("geodem.core.engine", "geodem.build", "geodem.geo", "geodem.fields", "geodem.io"),
    ("geodem.measure",),
    ("geodem.workflow",),
    ("geodem.cases",),
    ("geodem.studies", "geodem.bench"),  # studies of accuracy and cost; bench: the step's speed
    ("geodem.advise", "geodem.sweep", "geodem.cli", "geodem.__main__"),
)


def layer_of(module: str) -> int | None:
    """Index in :data:`LAYERS` of ``module`` (a dotted name; the longest name of LAYERS that
    contains it decides), None for ``geodem`` itself."""
    best, layer = "", None
    for k, names in enumerate(LAYERS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > len(best):
                best, layer = name, k
    return layer


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def imported(tree: ast.AST, module: str, is_package: bool) -> list[tuple[int, str]]:
    """``(line, dotted name)`` of every geodem module ``tree`` imports."""
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = module.split(".")
                base = base[: len(base) - node.level + (1 if is_package else 0)]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            # "from geodem import measure" imports the module geodem.measure
            out += [(node.lineno, f"{name}.{a.name}") if layer_of(name) is None
                    else (node.lineno, name) for a in node.names]
    return [(line, n) for line, n in out if n == "geodem" or n.startswith("geodem.")]


def violations(root: Path = PACKAGE) -> list[str]:
    """Imports that point up the layers, as ``file:line: A (layer i) imports B (layer j)``."""
    bad = []
    for path in sorted(root.rglob("*.py")):
        module = module_name(path, root)
        here = layer_of(module)
        if here is None:  # geodem/__init__.py
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        for line, name in imported(tree, module, path.name == "__init__.py"):
            there = layer_of(name)
            if there is not None and there > here:
                bad.append(f"{path.relative_to(root.parent)}:{line}: {module} (layer {here}) "
                           f"imports {name} (layer {there})")
    return bad


def test_every_module_has_a_layer():
    missing = [module_name(p, PACKAGE) for p in sorted(PACKAGE.rglob("*.py"))
               if p != PACKAGE / "__init__.py" and layer_of(module_name(p, PACKAGE)) is None]
    assert not missing, f"modules in no layer (add them to LAYERS): {missing}"


def test_lower_layers_never_import_upper_ones():
    bad = violations()
    assert not bad, "imports up the layers:\n" + "\n".join(bad)


def test_a_violation_is_found(tmp_path):
    """The check can fail: a copy of the package with one import up the layers."""
    import shutil

    copy = tmp_path / "geodem"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    law = copy / "core" / "law.py"
    law.write_text(law.read_text() + "\n\ndef _up():\n    from geodem.cases import common\n")
    bad = violations(copy)
    assert len(bad) == 1 and "geodem.core.law (layer 1) imports geodem.cases" in bad[0]


@pytest.mark.parametrize("module,layer", [("geodem.core.state", 1), ("geodem.core.engine", 3),
                                          ("geodem.fields.pore", 3), ("geodem.cases.tbm", 6),
                                          ("geodem.cli", 8), ("geodem", None)])
def test_layer_of(module, layer):
    assert layer_of(module) == layer
