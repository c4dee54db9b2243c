"""`pih search` from two processes sharing one Optuna study on a real PostgreSQL server started for the test.

The server (Debian's `postgresql` package, installed by setup.sh when run as root) is initialised in a
temporary folder, listens on 127.0.0.1 on a free port and is stopped after the test, even when it fails.
initdb refuses to run as root, so as root the server runs as the `postgres` user. Skipped, with the
reason, where no server can be started.
"""

import glob
import os
import pwd
import shutil
import socket
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Iterator

import pytest

from tests.helpers import REPO

optuna = pytest.importorskip("optuna", reason="optuna not installed: pip install -e '.[search]'")
pytest.importorskip("psycopg", reason="psycopg not installed: pip install -e '.[search]'")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _run(argv: list[str], user: str | None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(argv, user=user, capture_output=True, text=True, timeout=timeout, check=False)


@pytest.fixture()
def postgres_url() -> Iterator[str]:
    """A PostgreSQL server on 127.0.0.1 for this test; yields its SQLAlchemy URL."""
    binaries = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not binaries:
        pytest.skip("PostgreSQL server not installed (Debian: apt-get install postgresql; setup.sh does it as root)")
    bindir = Path(binaries[-1]).parent
    user = None
    if os.geteuid() == 0:
        try:
            pwd.getpwnam("postgres")
        except KeyError:
            pytest.skip("running as root and there is no 'postgres' user for initdb")
        user = "postgres"
    root = Path(tempfile.mkdtemp(prefix="pih-pg-"))
    data = root / "data"
    if user is not None:
        shutil.chown(root, user=user)
    port = _free_port()
    started = False
    try:
        init = _run([str(bindir / "initdb"), "-D", str(data), "-U", "pih", "--auth=trust", "-E", "UTF8",
                     "--no-sync"], user)
        if init.returncode != 0:
            pytest.skip(f"initdb failed: {init.stderr.strip().splitlines()[-1:] or init.returncode}")
        options = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=off"
        start = _run([str(bindir / "pg_ctl"), "-D", str(data), "-o", options, "-l", str(root / "server.log"), "-w",
                      "-t", "60", "start"], user, timeout=90)
        if start.returncode != 0:
            log = (root / "server.log").read_text() if (root / "server.log").exists() else start.stderr
            pytest.skip(f"PostgreSQL did not start: {log.strip().splitlines()[-1:]}")
        started = True
        yield f"postgresql+psycopg://pih@127.0.0.1:{port}/postgres"
    finally:
        if started:
            _run([str(bindir / "pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop"], user)
        shutil.rmtree(root, ignore_errors=True)


@pytest.mark.slow
def test_two_processes_write_trials_to_one_study(postgres_url: str, tmp_path: Path) -> None:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    procs = []
    for k in (1, 2):
        argv = [sys.executable, "-m", "scripts.cli", "search", "--shape", "Angle", "--manifold", "spd",
                "--trials", "2", "--epochs", "1", "--n-points", "40", "--storage", postgres_url, "--study", "shared",
                "--sampler-seed", str(k), "--out", str(tmp_path / f"p{k}")]
        procs.append(subprocess.Popen(argv, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                      text=True))
    outputs = [p.communicate(timeout=600)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outputs
    study = optuna.load_study(study_name="shared", storage=postgres_url)
    workers = [t.user_attrs.get("worker") for t in study.trials]
    assert len(study.trials) == 4 and all(t.state.name == "COMPLETE" for t in study.trials)
    assert len(set(workers)) == 2 and all(workers.count(w) == 2 for w in set(workers))
    assert (tmp_path / "p1" / "best.json").is_file() and (tmp_path / "p2" / "best.json").is_file()
