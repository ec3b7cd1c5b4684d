"""Flying a campaign: each (episode, method) run in lockstep, on a local process pool or a Dask cluster.

A run is a pure function of ``(family, seed, index, method, c_min, duration_s)`` (and the
noise correlation, the vehicle profile and the planner's QP backend)
(:class:`EpisodeTask`): the encounter and the simulator seed come from ``(seed, index)``,
so a run gives the same result in this process, in a pool worker or on another machine
(timing fields aside). Finished runs are appended to the results file as they complete
(:mod:`companion.offline.campaign.store`).
"""

from __future__ import annotations

import logging
import math
import os
import signal
import time
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator, Sequence

from companion.core.planner.config import SOLVERS
from companion.errors import ConfigError, InputError, LinkError
from companion.offline.campaign.generate import (DEFAULT_DURATION_S, FAMILIES, MAX_DURATION_S, METHODS, episode_sim_seed,
                                                generate_scenario, profile_autopilot, profile_response_state)
from companion.offline.campaign.progress import Progress
from companion.offline.campaign.results import CampaignResult, EpisodeResult
from companion.offline.campaign.score import score_run
from companion.offline.campaign.stats import summarise
from companion.offline.campaign.store import ResultsFile, campaign_header
from companion.offline.harness import run_lockstep  # imports mavsim (the harness exception of the dependency rule)

logger = logging.getLogger(__name__)

#: Simulated seconds a run goes on after the truth says the goal was reached.
STOP_AFTER_GOAL_S = 0.5
#: Seconds to wait for a Dask scheduler to answer.
SCHEDULER_TIMEOUT_S = 20.0
#: Most episodes in one campaign (``--episodes``; the indices of ``--episode``): the
#: campaign holds every run's key and result in memory, and 100,000 episodes of four
#: methods at about 10 s each are already weeks of one core.
MAX_EPISODES = 100_000
#: Most local worker processes per CPU (``--workers``): a run is CPU-bound, so more processes
#: than CPUs only share them, and each worker holds its own numpy, OSQP and mavsim.
WORKERS_PER_CPU = 4


def max_workers() -> int:
    """The most local worker processes a campaign starts: :data:`WORKERS_PER_CPU` per CPU."""
    return WORKERS_PER_CPU * (os.cpu_count() or 1)


@dataclass(frozen=True)
class EpisodeTask:
    """One (episode, method) run of a campaign; picklable for the process pool and Dask."""

    family: str
    seed: int
    index: int
    method: str
    c_min: float = 0.90
    duration_s: float = DEFAULT_DURATION_S
    noise_correlation_s: float = 0.0
    vehicle: str = "lag"
    solver: str = "osqp"


def run_episode(task: EpisodeTask, *, keep_records: bool = False) -> EpisodeResult:
    """Generate, fly and score one episode with one method; never raises (errors are reported).

    With ``keep_records`` the :class:`~companion.offline.harness.RunResult` is kept in
    :attr:`EpisodeResult.run`.
    """
    key = dict(episode=task.index, method=task.method, family=task.family, seed=task.seed,
               sim_seed=episode_sim_seed(task.seed, task.index))
    t0 = time.perf_counter()
    try:
        data = generate_scenario(task.family, task.seed, task.index, c_min=task.c_min, duration_s=task.duration_s,
                                 noise_correlation_s=task.noise_correlation_s, vehicle=task.vehicle)
        run = run_lockstep(data, seed=key["sim_seed"], stop_after_goal_s=STOP_AFTER_GOAL_S, formulation=task.method,
                           autopilot=profile_autopilot(task.vehicle), solver=task.solver)
        return EpisodeResult(**key, score=score_run(run, data), wall_time_s=time.perf_counter() - t0,
                             run=run if keep_records else None)
    except Exception as exc:  # one bad episode must not end a campaign of hundreds
        # one line per failed run (a campaign may fail hundreds); the traceback with -vv
        logger.error("episode %d method %s failed: %s: %s", task.index, task.method, type(exc).__name__, exc)
        logger.debug("episode %d method %s failed", task.index, task.method, exc_info=True)
        return EpisodeResult(**key, error=f"{type(exc).__name__}: {exc}", wall_time_s=time.perf_counter() - t0)


