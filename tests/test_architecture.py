"""The package's structure (docs/architecture.md) as tests: the import graph of the source, read with ast.

Every import statement counts, at module level and inside functions (a lazy import is still a dependency),
resolved to the project module it names. The checks: no cycle between modules; each package imports only
the layers below it; rflow never imports MuJoCo or the simulator; and the concepts with one owner are
defined once (the bar "grep shows one definition").
"""

from __future__ import annotations

import ast
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("pihutil", "numerics", "batch", "rflow", "controllers", "assets", "envs", "scripts")

ALLOWED: dict[str, set[str]] = {
    "pihutil": set(),
    "numerics": set(),
    "assets": set(),
    "batch": {"pihutil"},
    "rflow": {"batch", "numerics", "pihutil"},
    "controllers": {"numerics", "pihutil"},
    "envs": {"assets", "batch", "controllers", "numerics", "pihutil", "rflow"},
    "scripts": {"assets", "batch", "controllers", "envs", "numerics", "pihutil", "rflow"},
}
"""Which project packages each package may import (the layers below it; docs/architecture.md)."""

FORBIDDEN_LIBRARIES: dict[str, set[str]] = {
    "pihutil": {"numpy", "torch", "mujoco", "dm_control", "numba", "ray"},
    "batch": {"torch", "mujoco", "dm_control", "numba"},
    "rflow": {"mujoco", "dm_control", "gymnasium", "imageio", "mink"},
    "numerics": {"torch", "scipy", "mujoco", "dm_control", "gymnasium", "imageio", "mink", "matplotlib", "ray"},
}
"""Third-party libraries a package must not import: rflow learns from arrays without the simulator; batch runs
any picklable unit; pihutil is the standard library only; numerics is numpy, numba and the standard library."""


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


@lru_cache(maxsize=1)
def modules() -> dict[str, Path]:
    """Every project module (dotted name -> file)."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            found[_module_name(path)] = path
    return found


@lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), str(path))


def _imported_names(name: str, path: Path) -> set[str]:
    """Dotted names imported anywhere in the module (absolute, relative ones resolved; ``from a import b`` gives
    a.b, which resolves to the submodule b or, if it is no module, to a)."""
    tree = _tree(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                prefix = package[:len(package) - node.level + 1]
                base = ".".join(prefix + ([base] if base else []))
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)
    return names


def _resolve(name: str) -> str | None:
    """The project module a dotted name belongs to (its longest prefix that is a module), or None."""
    while name:
        if name in modules():
            return name
        name = name.rpartition(".")[0]
    return None


@lru_cache(maxsize=1)
def graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports."""
    edges = {}
    for name, path in modules().items():
        imported = {_resolve(n) for n in _imported_names(name, path)}
        edges[name] = {m for m in imported if m is not None and m != name}
    return edges


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_the_walk_sees_the_packages_and_their_lazy_imports() -> None:
    assert len(modules()) > 100
    assert "batch.supervision" in graph()["batch.runner"]
    assert "controllers.ik" in graph()["envs.execution.evaluate"]  # imported inside a function


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle_between_modules() -> None:
    assert _cycles(graph()) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_imports_only_the_layers_below_it(package: str) -> None:
    wrong = sorted((module, target) for module, targets in graph().items() if module.split(".")[0] == package
                   for target in targets if target.split(".")[0] not in ALLOWED[package] | {package})
    assert wrong == []


def test_the_simulator_does_not_import_skill_execution_or_datasets() -> None:
    def simulator(module: str) -> bool:
        return module.startswith("envs") and not module.startswith(("envs.execution", "envs.datasets"))

    wrong = sorted((module, target) for module, targets in graph().items() if simulator(module)
                   for target in targets if target.startswith(("envs.execution", "envs.datasets")))
    assert wrong == []


@pytest.mark.parametrize("package", sorted(FORBIDDEN_LIBRARIES))
def test_a_package_does_not_import_the_libraries_it_must_not_need(package: str) -> None:
    wrong = sorted((name, imported) for name, path in modules().items() if name.split(".")[0] == package
                   for imported in _imported_names(name, path)
                   if imported.split(".")[0] in FORBIDDEN_LIBRARIES[package])
    assert wrong == []


def _definitions(name: str) -> list[str]:
    """Where a function or class ``name`` is defined in the package code."""
    places = []
    for module, path in modules().items():
        for node in ast.walk(_tree(path)):
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)) and node.name == name:
                places.append(module)
    return places


@pytest.mark.parametrize("name, owner", [
    ("hamilton", "numerics.quaternion"),  # the quaternion product; quat_mul and quat_mul_one are it on arrays, floats
    ("quat_mul", "numerics.quaternion"),
    ("quat_conj", "numerics.quaternion"),
    ("quat_to_mat", "numerics.quaternion"),
    ("matrix_to_quat_components", "numerics.quaternion"),
    ("mat_to_quat", "numerics.quaternion"),
    ("AtomicFile", "pihutil.atomic"),
    ("wilson_interval", "envs.execution.statistics"),
    ("use_headless_rendering", "envs.rendering"),
    ("Task", "envs.task"),  # the task: its fields and their checks (the presets are its files, envs/tasks/)
    ("SuccessConfig", "envs.task"),
    ("StartRange", "envs.task"),
    ("check_force_limit", "envs.task"),
    ("Controller", "controllers.interface"),  # what the episode stepping needs of a controller
    ("EpisodeConfig", "envs.episode_config"),
    ("SceneConfig", "envs.scene_config"),
    ("EpisodeSensing", "envs.sensing"),
    ("ExpertConfig", "envs.expert"),
    ("EvaluationResult", "envs.execution.result"),
    ("record_from_dict", "envs.execution.episode"),
    ("pair_records", "envs.execution.pairing"),
])
def test_a_concept_with_one_owner_is_defined_once(name: str, owner: str) -> None:
    assert _definitions(name) == [owner]


def _calls(predicate) -> list[str]:
    """Modules with a call for which ``predicate(call)`` holds."""
    return sorted({module for module, path in modules().items()
                   for node in ast.walk(_tree(path))
                   if isinstance(node, ast.Call) and predicate(node)})


def test_only_the_atomic_write_renames_files_into_place() -> None:
    def renames(call: ast.Call) -> bool:
        func = call.func
        return isinstance(func, ast.Attribute) and func.attr in ("replace", "rename", "mkstemp", "mkdtemp") and \
            isinstance(func.value, ast.Name) and func.value.id in ("os", "tempfile")

    assert _calls(renames) == ["pihutil.atomic"]


def test_only_the_rendering_module_sets_the_opengl_backend() -> None:
    def sets_mujoco_gl(call: ast.Call) -> bool:
        return isinstance(call.func, ast.Attribute) and call.func.attr in ("setdefault", "__setitem__", "update") \
            and any(isinstance(arg, ast.Constant) and arg.value == "MUJOCO_GL" for arg in call.args)

    assigns = sorted({module for module, path in modules().items()
                      for node in ast.walk(_tree(path))
                      if isinstance(node, ast.Assign) and any(
                          isinstance(t, ast.Subscript) and isinstance(t.slice, ast.Constant)
                          and t.slice.value == "MUJOCO_GL" for t in node.targets)})
    assert _calls(sets_mujoco_gl) == ["envs.rendering"] and assigns == []
