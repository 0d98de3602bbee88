"""Where the partition tasks of a chain run execute: Dask's local or distributed scheduler.

:class:`Engine` maps a picklable function over a list of picklable items and returns the
results in the items' order, with a progress bar per stage (tqdm, stderr);
:meth:`Engine.submit` starts one task and returns at once, so a long stage (discovery,
alignment) runs on a worker while the driver goes on. The local engine runs Dask's
multiprocessing scheduler on one pool of ``workers`` spawned processes kept for the
whole run, also for one worker: every task then runs in a process whose BLAS uses one
thread, so a product is byte-identical whatever the number of workers (BLAS sums on
two threads differ from one thread's in the last bits). The distributed engine submits
to a ``dask.distributed`` scheduler (an address, or a ``Client``); its process workers
run BLAS on one thread as well. The partition task functions never raise (they return
failure records), so a failed partition cannot cancel the others.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable, Sequence

from magcal.errors import InputError

#: Seconds to wait for a ``--scheduler`` address to answer before giving up (exit 2).
CONNECT_TIMEOUT_S = 10.0

#: Thread-count variables of the BLAS libraries, set to 1 for local pool workers.
_BLAS_THREADS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def usable_cores() -> int:
    """Cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class Engine:
    """Run tasks on Dask.

    Parameters
    ----------
    workers : int, optional
        Local worker processes (default: the usable cores). Ignored with ``scheduler``.
    scheduler : str or distributed.Client, optional
        Address of a running ``dask.distributed`` scheduler (``tcp://host:port``) or a
        connected client.
    bars : bool
        Show a tqdm bar per stage on stderr.
    """

    def __init__(self, workers: int | None = None, scheduler=None, bars: bool = False):
        if workers is not None and workers < 1:
            raise InputError(f"--workers must be at least 1, got {workers}")
        self.workers = workers or usable_cores()
        self.bars = bars
        self._client = None
        self._own_client = False
        self._pool = None
        self._env_set: list[str] = []
        if scheduler is not None:
            self._client, self._own_client = _connect(scheduler)

    @property
    def description(self) -> str:
        if self._client is not None:
            return f"dask.distributed scheduler {self._client.scheduler.address}"
        return f"dask local scheduler, {self.workers} worker(s)"

    def map(self, func: Callable, items: Sequence, label: str) -> list:
        """``[func(item) for item in items]`` on the workers, in order."""
        if not items:
            return []
        from tqdm import tqdm

        with tqdm(total=len(items), desc=label, unit="task", file=sys.stderr,
                  disable=not self.bars, leave=True) as bar:
            if self._client is not None:
                return self._map_distributed(func, items, bar)
            return self._map_local(func, items, bar)

    def _map_local(self, func, items, bar) -> list:
        import dask
        from dask.callbacks import Callback

        class _Bar(Callback):
            def _posttask(self, key, result, dsk, state, worker_id):
                bar.update(1)

        tasks = [dask.delayed(func, pure=False)(item) for item in items]
        # the callback is given to this computation only (not made active for every
        # computation): a task started by submit() runs at the same time
        return list(dask.compute(*tasks, scheduler="processes", pool=self._get_pool(),
                                 num_workers=self.workers, callbacks=[_Bar()._callback]))

    def start_workers(self) -> None:
        """Spawn the local workers now and have each import the partition code, so a
        driver busy with something else (simulating the input) hides their start-up
        (a second or two each). Nothing waits for them; a distributed engine's workers
        are running already."""
        if self._client is None:
            pool = self._get_pool()
            for _ in range(self.workers):  # each submit spawns a worker while none is idle
                pool.submit(_import_partition_code)

    def submit(self, func: Callable, item) -> Pending:
        """Start ``func(item)`` on a worker and return at once; ``.result()`` waits for
        its value (or raises its exception). Tasks submitted before a :meth:`map` are
        started before that map's tasks (the pool serves tasks first come, first
        served)."""
        if self._client is not None:
            return Pending(self._client.submit(func, item, pure=False).result)
        import dask

        task = dask.delayed(func, pure=False)(item)
        pool = self._get_pool()
        return Pending.in_thread(lambda: dask.compute(task, scheduler="processes", pool=pool,
                                                      num_workers=1)[0])

    def _get_pool(self):
        # One pool for the whole run, handed to Dask's multiprocessing scheduler (which
        # would otherwise spawn fresh processes for every stage). Its workers run BLAS
        # on one thread each, as dask.distributed's do: N workers x N BLAS threads
        # would oversubscribe the cores. The driver's BLAS libraries are loaded first,
        # so the driver keeps its own setting.
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            import numpy  # noqa: F401
            import scipy.linalg  # noqa: F401

            for var in _BLAS_THREADS:
                if var not in os.environ:
                    self._env_set.append(var)
                    os.environ[var] = "1"
            self._pool = ProcessPoolExecutor(self.workers,
                                             mp_context=multiprocessing.get_context("spawn"),
                                             initializer=keep_freed_memory)
        return self._pool

    def _map_distributed(self, func, items, bar) -> list:
        from distributed import as_completed

        futures = self._client.map(func, list(items), pure=False)
        for _ in as_completed(futures, loop=self._client.loop):
            bar.update(1)
        return self._client.gather(futures)

    def close(self) -> None:
        """Stop the local pool; disconnect a client this engine opened."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        for var in self._env_set:
            os.environ.pop(var, None)
        self._env_set = []
        if self._client is not None and self._own_client:
            self._client.close()
        self._client = None

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Pending:
    """A started task: :meth:`result` waits for its value or raises its exception."""

    def __init__(self, wait: Callable):
        self._wait = wait

    @classmethod
    def in_thread(cls, compute: Callable) -> Pending:
        """Run ``compute()`` (a Dask computation that waits on the pool) in a driver
        thread, so the driver goes on while a worker runs the task."""
        box: dict = {}

        def target():
            try:
                box["value"] = compute()
            except BaseException as exc:  # noqa: BLE001 - handed to result()
                box["error"] = exc

        thread = threading.Thread(target=target, daemon=True)
        thread.start()

        def wait():
            thread.join()
            if "error" in box:
                raise box["error"]
            return box["value"]

        return cls(wait)

    def result(self):
        """The task's value (waits for it)."""
        return self._wait()