@contextmanager
def open_executor(workers: int, scheduler: str | None = None) -> Iterator[tuple[Executor | None, int]]:
    """The executor that runs the episodes, and how many workers it has.

    ``scheduler``: the address of a Dask distributed scheduler (``tcp://host:8786``); its
    client's ``concurrent.futures`` executor runs the episodes on the cluster's workers
    (which need only this package installed). Otherwise a local process pool of
    ``workers`` processes, or none (this process) for one worker.

    Raises
    ------
    ConfigError
        ``scheduler`` is given but ``distributed`` is not installed.
    LinkError
        The scheduler does not answer within ``SCHEDULER_TIMEOUT_S``.
    """
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise ConfigError("--scheduler needs Dask distributed: pip install 'ogccmpc[cluster]'") from None
        try:
            client = Client(scheduler, timeout=SCHEDULER_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise LinkError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            n = len(client.scheduler_info().get("workers", {}))
            logger.info("Dask scheduler %s: %d worker(s)", scheduler, n)
            yield client.get_executor(pure=False), n
        finally:
            client.close()
    elif workers == 1:
        yield None, 1
    else:
        with ProcessPoolExecutor(max_workers=workers, initializer=_take_interrupts_only_in_runs) as pool:
            yield pool, workers


_in_run = False  # a local pool worker's: inside :func:`interruptible`


def _take_interrupts_only_in_runs() -> None:
    """A local pool worker's Ctrl-C handler: it interrupts a run, never the worker's wait for one.

    Ctrl-C in a terminal reaches the whole process group. Python's default interrupted a
    worker anywhere: one waiting for its next run died in the pool's queue read with a
    traceback on the terminal (a clean-clone CI run's Ctrl-C test failed on it), and one
    that died holding the queue's lock could leave the other workers waiting for it. Now a
    worker between runs ignores Ctrl-C (the campaign process cancels the queued runs and
    shuts the pool down), and a run in flight is interrupted as before.
    """
    signal.signal(signal.SIGINT, _interrupt_run)


def _interrupt_run(signum: int, frame) -> None:
    global _in_run
    if _in_run:
        _in_run = False  # once per run: a second Ctrl-C while the run unwinds is not raised into the unwinding
        raise KeyboardInterrupt


def interruptible(fn: Callable, *args):
    """``fn(*args)`` in a local pool worker, interruptible by Ctrl-C (:func:`_take_interrupts_only_in_runs`)."""
    global _in_run
    try:
        _in_run = True
        return fn(*args)
    finally:
        _in_run = False


def _stop(futures: dict, take: Callable[[Future], None]) -> None:
    """Interrupted (Ctrl-C): cancel the queued runs, and record the ones in flight as they finish.

    Without this the executor's shutdown flew every queued run before the campaign ended
    (a pool worker returns an interrupted run as its result and takes the next): up to
    hours of runs whose results were then thrown away. A run in flight is bounded by one
    episode; one interrupted in its worker (Ctrl-C reaches the whole process group) comes
    back as KeyboardInterrupt and is not recorded: ``--resume`` flies it. A second
    interrupt stops recording.
    """
    cancelled = sum(f.cancel() for f in futures)
    running = [f for f in futures if not f.done()]
    logger.warning("interrupted: %d queued runs cancelled; recording the %d in flight as they finish", cancelled, len(running))
    try:
        for fut in as_completed(running):
            if not fut.cancelled() and not isinstance(fut.exception(), KeyboardInterrupt):
                take(fut)
    except KeyboardInterrupt:
        logger.warning("interrupted again: the runs still in flight are not recorded")


def fly_tasks(run: Callable, todo: Sequence, workers: int, scheduler: str | None,
              finished: Callable) -> tuple[int, int]:
    """``finished(run(task))`` for every task, on :func:`open_executor`'s executor; returns (workers, runs lost).

    ``run`` never raises (it reports errors in its result); a task whose worker died is lost:
    logged and counted. Ctrl-C cancels the queued tasks and records the ones in flight
    (:func:`_stop`); local pool workers take it only inside a run (:func:`interruptible`).
    """
    lost = 0
    with open_executor(workers, scheduler) as (executor, n_workers):
        if executor is None:
            for task in todo:
                finished(run(task))
            return n_workers, 0
        call = (interruptible, run) if isinstance(executor, ProcessPoolExecutor) else (run,)
        futures: dict[Future, object] = {executor.submit(*call, task): task for task in todo}

        def take(fut: Future) -> None:
            nonlocal lost
            try:
                finished(fut.result())
            except Exception as exc:  # the worker died (run itself never raises)
                lost += 1
                logger.error("%s lost: %s: %s", futures[fut], type(exc).__name__, exc)

        try:
            for fut in as_completed(futures):
                take(fut)
        except KeyboardInterrupt:
            _stop(futures, take)
            raise
    return n_workers, lost


def run_campaign(family: str, episodes: Sequence[int], methods: Sequence[str], seed: int, *,
                 workers: int | None = None, c_min: float = 0.90, duration_s: float = DEFAULT_DURATION_S,
                 progress: bool | str | None = None, results_path: str | Path | None = None, resume: bool = False,
                 scheduler: str | None = None, noise_correlation_s: float = 0.0,
                 vehicle: str = "lag", solver: str = "osqp") -> CampaignResult:
    """Fly ``episodes`` (indices) of a ``family`` campaign with every method.

    Parameters
    ----------
    workers : local processes (default: CPU count); ignored with ``scheduler``.
    progress : ``"bar"``, ``"log"``, ``"off"`` or ``"auto"`` (see
        :class:`~companion.offline.campaign.progress.Progress`); ``None`` or ``True``: ``"auto"``,
        ``False``: ``"off"``.
    results_path : append every finished run to this JSON-lines file; the result is then
        computed from the file. ``resume`` continues a file that already holds runs and
        runs only the missing ones.
    scheduler : address of a Dask distributed scheduler to run the episodes on.
    noise_correlation_s : correlation time of mavsim's drone position error and obstacle measurement errors (s; 0: white).
    vehicle : mavsim's vehicle profile, ``"lag"``, ``"px4"`` or ``"ardupilot"`` (see :func:`generate_scenario`);
        ``"ardupilot"`` also flies mavsim's ArduPilot personality (:func:`profile_autopilot`).
    solver : the planner's QP backend (``[planner] solver``: ``"osqp"`` or ``"piqp"``).
    """
    if family not in FAMILIES:
        raise InputError(f"unknown campaign family {family!r} (known: {', '.join(FAMILIES)})")
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"unknown method(s) {', '.join(unknown) or '(none given)'} (known: {', '.join(METHODS)})")
    episodes, methods = tuple(episodes), tuple(methods)
    if len(episodes) > MAX_EPISODES or any(not 0 <= i < MAX_EPISODES for i in episodes):
        raise InputError(f"a campaign has at most {MAX_EPISODES} episodes, indices 0 to {MAX_EPISODES - 1}")
    if not (math.isfinite(duration_s) and 0.0 < duration_s <= MAX_DURATION_S):
        raise InputError(f"duration_s = {duration_s!r} must be > 0 and at most {MAX_DURATION_S:g} s")
    if solver not in SOLVERS:
        raise InputError(f"solver = {solver!r} is not one of {', '.join(SOLVERS)}")
    if workers is not None and not 1 <= workers <= max_workers():
        raise InputError(f"workers = {workers!r} must be from 1 to {max_workers()} "
                         f"({WORKERS_PER_CPU} per CPU, {os.cpu_count() or 1} CPUs)")
    workers = workers or os.cpu_count() or 1
    keys = [(i, m) for i in episodes for m in methods]
    response_state = profile_response_state(vehicle)
    store = (ResultsFile(results_path, campaign_header(family, seed, c_min, duration_s, noise_correlation_s, vehicle,
                                                       response_state, profile_autopilot(vehicle), solver), resume=resume)
             if results_path is not None else None)
    in_memory: dict[tuple[int, str], EpisodeResult] = {}
    todo = [EpisodeTask(family, seed, i, m, c_min, duration_s, noise_correlation_s, vehicle, solver)
            for i, m in keys if store is None or (i, m) not in store]
    workers = max(1, min(workers, len(todo)))  # a pool never starts more processes than there are runs
    mode = "auto" if progress is None or progress is True else ("off" if progress is False else progress)
    bar = Progress(f"campaign {family}", len(keys), len(keys) - len(todo), mode=mode)
    t0 = time.perf_counter()

    def finished(result: EpisodeResult) -> None:
        if store is not None:
            store.append(result)
        in_memory[result.key] = result
        bar.update(result)

    try:
        n_workers, lost = fly_tasks(run_episode, todo, workers, scheduler, finished)
    finally:
        bar.close()
        if store is not None:
            store.close()
    results = store.results(keys) if store is not None else [in_memory[k] for k in keys if k in in_memory]
    return CampaignResult(family, seed, episodes, methods, c_min, duration_s, tuple(results),
                          summarise(results, methods, c_min), time.perf_counter() - t0, n_workers, lost,
                          noise_correlation_s)
