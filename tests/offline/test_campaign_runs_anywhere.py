"""A campaign gives the same per-episode results wherever and however its runs are flown.

Killed midway (SIGKILL, a real subprocess) and resumed, or flown by two Dask workers over
loopback: the results file holds the same rows as one uninterrupted local run (timing
fields aside), because each run is a function of ``(seed, episode, method)``.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.offline.campaign import EpisodeResult, ResultsFile, campaign_header, run_campaign

FAMILY, SEED, EPISODES, METHODS, DURATION_S = "antipodal", 5, 2, ("hyperplane", "deterministic"), 6.0
COMPANION = [sys.executable, "-m", "companion.cli"]
ARGS = ["campaign", "--family", FAMILY, "--seed", str(SEED), "--episodes", str(EPISODES), "--methods", ",".join(METHODS),
        "--duration", str(DURATION_S), "--progress", "off"]
DEADLINE_S = 240.0  # for any one subprocess step below, on a loaded 2-core machine


@pytest.fixture(scope="module")
def uninterrupted():
    """The reference: the same campaign flown in one go on the local process pool (two processes)."""
    res = run_campaign(FAMILY, range(EPISODES), METHODS, SEED, workers=2, duration_s=DURATION_S, progress=False)
    assert all(r.score is not None for r in res.results)
    return {r.key: r.reproducible_json() for r in res.results}


def _rows(path: Path) -> dict:
    lines = path.read_text().splitlines()
    assert json.loads(lines[0])["format"] == "ogccmpc-campaign-results"
    rows = [EpisodeResult.from_json(json.loads(line)) for line in lines[1:]]
    assert len({r.key for r in rows}) == len(rows), "a run was written twice"
    return {r.key: r.reproducible_json() for r in rows}


def _wait_for_rows(path: Path, n: int, proc: subprocess.Popen, deadline_s: float) -> None:
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end:
        if path.exists() and len(path.read_bytes().splitlines()) >= 1 + n:
            return
        if proc.poll() is not None:
            pytest.fail(f"campaign ended (exit {proc.returncode}) before writing {n} rows")
        time.sleep(0.05)
    pytest.fail(f"no {n} rows in {path} within {deadline_s} s")


def test_that_a_campaign_killed_midway_resumes_to_the_uninterrupted_results(uninterrupted, tmp_path):
    results = tmp_path / "runs.jsonl"
    cmd = COMPANION + ARGS + ["--workers", "1", "--results", str(results)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_for_rows(results, 1, proc, DEADLINE_S)
        os.killpg(proc.pid, signal.SIGKILL)  # no chance to clean up: as a node lost mid-campaign
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    done_before = _rows(results)
    assert 1 <= len(done_before) < len(uninterrupted), "the kill did not land midway"

    # Without --resume the file is protected; with it, only the missing runs are flown.
    refused = subprocess.run(cmd, capture_output=True, text=True, timeout=DEADLINE_S)
    assert refused.returncode == 2 and "--resume" in refused.stderr and "Traceback" not in refused.stderr
    resumed = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=DEADLINE_S)
    assert resumed.returncode == 0, resumed.stderr
    assert "hyperplane" in resumed.stdout and "deterministic" in resumed.stdout

    final = _rows(results)
    assert final == uninterrupted
    for key, row in done_before.items():  # the runs done before the kill were kept, not flown again
        assert final[key] == row
    wall = [json.loads(line)["wall_time_s"] for line in results.read_text().splitlines()[1:]]
    assert len(wall) == len(uninterrupted)


def _sigint_default() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_that_ctrl_c_ends_a_campaign_promptly_keeping_every_finished_run(tmp_path):
    """Ctrl-C (SIGINT to the process group) cancels the queued runs instead of flying them all first."""
    results = tmp_path / "runs.jsonl"
    many = list(ARGS)
    many[many.index("--episodes") + 1] = "200"  # 400 runs: minutes to fly them all
    # Ctrl-C as a terminal delivers it, whatever the suite inherited: a shell that starts the
    # suite in the background (`make test &`) ignores SIGINT, every child inherits that, and
    # the campaign would never see the interrupt (two verification runs hung here that way)
    proc = subprocess.Popen(COMPANION + many + ["--workers", "2", "--results", str(results)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_sigint_default)
    try:
        _wait_for_rows(results, 1, proc, DEADLINE_S)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)
        _, stderr = proc.communicate(timeout=60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr[-2000:]
    assert "queued runs cancelled" in stderr
    rows = _rows(results)  # every line whole, none twice
    assert 1 <= len(rows) < 100, (len(rows), took)


def test_that_a_pool_worker_takes_ctrl_c_in_a_run_and_ignores_it_while_it_waits_for_one():
    """Ctrl-C reaches every process of the group. A worker waiting for its next run used to die
    in the pool's queue read, with a traceback on the terminal (a clean-clone CI run failed the
    test above on it); now only a run in flight is interrupted, and the worker lives on."""
    from concurrent.futures import ProcessPoolExecutor

    from companion.offline.campaign.run import _take_interrupts_only_in_runs, interruptible

    with ProcessPoolExecutor(max_workers=1, initializer=_take_interrupts_only_in_runs) as pool:
        pid = pool.submit(os.getpid).result(timeout=30)
        time.sleep(0.5)  # back in its wait for the next run
        os.kill(pid, signal.SIGINT)
        time.sleep(0.5)
        assert pool.submit(os.getpid).result(timeout=30) == pid
        run = pool.submit(interruptible, time.sleep, 30.0)
        deadline = time.monotonic() + 10.0
        while not run.done() and time.monotonic() < deadline:  # until the run has started and taken it
            os.kill(pid, signal.SIGINT)
            time.sleep(0.2)
        assert run.done() and isinstance(run.exception(timeout=0), KeyboardInterrupt)
        assert pool.submit(os.getpid).result(timeout=30) == pid


def test_that_the_results_file_keeps_what_it_holds_and_drops_an_unfinished_line(tmp_path):
    path = tmp_path / "r.jsonl"
    header = campaign_header("crossing", 3, 0.9, 6.0)
    row = EpisodeResult(episode=0, method="paper", family="crossing", seed=3, sim_seed=11, error="RuntimeError: x",
                        wall_time_s=1.5)
    with ResultsFile(path, header) as store:
        store.append(row)
    with path.open("a") as f:
        f.write('{"episode": 1, "method": "pap')  # killed in the middle of a write
    with pytest.raises(ValueError, match="pass --resume"):
        ResultsFile(path, header)
    with pytest.raises(ValueError, match="written for seed = 3, this campaign has 4"):
        ResultsFile(path, campaign_header("crossing", 4, 0.9, 6.0), resume=True)
    with ResultsFile(path, header, resume=True) as store:
        assert (0, "paper") in store and (1, "paper") not in store and len(store) == 1
        assert store.results([(1, "paper"), (0, "paper")]) == [row]
    assert path.read_text().endswith("}\n")  # the unfinished line is gone
    path.write_text(json.dumps(header) + "\nnot json\n")
    with pytest.raises(ValueError, match=r"r.jsonl:2: not a JSON line"):
        ResultsFile(path, header, resume=True)


# --------------------------------------------------------------------------- Dask


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_port(port: int, procs: list[subprocess.Popen], deadline_s: float) -> None:
    t_end = time.monotonic() + deadline_s
    while time.monotonic() < t_end:
        for p in procs:
            if p.poll() is not None:
                pytest.fail(f"{p.args[:4]} ended early (exit {p.returncode})")
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.settimeout(0.5)
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.2)
    pytest.fail(f"the Dask scheduler did not listen on 127.0.0.1:{port} within {deadline_s} s")


def _wait_for_workers(address: str, n: int, deadline_s: float) -> None:
    from distributed import Client

    with Client(address, timeout=deadline_s, set_as_default=False) as client:
        client.wait_for_workers(n, timeout=deadline_s)


def test_that_a_dask_cluster_flies_the_campaign_to_the_local_results(uninterrupted, tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path / "logs"
    logs.mkdir()
    procs: list[subprocess.Popen] = []

    def start(name: str, argv: list[str]) -> None:
        with (logs / f"{name}.log").open("w") as log:
            procs.append(subprocess.Popen([sys.executable, "-m", *argv], stdout=log, stderr=subprocess.STDOUT,
                                          cwd=tmp_path, start_new_session=True))

    try:
        start("scheduler", ["distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", str(port),
                            "--no-dashboard"])
        _wait_for_port(port, procs, 60.0)
        for i in range(2):
            start(f"worker{i}", ["distributed.cli.dask_worker", address, "--host", "127.0.0.1", "--nworkers", "1",
                                 "--nthreads", "1", "--no-dashboard", "--name", f"w{i}"])
        _wait_for_workers(address, 2, 60.0)
        results = tmp_path / "dask.jsonl"
        done = subprocess.run(COMPANION + ARGS + ["--scheduler", address, "--results", str(results)],
                              capture_output=True, text=True, timeout=DEADLINE_S, cwd=tmp_path)
        assert done.returncode == 0, done.stderr + "".join(p.read_text() for p in logs.iterdir())
        assert _rows(results) == uninterrupted
        assert "on 2 worker(s)" in done.stdout
    finally:
        for p in procs:
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(timeout=15)


def test_that_an_unreachable_scheduler_is_one_clear_error(monkeypatch, capsys, tmp_path):
    import companion.offline.campaign.run as run_module
    from companion.cli import main

    monkeypatch.setattr(run_module, "SCHEDULER_TIMEOUT_S", 2.0)
    code = main(ARGS + ["--scheduler", f"tcp://127.0.0.1:{_free_port()}", "--results", str(tmp_path / "r.jsonl")])
    err = capsys.readouterr().err
    assert code == 2 and "cannot reach the Dask scheduler at tcp://127.0.0.1:" in err and "Traceback" not in err
