"""Where a study's episodes run: a process pool on this machine, or Ray tasks on a local Ray or a cluster.

An episode is a pure function of its spec: ``fn(spec) -> result``, both picklable, with no state
shared between episodes (each makes its own twin and estimators). So the engine only decides where
it runs, and every engine gives the same results::

    engine = EngineConfig("local", workers=2)                     # or EngineConfig("ray", ray_address=...)
    for outcome in stream_episodes(render_sequence, specs, engine, label="robustness"):
        ...                                                       # as they finish, with a progress bar
    outcomes = run_episodes(render_sequence, specs, engine)       # all of them, in spec order

- ``local`` (the default): a pool of ``workers`` processes (default: this machine's CPUs), started
  with ``spawn`` so no process inherits another's OpenGL context or numba state.
- ``ray``: each episode a Ray task of one CPU, at most ``workers`` in flight (default: the
  cluster's CPUs), on the Ray at ``ray_address`` or on a local Ray started for the study (and
  stopped after it; a Ray already running in this process is used and left running).

Episodes start in the order given, or longest first when the caller says what each is expected
to cost (``cost``): with a few episodes of unequal length on a few workers, the long ones started
last would leave the other workers idle at the end (the robustness study's blurred and random
scenes draw four times per frame and take half as long again as the others).

Either way, an episode that raises (or whose worker dies) is tried once more; one that fails twice
is reported in its :class:`Outcome` (``error``) and the others complete. Each episode runs on one
core (OpenCV's and the CPU renderer's threads set to 1, as Ray sets for a task of one CPU, and the
estimator's second image on the same thread as the first), so N workers use N cores and the
episodes per hour per core a study reports are one core's.
"""

from __future__ import annotations

import concurrent.futures as futures
import dataclasses
import multiprocessing
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from typing import Any

ENGINES = ("local", "ray")
ATTEMPTS = 2  # an episode is tried once more after a failure, then reported


class EngineError(RuntimeError):
    """The engine cannot run (Ray is not installed, or the cluster cannot be reached); the message says why."""


@dataclasses.dataclass(frozen=True)
class EngineConfig:
    """Where episodes run.

    Attributes:
        name: "local" (a process pool) or "ray".
        workers: episodes at once; None: this machine's CPUs (local) or the cluster's (ray).
        ray_address: ray only: the cluster to connect to ("host:6379", "auto", "ray://host:10001");
            None starts a local Ray for the study.
    """

    name: str = "local"
    workers: int | None = None
    ray_address: str | None = None

    def __post_init__(self) -> None:
        if self.name not in ENGINES:
            raise ValueError(f"engine: expected one of {', '.join(ENGINES)}, got {self.name!r}")
        if self.workers is not None and (isinstance(self.workers, bool) or not isinstance(self.workers, int)
                                         or self.workers < 1):
            raise ValueError(f"workers: expected a whole number >= 1, got {self.workers!r}")
        if self.ray_address is not None and self.name != "ray":
            raise ValueError(f"ray_address: only the ray engine connects to a cluster (engine is {self.name!r})")

    def describe(self, workers_used: int | None = None) -> dict[str, Any]:
        """The engine as ``study.json`` records it."""
        out: dict[str, Any] = {"name": self.name, "workers": workers_used or self.workers}
        if self.name == "ray":
            out["ray_address"] = self.ray_address
            out["ray_version"] = _ray_version()
        return out


@dataclasses.dataclass(frozen=True)
class Outcome:
    """One episode's end.

    Attributes:
        index: the spec's position in the list given.
        spec: the spec.
        result: what the episode returned, or None when it failed twice.
        error: "ExceptionType: message" of the last failure, or None.
        attempts: how many times it ran (1, or 2 after a retry).
        episode_s: wall seconds inside the episode function (its last attempt).
        failures: the error of each failed attempt.
        workers: how many episodes the engine ran at once.
    """

    index: int
    spec: Any
    result: Any
    error: str | None
    attempts: int
    episode_s: float
    failures: tuple[str, ...] = ()
    workers: int | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


def call_episode(fn: Callable[[Any], Any], spec: Any) -> tuple[Any, float]:
    """Run one episode on one core; (result, seconds inside ``fn``). What the workers of both engines run."""
    _one_core()
    start = time.perf_counter()
    result = fn(spec)
    return result, time.perf_counter() - start


def _one_core() -> None:
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # before the twin imports PyOpenGL in this worker
    # Mesa's CPU renderer (llvmpipe) starts a thread per core unless told: on a core of its own an episode
    # renders as fast with one (the same pixels), and N workers do not fight over N cores
    os.environ.setdefault("LP_NUM_THREADS", "1")
    import cv2

    import estimator

    cv2.setNumThreads(1)
    estimator.use_second_thread(False)


