"""No BLAS or LAPACK call on the paths that feed an episode record or a demo file.

OpenBLAS sums in the order of the kernel it picks for the CPU (or for OPENBLAS_CORETYPE, which a test must not
change), and the contact physics amplifies a last-bit difference into other records; `numerics.small_linalg` has the
BLAS-free replacements. This is a source check: it walks the modules of envs/, controllers/, numerics/ and rflow/
(less the ones below that feed no record) and fails on ``@``, ``np.dot``-like calls, ``np.linalg.*`` (``norm`` only
with an ``axis``: then it is a reduction, not a dot product), ``scipy.linalg`` and ``einsum(..., optimize=...)``. A line
proven not to feed a record carries ``# blas-ok: <reason>``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("envs", "controllers", "numerics", "rflow")
NOT_ON_THE_RECORD_PATH: dict[str, str] = {
    "envs/media/video.py": "renders frames",
    "envs/media/figures.py": "draws figures",
    "controllers/timing.py": "times the controller",
    "rflow/bench.py": "times the flow",
    "rflow/dynamics.py": "torch only (its kernels pinned by numerics.cpu_dispatch)",
    "rflow/flow.py": "torch only (its kernels pinned by numerics.cpu_dispatch)",
    "rflow/lasa.py": "Riemannian LASA benchmark",
    "rflow/rgmm.py": "LASA baseline",
    "rflow/fdm.py": "LASA baseline",
    "rflow/naive.py": "LASA baseline",
    "rflow/metrics.py": "LASA metrics",
    "rflow/search.py": "hyperparameter search on LASA",
}
MARKER = "# blas-ok:"
BLAS_FUNCTIONS = frozenset({"dot", "vdot", "inner", "matmul", "tensordot", "cov", "corrcoef", "polyfit"})
BLAS_MODULES = ("np.linalg", "numpy.linalg", "scipy.linalg", "linalg")


def blas_calls(source: str) -> list[tuple[int, str]]:
    """(line, expression) of every BLAS/LAPACK-calling expression in ``source`` whose line has no MARKER."""
    lines = source.splitlines()
    found = []
    for node in ast.walk(ast.parse(source)):
        what = None
        if isinstance(node, (ast.BinOp, ast.AugAssign)) and isinstance(node.op, ast.MatMult):
            what = "@"
        elif isinstance(node, ast.Call):
            name = ast.unparse(node.func)
            keywords = {k.arg for k in node.keywords}
            module = name.rpartition(".")[0]
            if isinstance(node.func, ast.Attribute) and node.func.attr in BLAS_FUNCTIONS:
                what = name
            elif module in BLAS_MODULES and not (name.endswith(".norm") and "axis" in keywords):
                what = name
            elif name.endswith("einsum") and "optimize" in keywords:
                what = "einsum(optimize=...)"
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [f"{node.module}.{a.name}"
                                                                                    for a in node.names]
            if any(n.startswith(("scipy.linalg", "numpy.linalg")) for n in names):
                what = "import " + ", ".join(names)
        if what is not None and MARKER not in lines[node.lineno - 1]:
            found.append((node.lineno, what))
    return sorted(found)


def record_path_modules() -> list[Path]:
    files = sorted(p for package in PACKAGES for p in (ROOT / package).rglob("*.py"))
    return [p for p in files if p.relative_to(ROOT).as_posix() not in NOT_ON_THE_RECORD_PATH]


def test_no_blas_call_on_the_record_path():
    hits = [f"{p.relative_to(ROOT)}:{line}: {what}" for p in record_path_modules()
            for line, what in blas_calls(p.read_text())]
    assert not hits, ("BLAS/LAPACK calls on the record path (use numerics.small_linalg, or mark a line that feeds no "
                      f"record with '{MARKER} <reason>'):\n" + "\n".join(hits))


def test_every_excluded_module_exists_and_every_marker_gives_a_reason():
    assert all((ROOT / name).is_file() for name in NOT_ON_THE_RECORD_PATH)
    for path in record_path_modules():
        for line in path.read_text().splitlines():
            if MARKER in line:
                assert line.split(MARKER, 1)[1].strip(), f"{path.relative_to(ROOT)}: '{line.strip()}' gives no reason"


@pytest.mark.parametrize("code", [
    "y = a @ b", "a @= b", "y = np.dot(a, b)", "y = a.dot(b)", "y = np.inner(a, b)", "y = np.matmul(a, b)",
    "y = np.linalg.norm(v)", "y = np.linalg.solve(a, b)", "w = np.linalg.eigvalsh(k)", "y = scipy.linalg.expm(a)",
    "import scipy.linalg", "from numpy.linalg import inv", "y = np.einsum('ij,jk', a, b, optimize=True)",
])
def test_the_check_finds_blas_calls(code):
    assert blas_calls(code)


@pytest.mark.parametrize("code", [
    "y = np.linalg.norm(v, axis=-1)", "y = (a * b).sum(axis=-1)", "y = np.einsum('ij,jk->ik', a, b)",
    "y = np.cross(a, b)", "y = a @ b  # blas-ok: a test", "except np.linalg.LinAlgError: pass",
])
def test_the_check_passes_blas_free_code(code):
    source = f"try:\n    pass\n{code}" if code.startswith("except") else code
    assert not blas_calls(source)
