"""`pih warmup` runs the code paths of a run on a throw-away skill and writes nothing but numba's cache."""

from __future__ import annotations

from pathlib import Path

import pytest

from scripts.cli import main


def test_warmup_runs_the_kernels_and_leaves_the_working_folder_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["warmup"]) == 0
    assert "numba kernels compiled and cached" in capsys.readouterr().out
    assert list(tmp_path.iterdir()) == []


def test_the_generic_warmup_runs_beside_and_its_failure_is_one_line_and_exit_1(monkeypatch: pytest.MonkeyPatch,
                                                                               capsys: pytest.CaptureFixture[str]) -> None:
    import sys

    import scripts.warmup as warmup

    ran = []
    monkeypatch.setattr(warmup, "warm_up", lambda: ran.append("host"))
    script = "import os, sys; print(os.environ['NUMBA_CPU_NAME'], os.environ['NPY_DISABLE_CPU_FEATURES']); sys.exit({})"
    monkeypatch.setattr(warmup, "generic_command", lambda: [sys.executable, "-c", script.format(0)])
    assert main(["warmup", "--generic-too"]) == 0 and ran == ["host"]
    assert capsys.readouterr().out.strip() == "generic X86_V3 (generic x86-64)"
    monkeypatch.setattr(warmup, "generic_command", lambda: [sys.executable, "-c", script.format(3)])
    assert main(["warmup", "--generic-too"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "generic x86-64 warmup failed (exit 3): generic X86_V3" in err


def test_the_generic_environment_replaces_the_pins_and_keeps_the_rest() -> None:
    from numerics.cpu_dispatch import GENERIC_CPU_ENVIRONMENT, generic_cpu_environment

    env = generic_cpu_environment({"PATH": "/bin", "MKL_CBWR": "COMPATIBLE", "NUMBA_CPU_NAME": "skylake"})
    assert env == {"PATH": "/bin", **GENERIC_CPU_ENVIRONMENT}
