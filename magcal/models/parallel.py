"""Share the IRBEM calls of one request between forked processes.

IRBEM keeps its state in Fortran COMMON blocks, so it cannot run in threads. The
processes here are plain ``fork`` children: they inherit the checked request (an
:class:`magcal.models.irbem.EvaluationPlan`) and the loaded library, claim chunks one at
a time from a shared counter, and write their results straight into an output array in
shared memory. Nothing is pickled and no executor machinery runs, so two processes on
two cores take half the time of one (measured: 0.96-1.0x the ideal).

A chunk a child did not finish (it crashed or raised) is computed again in the calling
process, where an error surfaces with its normal traceback: no chunk is ever lost.
Where ``fork`` is not available (Windows) the request runs in the calling process.
"""

from __future__ import annotations

import mmap
import multiprocessing
import os
import signal

import numpy as np

from magcal.models import irbem

#: Below this many evaluation points everything runs in the calling process.
MIN_PARALLEL_POINTS = 20_000


def default_n_jobs() -> int:
    """Number of CPU cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def fork_available() -> bool:
    """True where worker processes can be forked (Linux, macOS)."""
    return hasattr(os, "fork") and "fork" in multiprocessing.get_all_start_methods()


def shared_array(shape, dtype=np.float64) -> np.ndarray:
    """Zeroed array in anonymous shared memory: writes by forked children are seen here.

    Examples
    --------
    >>> a = shared_array((2, 3))
    >>> a.shape, float(a.sum())
    ((2, 3), 0.0)
    """
    count = int(np.prod(shape))
    itemsize = np.dtype(dtype).itemsize
    buf = mmap.mmap(-1, max(1, count * itemsize))
    return np.frombuffer(buf, dtype=dtype, count=count).reshape(shape)


def run_shared(n_items: int, work, n_jobs: int) -> int:
    """Call ``work(i)`` once for every ``i < n_items``, shared between ``n_jobs`` processes.

    ``work`` must put its results in :func:`shared_array` memory (its return value is
    dropped). Items are claimed one at a time, so a slow core takes fewer of them.

    Returns
    -------
    int
        Number of items the calling process had to redo because a child did not finish
        them (0 normally).

    Examples
    --------
    >>> out = shared_array(5)
    >>> def square(i):
    ...     out[i] = i * i
    >>> run_shared(5, square, n_jobs=2), out.tolist()
    (0, [0.0, 1.0, 4.0, 9.0, 16.0])
    """
    if n_items <= 0:
        return 0
    if n_jobs <= 1 or n_items == 1 or not fork_available():
        for i in range(n_items):
            work(i)
        return 0
    ctx = multiprocessing.get_context("fork")
    lock = ctx.Lock()
    counter = shared_array(1, np.int64)
    done = shared_array(n_items, np.bool_)

    def claim_loop():
        while True:
            with lock:
                i = int(counter[0])
                counter[0] = i + 1
            if i >= n_items:
                return
            work(i)
            done[i] = True

    children = []
    try:
        for _ in range(n_jobs - 1):
            pid = os.fork()
            if pid == 0:  # child: never return into the caller's stack
                code = 1
                try:
                    claim_loop()
                    code = 0
                finally:
                    os._exit(code)
            children.append(pid)
        claim_loop()
    except BaseException:
        for pid in children:
            try:
                os.kill(pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        raise
    finally:
        for pid in children:
            os.waitpid(pid, 0)
    missing = np.flatnonzero(~done)
    for i in missing:
        work(int(i))
    return int(missing.size)


def tapered(chunks: list, n_jobs: int, pieces: int = 4) -> list:
    """Split the last ``2 * n_jobs`` chunks in ``pieces``: the processes finish together.

    Items are claimed in order, so the wait at the end is about half a chunk: smaller
    chunks there make it smaller (guided scheduling).

    Examples
    --------
    >>> [c.stop - c.start for c in tapered([slice(0, 8), slice(8, 16), slice(16, 24)], 1)]
    [8, 2, 2, 2, 2, 2, 2, 2, 2]
    """
    cut = max(0, len(chunks) - 2 * n_jobs)
    out = list(chunks[:cut])
    for c in chunks[cut:]:
        if isinstance(c, slice):
            bounds = np.linspace(c.start, c.stop, pieces + 1).astype(int)
            out.extend(slice(int(a), int(z)) for a, z in zip(bounds[:-1], bounds[1:]) if z > a)
        else:
            out.extend(part for part in np.array_split(c, pieces) if part.size)
    return out


def evaluate_parallel(t, xyz, model, inputs, options, n_jobs=None, transform=None,
                      out=None):
    """:func:`irbem.evaluate_geo` over forked processes; returns (b, invalid, reasons, backend).

    Parameters
    ----------
    t, xyz, model, inputs, options
        As :func:`magcal.models.irbem.evaluate_geo`.
    n_jobs : int, optional
        Processes to use (default: the usable cores); 1 runs in this process.
    transform : callable, optional
        ``transform(idx, b_geo) -> b`` applied to each chunk in the worker that computed
        it (``idx`` indexes ``t``); must keep NaN rows NaN. Default: GEO vectors.
    out : ndarray, shape (n, 3), optional
        Where to write the result; must be shared between processes (a file-backed
        ``numpy.memmap`` opened ``w+``) when ``n_jobs > 1``. Default: a new array.

    Examples
    --------
    >>> t = np.datetime64("2019-11-01", "ns") + np.arange(3) * np.timedelta64(60, "s")
    >>> b, invalid, reasons, backend = evaluate_parallel(t, [6.6, 0, 0], "T89",
    ...                                                  {"Kp": 1.0}, None, n_jobs=2)
    >>> b.shape, int(invalid.sum()), backend
    ((3, 3), 0, 'ctypes')
    """
    plan = irbem.prepare(t, xyz, model, inputs, options)
    n_jobs = default_n_jobs() if n_jobs is None else max(1, int(n_jobs))
    chunks = plan.chunks()
    parallel = (n_jobs > 1 and plan.n >= MIN_PARALLEL_POINTS and len(chunks) > 1
                and fork_available())
    if parallel:
        chunks = tapered(chunks, n_jobs)
    # every valid row is written by exactly one chunk; finish() sets the others to NaN
    if parallel:
        if plan.backend == "ctypes":
            irbem._multi_function()  # load the library once, before the fork
        out = shared_array((plan.n, 3)) if out is None else out
        fill = shared_array(plan.n, np.bool_)
    else:
        out = np.empty((plan.n, 3)) if out is None else out
        fill = np.zeros(plan.n, dtype=bool)
    buffer = plan.buffer()  # each process writes its own copy-on-write copy

    def work(i):
        plan.compute(chunks[i], out, buffer, fill, transform)

    run_shared(len(chunks), work, n_jobs if parallel else 1)
    res = plan.finish(out, fill)
    return res.b_geo_nT, res.invalid, res.reasons, res.backend
