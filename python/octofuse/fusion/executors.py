"""Where independent runs execute: in this process, one after another, or as Ray tasks.

A study (:func:`octofuse.outputs.study.run_study`) is a grid of independent cells. An
executor runs a picklable top-level function on each cell's payload and reports every
outcome as soon as it is known, success or failure, so one failing cell (a bad bag, a worker
killed for memory) is reported with its error while the others go on.

Ray is optional and imported only when a Ray executor is made. Without it, ``auto`` falls back
to the serial executor; ``ray`` (or a cluster address), asked for by name, is refused.
"""

from __future__ import annotations

import contextlib
import importlib.util
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

EXECUTORS = ("auto", "serial", "ray")
RAY_MISSING = (
    "executor 'ray': Ray is not installed (pip install 'octofuse[ray]'); "
    "use --executor serial or auto to run without it"
)


@dataclass
class Outcome:
    """What running one item gave: ``value`` when ``ok``, else ``error`` (one line) and
    ``details`` (the traceback, if any)."""

    index: int
    ok: bool
    value: Any = None
    error: str = ""
    details: str = ""
    seconds: float = 0.0


class Executor(Protocol):
    name: str

    def run(
        self,
        fn: Callable[[Any], Any],
        payloads: Sequence[Any],
        on_outcome: Callable[[Outcome], None],
    ) -> None:
        """Run ``fn(payload)`` for every payload; call ``on_outcome`` once per payload, in
        the order they finish, in the calling thread."""

    def close(self) -> None: ...


def _one_line(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    return f"{type(e).__name__}: {msg}" if msg else type(e).__name__


class SerialExecutor:
    """Every item in this process, one after another (exceptions, including ``MemoryError``,
    are caught per item; ``KeyboardInterrupt`` stops the run)."""

    name = "serial"

    def run(self, fn, payloads, on_outcome) -> None:
        for i, p in enumerate(payloads):
            t0 = time.perf_counter()
            try:
                value = fn(p)
            except Exception as e:  # noqa: BLE001 - reported, the other items go on
                on_outcome(
                    Outcome(
                        i,
                        False,
                        error=_one_line(e),
                        details=traceback.format_exc(),
                        seconds=time.perf_counter() - t0,
                    )
                )
            else:
                on_outcome(Outcome(i, True, value=value, seconds=time.perf_counter() - t0))

    def close(self) -> None:
        pass


def ray_available() -> bool:
    """Whether Ray can be imported (without importing it)."""
    try:
        return importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):  # a blocked or broken installation
        return False


@contextlib.contextmanager
def ray_session(
    address: str | None = None, num_cpus: int | None = None, runtime_env: dict | None = None
) -> Iterator[Any]:
    """The ``ray`` module with a running runtime: an already initialised one is used (and
    left running); otherwise a local one (``address=None``, ``num_cpus`` CPUs) or the cluster
    at ``address`` is joined for the duration of the block."""
    import ray

    if ray.is_initialized():
        yield ray
        return
    kwargs: dict = {"include_dashboard": False, "log_to_driver": False}
    if runtime_env:
        kwargs["runtime_env"] = runtime_env
    if address:
        ray.init(address=address, **kwargs)
    else:
        ray.init(num_cpus=num_cpus, **kwargs)
    try:
        yield ray
    finally:
        ray.shutdown()


class RayExecutor:
    """Every item as a Ray task (``cpus`` CPUs and ``memory`` bytes reserved per task, so Ray
    places no more tasks on a node than it can hold). A local Ray is started unless one is
    running or ``address`` names a cluster (``"auto"``: the one this machine belongs to).
    Tasks are not retried by default: a cell that failed once fails the same way again."""

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        *,
        num_cpus: int | None = None,
        cpus: float = 1,
        memory: int | None = None,
        max_retries: int = 0,
        runtime_env: dict | None = None,
    ):
        import ray  # noqa: F401 - fail here, not in the middle of a study

        self.address, self.num_cpus, self.cpus, self.memory = address, num_cpus, cpus, memory
        self.max_retries, self.runtime_env = max_retries, runtime_env
        self._session: contextlib.ExitStack | None = None
        self._ray = None

    def _start(self):
        if self._ray is None:
            self._session = contextlib.ExitStack()
            self._ray = self._session.enter_context(
                ray_session(self.address, self.num_cpus, self.runtime_env)
            )
        return self._ray

    def run(self, fn, payloads, on_outcome) -> None:
        ray = self._start()
        opts: dict = {"num_cpus": self.cpus, "max_retries": self.max_retries}
        if self.memory:
            opts["memory"] = int(self.memory)
        task = ray.remote(_timed).options(**opts)
        fn_ref = ray.put(fn)
        started = time.perf_counter()
        pending = {task.remote(fn_ref, p): i for i, p in enumerate(payloads)}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                for ref in done:
                    i = pending.pop(ref)
                    try:
                        ok, value, error, details, seconds = ray.get(ref)
                        on_outcome(Outcome(i, ok, value, error, details, seconds))
                    except ray.exceptions.RayError as e:  # worker died, out of memory, ...
                        on_outcome(
                            Outcome(
                                i,
                                False,
                                error=_ray_error(e),
                                details=str(e),
                                seconds=time.perf_counter() - started,
                            )
                        )
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise

    def close(self) -> None:
        if self._session is not None:
            self._session.close()
        self._session, self._ray = None, None


def _timed(fn, payload):
    """Run in a Ray worker: the outcome as plain data (an exception of the cell is a result,
    not a task failure, so it is never retried and keeps its own message)."""
    t0 = time.perf_counter()
    try:
        return True, fn(payload), "", "", time.perf_counter() - t0
    except Exception as e:  # noqa: BLE001
        return False, None, _one_line(e), traceback.format_exc(), time.perf_counter() - t0


def _ray_error(e: BaseException) -> str:
    name = type(e).__name__
    text = " ".join(str(e).split())
    if "OutOfMemory" in name or "out of memory" in text.lower() or "OOM" in text:
        return f"out of memory ({name}): the worker was killed; give the cells more memory"
    return f"{name}: {text[:300]}"


def make_executor(
    kind: str = "auto",
    *,
    address: str | None = None,
    log: Callable[[str], None] | None = None,
    **ray_options,
) -> Executor:
    """``serial``, ``ray`` or ``auto`` (Ray when it is installed, else serial). Asking for Ray
    by name (``ray``, or an ``address``) without it installed raises ``ValueError``
    (:data:`RAY_MISSING`): an executor named explicitly runs or the command stops."""
    if kind not in EXECUTORS:
        raise ValueError(f"unknown executor {kind!r}; valid: {', '.join(EXECUTORS)}")
    if kind == "serial":
        return SerialExecutor()
    if not ray_available():
        if kind == "ray" or address:
            raise ValueError(RAY_MISSING)
        return SerialExecutor()
    return RayExecutor(address, **ray_options)
