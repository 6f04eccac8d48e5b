"""rddl-batch --cluster on a real Dask scheduler and two worker processes, each started
(as `dask scheduler` and `dask worker`) in a folder of its own, away from the
experiment: its instances are given relative to the experiment file, which sits in yet
another folder, and the run starts from a fourth. Every job finishes and the scores
equal those of the local run with the same seeds."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from ippc.batch import load_experiment, run_batch

from .conftest import SMALL, outcome

pytestmark = pytest.mark.alone  # a scheduler and two worker processes

DASK = Path(sys.executable).parent / "dask"


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for proc in procs:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGTERM)
    for proc in procs:
        try:
            proc.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


@pytest.fixture
def scheduler(tmp_path: Path) -> Iterator[str]:
    """A scheduler and two single-threaded workers on 127.0.0.1: its address."""
    pytest.importorskip("distributed")
    if not DASK.exists():
        pytest.skip("no `dask` command beside this Python")
    file = tmp_path / "scheduler" / "scheduler.json"
    file.parent.mkdir()
    procs: list[subprocess.Popen[bytes]] = []

    def start(args: list[str], folder: Path) -> None:
        folder.mkdir(exist_ok=True)
        log = open(folder / "out.log", "wb")  # noqa: SIM115 - the process holds it
        procs.append(
            subprocess.Popen(
                [str(DASK), *args],
                cwd=folder,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        )
        log.close()

    try:
        start(
            [
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                str(file),
            ],
            file.parent,
        )
        deadline = time.monotonic() + 120
        while not file.exists() or not file.read_text().strip():
            assert time.monotonic() < deadline, (file.parent / "out.log").read_text()
            assert procs[0].poll() is None, (file.parent / "out.log").read_text()
            time.sleep(0.2)
        time.sleep(0.2)  # the file is written at once, not atomically
        address = json.loads(file.read_text())["address"]
        for name in ("worker1", "worker2"):
            start(
                [
                    "worker",
                    address,
                    "--host",
                    "127.0.0.1",
                    "--nthreads",
                    "1",
                    "--no-dashboard",
                    "--local-directory",
                    str(tmp_path / name / "space"),
                ],
                tmp_path / name,
            )
        import distributed

        with distributed.Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        _stop(procs[::-1])


def test_workers_started_elsewhere_play_every_job_with_the_local_scores(
    tmp_path: Path, scheduler: str, small_reference, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, _, reference = small_reference
    exp_dir = tmp_path / "experiment"
    exp_dir.mkdir()
    text = SMALL
    for line in SMALL.splitlines():
        if line.startswith('    "/'):
            absolute = line.strip().strip('",')
            text = text.replace(absolute, os.path.relpath(absolute, exp_dir))
    assert '"../' in text and '    "/' not in text
    path = exp_dir / "small.toml"
    path.write_text(text)
    elsewhere = tmp_path / "run"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    summary = run_batch(load_experiment(path), "cluster.sqlite", cluster=scheduler)
    assert (summary.finished, summary.failed, summary.failures) == (12, 0, [])
    assert outcome(elsewhere / "cluster.sqlite") == reference