def stream_episodes(fn: Callable[[Any], Any], specs: Sequence[Any], engine: EngineConfig | None = None, *,
                    label: str = "episodes", progress: bool = True,
                    cost: Callable[[Any], float] | None = None) -> Iterator[Outcome]:
    """Run ``fn`` on every spec and yield each :class:`Outcome` as it finishes.

    Args:
        fn: a module-level function (it is pickled by reference): the episode.
        specs: the episodes' specs (picklable).
        engine: where to run them; None: the local pool on every CPU.
        label: the progress bar's label.
        progress: show a progress bar on stderr.
        cost: a spec's expected cost in any unit; the costliest episodes start first (ties in the
            order given). None: in the order given.

    Raises:
        EngineError: the ray engine without Ray installed, or a cluster that cannot be reached.
    """
    engine = engine or EngineConfig()
    specs = list(specs)
    if not specs:
        return
    from tqdm import tqdm

    order = list(range(len(specs)))
    if cost is not None:
        costs = [float(cost(spec)) for spec in specs]
        order.sort(key=lambda i: -costs[i])
    if engine.name == "local":
        def runner(fn, specs, engine):
            return _run_local(fn, specs, engine, order)
    else:
        ray, started = start_ray(engine)  # connected (or refused) before the progress bar shows

        def runner(fn, specs, engine):
            return _run_ray(fn, specs, engine, order, ray, started)
    failed = 0
    with tqdm(total=len(specs), desc=label, unit="episode", file=sys.stderr, disable=not progress,
              dynamic_ncols=True) as bar:
        for outcome in runner(fn, specs, engine):
            failed += not outcome.ok
            if failed:
                bar.set_postfix(failed=failed)
            if not outcome.ok:
                bar.write(f"{label}: episode {outcome.index} failed twice: {outcome.error}", file=sys.stderr)
            bar.update(1)
            yield outcome


def run_episodes(fn: Callable[[Any], Any], specs: Sequence[Any], engine: EngineConfig | None = None, *,
                 label: str = "episodes", progress: bool = True,
                 cost: Callable[[Any], float] | None = None) -> list[Outcome]:
    """Every episode's :class:`Outcome`, in the order of ``specs`` (whatever order they started or finished in)."""
    outcomes = list(stream_episodes(fn, specs, engine, label=label, progress=progress, cost=cost))
    return sorted(outcomes, key=lambda o: o.index)


def workers_for(engine: EngineConfig, episodes: int) -> int:
    """How many episodes the local engine runs at once: ``workers``, or one per CPU, never more than episodes."""
    workers = engine.workers or os.cpu_count() or 1
    return max(1, min(workers, episodes))


def workers_used(engine: EngineConfig, episodes: int) -> int | None:
    """The workers a study's ``study.json`` records: the local pool's size, or ``--workers`` on Ray (None: every
    CPU of the cluster)."""
    return workers_for(engine, episodes) if engine.name == "local" else engine.workers


# --- local: a process pool --------------------------------------------------------------------


@dataclasses.dataclass
class _Pending:
    index: int
    attempts: int = 0
    failures: list[str] = dataclasses.field(default_factory=list)


def _describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


def _queue(order: list[int]) -> list[_Pending]:
    """The episodes waiting to start: ``pop()`` takes them in ``order`` (a retry is appended, so it goes next)."""
    return [_Pending(i) for i in reversed(order)]


def _run_local(fn, specs: list, engine: EngineConfig, order: list[int]) -> Iterator[Outcome]:
    workers = workers_for(engine, len(specs))
    context = multiprocessing.get_context("spawn")
    queue = _queue(order)
    pool = futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
    running: dict[futures.Future, _Pending] = {}
    try:
        while queue or running:
            while queue and len(running) < workers:
                item = queue.pop()
                item.attempts += 1
                running[pool.submit(call_episode, fn, specs[item.index])] = item
            done, _ = futures.wait(running, return_when=futures.FIRST_COMPLETED)
            broken = False
            for future in done:
                item = running.pop(future)
                try:
                    result, seconds = future.result()
                except futures.process.BrokenProcessPool as e:  # a worker died (a crash, the OOM killer)
                    broken = True
                    outcome = _failed(item, specs, e, queue, workers)
                except Exception as e:  # noqa: BLE001 - the episode's own error: retried once, then reported
                    outcome = _failed(item, specs, e, queue, workers)
                else:
                    outcome = _succeeded(item, specs, result, seconds, workers)
                if outcome is not None:
                    yield outcome
            if broken:  # every episode still in the dead pool failed with it: each counts one attempt
                for future, item in list(running.items()):
                    running.pop(future)
                    outcome = _failed(item, specs, futures.process.BrokenProcessPool("a worker process died"), queue,
                                      workers)
                    if outcome is not None:
                        yield outcome
                pool.shutdown(wait=False, cancel_futures=True)
                pool = futures.ProcessPoolExecutor(max_workers=workers, mp_context=context)
    except BaseException:  # Ctrl-C, SIGTERM, or the caller stopped reading: do not wait for the episodes under way
        _stop_workers(pool)
        raise
    pool.shutdown(wait=True)


