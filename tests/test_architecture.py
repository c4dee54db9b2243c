"""The package's structure (docs/architecture.md) as tests: the import graph of the source, read with ast.

Every import statement counts, at module level and inside functions (a lazy import is still a dependency),
resolved to the project module it names. The checks: no cycle between modules; each package imports only
the layers below it; rflow never imports MuJoCo or the simulator, numerics nothing but numpy and numba; inside envs,
each sub-package imports only those below it (`ENVS_ALLOWED`) and none holds more than a fifth of envs's lines; each
package names its public surface, lazily; and the concepts with one owner are defined once (the bar "grep shows one
definition").
"""

from __future__ import annotations

import ast
import inspect
import subprocess
import sys
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

ENVS_BASE = ("errors", "geometry", "poses")
"""The shared base modules of envs (room "base"); every other room is a sub-package or the Gymnasium module."""

ENVS_ALLOWED: dict[str, set[str]] = {
    "base": set(),
    "io": {"base"},
    "cell": {"base", "io"},
    "task": {"base", "io", "cell"},
    "sim": {"base", "io", "cell", "task"},
    "policies": {"base", "io", "cell", "task", "sim"},
    "rollout": {"base", "io", "cell", "task", "sim", "policies"},
    "demos": {"base", "io", "cell", "task", "sim", "policies", "rollout"},
    "media": {"base", "io", "cell", "task", "sim", "policies", "rollout"},
    "statistics": {"base", "io"},
    "evaluation": {"base", "io", "cell", "task", "sim", "policies", "rollout", "demos", "media", "statistics"},
    "datasets": {"base", "io", "cell", "task", "sim", "policies", "rollout", "demos", "media"},
    "gym": {"base", "io", "cell", "task", "sim", "policies", "rollout", "media", "evaluation"},
    "gym_env": {"gym"},
}
"""Which rooms of envs each may import (docs/architecture.md): io/base <- cell <- task <- sim <- policies <- rollout
<- demos/media/statistics <- evaluation/datasets <- gym (it runs `pih evaluate --policy`'s episodes) <- gym_env (the
registration)."""

ENVS_LAYERS: tuple[tuple[str, ...], ...] = (("base",), ("io",), ("cell",), ("task",), ("sim",), ("policies",),
                                            ("rollout",), ("demos", "media", "statistics"),
                                            ("evaluation", "datasets"), ("gym",), ("gym_env",))
"""The rooms of envs from the bottom up; a room imports only rooms of lower layers (none beside it)."""

MAX_ROOM_SHARE = 0.20
"""No file or sub-package of envs/ holds more than this share of envs/'s lines."""


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
    assert "controllers.ik" in graph()["envs.evaluation.evaluate"]  # imported inside a function


def test_the_cycle_finder_finds_a_cycle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_import_cycle_between_modules() -> None:
    assert _cycles(graph()) == []


@pytest.mark.parametrize("package", PACKAGES)
def test_each_package_imports_only_the_layers_below_it(package: str) -> None:
    wrong = sorted((module, target) for module, targets in graph().items() if module.split(".")[0] == package
                   for target in targets if target.split(".")[0] not in ALLOWED[package] | {package})
    assert wrong == []


def _room(module: str) -> str:
    """The part of envs a module belongs to: its sub-package, "gym_env", or "base" (errors, geometry, poses)."""
    parts = module.split(".")
    if len(parts) == 2 and parts[1] in ENVS_BASE:
        return "base"
    return parts[1]


def _envs_arrows() -> list[tuple[str, str, str, str]]:
    """(module, imported module, its room, the imported module's room) for every import between two rooms of envs;
    the package's own ``__init__`` (lazy re-exports of the public surface, on top of all) is left out."""
    return sorted((module, target, _room(module), _room(target)) for module, targets in graph().items()
                  if module.startswith("envs.") for target in targets
                  if target.startswith("envs.") and _room(module) != _room(target))


def test_the_envs_table_lists_every_room_and_only_points_down() -> None:
    rooms = {_room(module) for module in modules() if module.startswith("envs.")}
    assert rooms == set(ENVS_ALLOWED) == {room for layer in ENVS_LAYERS for room in layer}
    rank = {room: n for n, layer in enumerate(ENVS_LAYERS) for room in layer}
    assert sorted((room, below) for room, allowed in ENVS_ALLOWED.items() for below in allowed
                  if rank[below] >= rank[room]) == []


def test_each_envs_subpackage_imports_only_what_the_table_allows() -> None:
    wrong = [arrow for arrow in _envs_arrows() if arrow[3] not in ENVS_ALLOWED[arrow[2]]]
    assert wrong == []