#: glibc ``mallopt`` parameters (malloc.h) and the values a worker sets.
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3
_KEEP_FREED = ((_M_MMAP_THRESHOLD, 32 << 20), (_M_TRIM_THRESHOLD, 1 << 30),
               (_M_TOP_PAD, 512 << 20))


def keep_freed_memory() -> bool:
    """Have glibc's malloc keep freed memory for reuse in this process; False where
    the C library is not glibc (nothing changed).

    A partition of a 10 Hz day allocates and frees arrays of 7-20 MB dozens of times;
    by default each is a fresh ``mmap`` whose pages the kernel zeroes on first touch
    and takes back on ``free``: 150,000 page faults per day, a partition taking 1.2-2.0
    s (measured). Served from a heap that is neither trimmed nor unmapped, it takes
    1.2 s every time, for 80 MB more peak memory. Every local worker calls this at
    start (the pool's initializer).
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return all(mallopt(param, value) == 1 for param, value in _KEEP_FREED)


def _import_partition_code() -> None:
    """What a worker imports to read files, fit and run partitions (see
    :meth:`Engine.start_workers`): imported while the driver starts, not when the first
    task waits for them (about a second of a small archive's run)."""
    import magcal.chain.archive  # noqa: F401
    import magcal.chain.prepare  # noqa: F401
    import magcal.io.formats  # noqa: F401
    import magcal.io.netcdf  # noqa: F401
    import magcal.missions.goes  # noqa: F401
    import magcal.models.field  # noqa: F401
    import magcal.qc.quality  # noqa: F401
    from magcal.offline import configure_offline

    configure_offline()


def _connect(scheduler):
    """A client for ``scheduler`` (address or Client); InputError when unreachable."""
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a dependency
        raise InputError("--scheduler needs the dask.distributed package") from None
    if isinstance(scheduler, Client):
        return scheduler, False
    if not isinstance(scheduler, str) or not scheduler:
        raise InputError(f"--scheduler must be an address such as tcp://host:8786, got "
                         f"{scheduler!r}")
    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s", set_as_default=False), True
    except (OSError, TimeoutError, ValueError) as exc:
        reason = " ".join(str(exc).split())  # one line, whatever distributed says
        raise InputError(f"cannot reach the dask scheduler {scheduler}: {reason}") from None