def _stop_workers(pool: futures.ProcessPoolExecutor) -> None:
    """End the pool's worker processes now, episodes under way included: left to finish, they would run
    on, orphaned, after the study stopped (a SIGTERM reaches only the study's own process)."""
    # the executor offers no public handle; after a shutdown the attributes are None
    processes = list((getattr(pool, "_processes", None) or {}).values())
    manager = getattr(pool, "_executor_manager_thread", None)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=5.0)
    # Let the pool's manager thread see its workers gone and close its wake-up pipe now: left running,
    # it closed that pipe while the interpreter's exit hook was writing to it, and the stopped study
    # ended with an "OSError: Bad file descriptor" traceback (seen once in CI, SIGTERM 4 s in).
    if manager is not None:
        manager.join(timeout=5.0)


def _succeeded(item: _Pending, specs: list, result, seconds: float, workers: int) -> Outcome:
    """The :class:`Outcome` of an episode that returned (after any earlier failed attempts)."""
    return Outcome(item.index, specs[item.index], result, None, item.attempts, seconds, tuple(item.failures), workers)


def _failed(item: _Pending, specs: list, error: BaseException | str, queue: list, workers: int) -> Outcome | None:
    """Queue the episode again after its first failure; its failed :class:`Outcome` after the last."""
    item.failures.append(error if isinstance(error, str) else _describe(error))
    if item.attempts < ATTEMPTS:
        queue.append(item)
        return None
    return Outcome(item.index, specs[item.index], None, item.failures[-1], item.attempts, float("nan"),
                   tuple(item.failures), workers)


# --- ray: one task per episode ----------------------------------------------------------------


def _ray_version() -> str | None:
    try:
        from importlib.metadata import version

        return version("ray")
    except Exception:  # noqa: BLE001 - not installed
        return None


def import_ray():
    """The ``ray`` module, or an :class:`EngineError` saying how to install it."""
    try:
        import ray
    except ImportError as e:
        raise EngineError("the ray engine needs Ray: pip install 'softarm-twin[scale]' (or pip install ray)") from e
    return ray


def start_ray(engine: EngineConfig):
    """Connect to ``engine.ray_address`` or start a local Ray; (ray module, whether this call started it)."""
    ray = import_ray()
    if ray.is_initialized():
        return ray, False
    kwargs: dict[str, Any] = {"include_dashboard": False, "configure_logging": True, "logging_level": "warning"}
    if engine.ray_address is None:
        kwargs["num_cpus"] = engine.workers or os.cpu_count() or 1
    try:
        ray.init(address=engine.ray_address, **kwargs)
    except (ConnectionError, RuntimeError, ValueError) as e:
        where = engine.ray_address or "a local Ray"
        raise EngineError(f"--ray-address {where}: cannot connect: {e}") from e
    return ray, True


def _run_ray(fn, specs: list, engine: EngineConfig, order: list[int], ray, started: bool) -> Iterator[Outcome]:
    try:
        # our own retry (ray's max_retries = 0), so both engines retry alike: once, whatever failed
        task = ray.remote(num_cpus=1, max_retries=0)(call_episode)
        cpus = int(ray.cluster_resources().get("CPU", 1))
        workers = max(1, min(engine.workers or cpus, len(specs)))
        fn_ref = ray.put(fn)
        queue = _queue(order)
        running: dict[Any, _Pending] = {}
        while queue or running:
            while queue and len(running) < workers:
                item = queue.pop()
                item.attempts += 1
                running[task.remote(fn_ref, specs[item.index])] = item
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                item = running.pop(ref)
                try:
                    result, seconds = ray.get(ref)
                except ray.exceptions.RayTaskError as e:  # the episode raised: name its own error
                    cause = getattr(e, "cause", None)
                    outcome = _failed(item, specs, cause if isinstance(cause, BaseException) else e, queue, workers)
                except ray.exceptions.RayError as e:  # the worker died, the node was lost, ...
                    outcome = _failed(item, specs, e, queue, workers)
                else:
                    outcome = _succeeded(item, specs, result, seconds, workers)
                if outcome is not None:
                    yield outcome
    finally:
        if started:
            ray.shutdown()


def engine_from_args(args) -> EngineConfig:
    """The engine of ``--engine``, ``--workers`` and ``--ray-address`` (each optional on ``args``).

    Raises:
        ValueError: a bad combination (``--ray-address`` without ``--engine ray``, workers below 1).
    """
    address = getattr(args, "ray_address", None)
    name = getattr(args, "engine", None) or "local"
    if address is not None and name != "ray":
        raise ValueError(f"--ray-address {address}: it takes --engine ray (the engine is {name!r})")
    workers = getattr(args, "workers", None)
    if workers is not None and workers < 1:
        raise ValueError(f"--workers {workers}: expected 1 or more")
    return EngineConfig(name, workers, address)