def test_no_envs_subpackage_imports_one_above_it_or_beside_it() -> None:
    rank = {room: n for n, layer in enumerate(ENVS_LAYERS) for room in layer}
    assert [arrow for arrow in _envs_arrows() if rank[arrow[3]] >= rank[arrow[2]]] == []


def _lines(path: Path) -> int:
    return sum(1 for _ in path.open(encoding="utf-8"))


def test_no_room_of_envs_holds_more_than_a_fifth_of_its_lines() -> None:
    """A file or sub-package of envs/ holds at most MAX_ROOM_SHARE of envs/'s lines of Python."""
    envs = ROOT / "envs"
    sizes = {child.name: sum(_lines(p) for p in ([child] if child.is_file() else child.rglob("*.py")))
             for child in envs.iterdir() if child.suffix == ".py" or (child / "__init__.py").is_file()}
    total = sum(sizes.values())
    assert total > 10_000 and len(sizes) > 10
    assert {name: round(n / total, 3) for name, n in sizes.items() if n > MAX_ROOM_SHARE * total} == {}


def _envs_subpackages() -> list[str]:
    return sorted(f"envs.{p.parent.name}" for p in (ROOT / "envs").glob("*/__init__.py"))


@pytest.mark.parametrize("package", ["envs", *_envs_subpackages()])
def test_a_package_names_its_public_surface_and_every_name_is_there(package: str) -> None:
    """``__all__`` names the public surface; each name resolves (lazily: from the module the table names) and none is
    also the name of a submodule, which an import would put in its place."""
    import importlib

    module = importlib.import_module(package)
    assert module.__all__ and set(module.__all__) <= set(dir(module))
    submodules = {p.stem for p in (ROOT / package.replace(".", "/")).glob("*.py")} | \
                 {p.parent.name for p in (ROOT / package.replace(".", "/")).glob("*/__init__.py")}
    for name in module.__all__:
        value = getattr(module, name)
        assert name not in submodules and not inspect.ismodule(value), name
        exports = getattr(module, "EXPORTS", {})
        if name in exports and (inspect.isclass(value) or inspect.isfunction(value)):
            assert value.__module__ == exports[name] or value.__module__.startswith(exports[name] + "."), name


def test_importing_envs_and_its_subpackages_loads_no_heavy_library() -> None:
    """The packages' ``__init__`` files are light: ``import envs.task`` (or any sub-package) loads neither numpy, torch,
    MuJoCo (and its renderer) nor scipy; only what a caller uses is imported."""
    code = ("import importlib, sys\n"
            f"for name in {['envs', *_envs_subpackages()]!r}:\n"
            "    importlib.import_module(name)\n"
            "print(sorted(m for m in ('numpy', 'torch', 'mujoco', 'dm_control', 'scipy', 'numba', 'gymnasium')"
            " if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "[]"


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
    ("wilson_interval", "envs.statistics.fixed_sample"),
    ("use_headless_rendering", "envs.media.rendering"),
    ("Task", "envs.task.task"),  # the task: its fields and their checks (its presets are files, envs/task/presets/)
    ("SuccessConfig", "envs.task.task"),
    ("StartRange", "envs.task.task"),
    ("check_force_limit", "envs.task.task"),
    ("Controller", "controllers.interface"),  # what the episode stepping needs of a controller
    ("Action", "controllers.action"),  # what a policy returns and a controller takes (envs re-exports it)
    ("Pose", "numerics.pose"),  # the pose value of every layer (envs.poses re-exports it)
    ("led_pose", "controllers.feedforward"),  # the feed-forward lead: the controller's, computed once
    ("EpisodeConfig", "envs.sim.episode_config"),
    ("SceneConfig", "envs.cell.scene_config"),
    ("EpisodeSensing", "envs.sim.sensing"),
    ("ExpertConfig", "envs.policies.expert_plan"),
    ("EvaluationResult", "envs.evaluation.result"),
    ("record_from_dict", "envs.rollout.episode"),
    ("pair_records", "envs.statistics.pairing"),
    ("HoleSpec", "envs.cell.hole"),
    ("StiffnessSetting", "envs.policies.skill_settings"),
    ("Observation", "envs.policies.interface"),  # what a policy sees; the simulator's truth is SimulatorState
    ("SimulatorState", "envs.sim.observation"),
    ("NumericsError", "numerics.errors"),
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
    assert _calls(sets_mujoco_gl) == ["envs.media.rendering"] and assigns == []
