"""Frames of an animation fanned out on Dask distributed (``pip install 'popvol[distributed]'``).

A sequence is cut into contiguous runs of frames, one per Dask worker thread, and each run is
rendered in order by :func:`popvol.sequence.render_run` in one worker process, so warm starts
still chain from frame to frame inside a run. ``render_run`` writes every frame atomically and
skips frames already written for the same scene and method, so a run that is retried after its
worker died (Dask reschedules it on another worker) renders only the frames still missing:
every frame ends up on disk once, complete.

Numba threads: a worker with one Dask thread gets ``cores // (Dask threads on its host)``
Numba threads, so two workers on two cores do not fight. :func:`local_client` spawns its
workers with ``NUMBA_NUM_THREADS`` set (Numba's pool size), and every task also calls
``numba.set_num_threads`` with the same figure (which covers workers restarted after a crash
and clusters started elsewhere, whose workers have Numba's default of one thread per core);
the number a task actually ran with is in its frames' dicts (``numba_threads``).

    from popvol.distributed import local_client, run_on_cluster
    with local_client(2) as client:
        frames = run_on_cluster(client, "scene.toml", list(range(48)), "out/frame_####.exr", {})

See docs/DISTRIBUTED.md for the measured overhead and a 100-node estimate.
"""
from __future__ import annotations

import contextlib
import inspect
import logging
import os
import re
import sys
import threading
import time
import uuid
from collections import Counter
from typing import Callable

from .errors import PopvolError

INSTALL_HINT = "pip install 'popvol[distributed]'"
CONNECT_TIMEOUT_S = 10.0
#: Dask settings of the local cluster (passed to its workers too): off the statistical profiler
#: that samples each worker every 10 ms, and slower health ticks and monitors. Idle, two
#: workers and their scheduler then use ~0.5 CPU s per 20 s instead of ~3.9 (measured on 2
#: cores), which a 2-core machine otherwise takes from the frames.
#: Also the environment the nannies spawn workers with: Dask's default less
#: MALLOC_TRIM_THRESHOLD_=65536, which has glibc hand every freed block above 64 kB back to the
#: system, so that the frame's NumPy temporaries are mapped and faulted in afresh each time:
#: with it a frame of the demo sequence at 128 cells took 0.21-0.23 s to build its procedural
#: medium instead of 0.04, and 0.13-0.16 s in the diffusion stage instead of 0.07-0.09
#: (one thread, the same process with and without the variable).
LOCAL_CONFIG = {
    "distributed.nanny.pre-spawn-environ": {"OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1,
                                            "OPENBLAS_NUM_THREADS": 1},
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.deploy.cluster-repr-interval": "10s",
}
#: how long run_on_cluster waits for a cluster that has no worker yet
WORKERS_TIMEOUT_S = 60.0


def _distributed():
    """The ``distributed`` module, or a one-line PopvolError saying how to install it."""
    try:
        import distributed
    except ImportError as e:
        raise PopvolError(f"Dask distributed is not installed (no module {e.name!r}): "
                          f"{INSTALL_HINT}") from None
    return distributed


def cpu_count() -> int:
    """Cores this process may run on (the affinity mask where the OS has one)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def numba_threads_for(workers: int, cores: int | None = None) -> int:
    """Numba threads for each of ``workers`` single-threaded workers sharing ``cores``."""
    return max(1, (cores or cpu_count()) // max(1, int(workers)))


def _host(address: str) -> str:
    """'tcp://10.0.0.5:4321' -> '10.0.0.5' ('inproc://...' and odd forms: the whole string)."""
    m = re.match(r"^[a-z]+://(\[[^\]]*\]|[^:/]+)(?::\d+)?", address or "")
    return m.group(1) if m else str(address)


def local_client(workers: int):
    """A ``distributed.Client`` on a new LocalCluster of ``workers`` worker processes, one Dask
    thread each and ``cpu_count() // workers`` Numba threads each (``NUMBA_NUM_THREADS`` in
    the environment they are spawned with; every task also sets it, see the module's doc), no
    dashboard, logs at ERROR, quiet Dask settings (:data:`LOCAL_CONFIG`). Closing the client
    closes the cluster. Workers are spawned processes: a script that calls this needs the
    ``if __name__ == "__main__":`` guard."""
    distributed = _distributed()
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise PopvolError(f"workers = {workers!r} must be an integer >= 1")
    threads = numba_threads_for(workers)
    try:
        # Client(**cluster_kwargs) starts a LocalCluster that the client owns and closes.
        import dask
        with dask.config.set(LOCAL_CONFIG), _environ(NUMBA_NUM_THREADS=str(threads)):
            return distributed.Client(
                n_workers=workers, threads_per_worker=1, processes=True,
                dashboard_address=None, silence_logs=logging.ERROR,
                # the scheduler's HTTP server (health checks) on a free port, not 8787
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}, set_as_default=False)
    except Exception as e:  # noqa: BLE001 - one line for the user, whatever went wrong
        raise PopvolError(f"could not start a local Dask cluster of {workers} workers: "
                          f"{_one_line(e)}") from None


@contextlib.contextmanager
def _environ(**values: str):
    """Set environment variables in this process while workers are spawned, then restore them.

    Workers are spawned: a child re-imports the parent's ``__main__`` (the ``popvol`` script
    imports popvol, hence Numba) before the Nanny's ``env`` would be applied, so the figure
    must already be in the environment the child inherits. (Not the Nanny's ``env`` as well: a
    worker restarted later would read Numba's default at import and then find a different
    NUMBA_NUM_THREADS in its environment, which Numba refuses at its next compile once its
    threads run; restarted workers keep Numba's default pool, and each task limits itself.)
    It is restored at once for the same reason in this process."""
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def connect(address: str, timeout: float = CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` connected to the scheduler at ``address``
    (``tcp://HOST:PORT`` or ``tls://HOST:PORT``); a one-line PopvolError if the address is not
    one, or if no scheduler answers within ``timeout`` s (also where something listens but
    never answers: the attempt runs in a thread that is given up on)."""
    distributed = _distributed()
    if not isinstance(address, str) or not address.strip():
        raise PopvolError(f"scheduler address {address!r} is empty: give e.g. tcp://HOST:8786")
    address = address.strip()
    m = re.fullmatch(r"(tcp|tls)://(\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):(\d{1,5})", address)
    if m is None or not 0 < int(m.group(3)) < 65536:
        raise PopvolError(f"scheduler address {address!r}: give tcp://HOST:PORT (or tls://HOST:PORT), "
                          "e.g. tcp://127.0.0.1:8786")
    result = {}

    def attempt():
        try:
            result["client"] = distributed.Client(address, timeout=timeout, set_as_default=False)
        except Exception as e:  # noqa: BLE001
            result["error"] = e

    thread = threading.Thread(target=attempt, name="popvol-connect", daemon=True)
    thread.start()
    thread.join(timeout + 5.0)
    if "client" in result:
        return result["client"]
    reason = _one_line(result["error"]) if "error" in result else "no answer (is a Dask scheduler listening there?)"
    raise PopvolError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s: {reason}")


def _one_line(e: BaseException) -> str:
    text = " ".join(str(e).split()) or type(e).__name__
    return text if len(text) <= 200 else text[:197] + "..."


def split_runs(frames: list[int], runs: int) -> list[list[int]]:
    """``frames`` cut, in their order, into ``runs`` contiguous runs whose lengths differ by at
    most one (fewer runs if there are fewer frames)."""
    frames = list(frames)
    runs = max(1, min(int(runs), len(frames)))
    q, r = divmod(len(frames), runs)
    out, start = [], 0
    for i in range(runs):
        n = q + (1 if i < r else 0)
        out.append(frames[start:start + n])
        start += n
    return [run for run in out if run]


def _render_task(scene_path, frames, output, options, host_threads, run_index, topic, render=None):
    """Runs in a worker: set this thread's Numba threads, render the run (each frame reported on
    the event ``topic``), tag its frames with where and how they were made."""
    from distributed import get_worker

    import numba

    worker = get_worker()
    sharing = host_threads.get(_host(worker.address)) or worker.state.nthreads or 1
    numba.set_num_threads(max(1, min(numba_threads_for(sharing), numba.config.NUMBA_NUM_THREADS)))
    if render is None:
        from .sequence import render_run as render
    kwargs = {}
    if "progress" in inspect.signature(render).parameters:
        kwargs["progress"] = lambda r: worker.log_event(topic, {"frame": r.get("frame")})
    t0 = time.perf_counter()
    try:
        results = render(scene_path, list(frames), output, dict(options), **kwargs)
    except PopvolError as e:
        # bad input fails the same way on every worker: returned, not raised, so not retried
        return {"error": str(e)}
    seconds = time.perf_counter() - t0
    tag = {"worker": worker.address, "pid": os.getpid(), "host": _host(worker.address),
           "numba_threads": numba.get_num_threads(), "run": run_index, "run_seconds": seconds}
    return {"results": [{**r, **tag} for r in results]}


def run_on_cluster(client, scene_path: str | None, frames: list[int], output: str,
                   options: dict, runs: int | None = None, *,
                   progress: bool | Callable[[int, int], None] | None = None,
                   retries: int = 2, render: Callable | None = None) -> list[dict]:
    """Render ``frames`` of the scene file ``scene_path`` (None: the built-in demo) on the
    cluster behind ``client``, in ``runs`` contiguous runs (default: one per Dask worker
    thread), each one task of :func:`popvol.sequence.render_run` with ``retries`` retries on an
    unexpected error (a task whose worker died is rescheduled by Dask itself, up to
    ``distributed.scheduler.allowed-failures`` times). ``output`` and ``options`` as for
    ``render_run``; paths are made absolute here, and the workers must see the same files
    (one machine, or a shared file system).

    Returns ``render_run``'s dicts sorted by frame, each with ``worker`` (address), ``pid``,
    ``host``, ``numba_threads`` (what the run used), ``run`` (its index) and ``run_seconds``
    (the run's wall time inside its worker) added. A frame finished by a worker that then died
    is ``skipped`` in the retried run's dicts.

    ``progress``: None shows a rich progress bar over frames when stderr is a terminal, False
    nothing, a callable is called as ``progress(frames_done, frames_total)``. ``render``
    replaces ``render_run`` (same signature; tests)."""
    distributed = _distributed()
    frames = [int(f) for f in frames]
    if len(set(frames)) != len(frames):
        raise PopvolError("frames: a frame is listed twice")
    if not frames:
        return []
    nthreads = client.nthreads()
    if not nthreads:
        try:
            client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
        except Exception:  # noqa: BLE001
            raise PopvolError(f"the Dask cluster at {client.scheduler.address} has no worker "
                              f"after {WORKERS_TIMEOUT_S:g} s") from None
        nthreads = client.nthreads()
    if runs is None:
        runs = sum(nthreads.values())
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise PopvolError(f"runs = {runs!r} must be an integer >= 1")
    host_threads = Counter()
    for address, n in nthreads.items():
        host_threads[_host(address)] += n
    scene = os.path.abspath(scene_path) if scene_path else scene_path
    output = os.path.abspath(output)
    options = dict(options)
    if options.get("exr"):
        options["exr"] = os.path.abspath(options["exr"])
    chunks = split_runs(frames, runs)
    token = uuid.uuid4().hex[:12]
    topic = f"popvol-frames-{token}"
    report = _progress_reporter(progress, len(frames))
    seen: set[int] = set()
    lock = threading.Lock()
    changed = threading.Event()

    def on_frame(event):
        with lock:
            seen.add(event[1].get("frame"))
        changed.set()

    if report is not None:
        client.subscribe_topic(topic, on_frame)
    # One run per worker thread, in order, as a loose hint: Dask may move a run elsewhere
    # (its worker died, or there are more runs than threads).
    slots = [a for a in sorted(nthreads) for _ in range(nthreads[a])]
    futures = [client.submit(_render_task, scene, chunk, output, options, dict(host_threads), i,
                             topic, render, key=f"popvol-run-{chunk[0]}-{chunk[-1]}-{token}",
                             pure=False, retries=retries, workers=[slots[i % len(slots)]],
                             allow_other_workers=True)
               for i, chunk in enumerate(chunks)]
    chunk_of = {f.key: c for f, c in zip(futures, chunks)}
    results: list[dict] = []
    try:
        for fut in futures:
            fut.add_done_callback(lambda _f: changed.set())
        pending = list(futures)
        while pending:
            changed.wait(timeout=None if report is None else 1.0)
            changed.clear()
            for fut in [f for f in pending if f.done()]:
                pending.remove(fut)
                out = _result(fut, chunk_of[fut.key], distributed)
                results.extend(out)
                with lock:
                    seen.update(r["frame"] for r in out)
            if report is not None:
                with lock:
                    report(len(seen & set(frames)))
    finally:
        for fut in futures:
            if not fut.done():
                fut.cancel()
        if report is not None:
            with contextlib.suppress(Exception):
                client.unsubscribe_topic(topic)
            report(None)
    return sorted(results, key=lambda r: r["frame"])


def _result(fut, chunk, distributed) -> list[dict]:
    """A finished run's dicts, or its failure as one PopvolError line."""
    where = f"the run of frames {chunk[0]}-{chunk[-1]}"
    try:
        out = fut.result()
    except distributed.client.FutureCancelledError:
        raise PopvolError(f"{where} was cancelled") from None
    except Exception as e:  # noqa: BLE001 (KilledWorker, an unexpected error in a worker)
        raise PopvolError(f"{where} failed: {type(e).__name__}: {_one_line(e)}") from None
    if "error" in out:
        raise PopvolError(out["error"])
    return out["results"]


def _progress_reporter(progress, total: int):
    """A function ``report(done)`` (``report(None)`` ends it), or None for no progress."""
    if progress is False:
        return None
    if callable(progress):
        last = [-1]

        def report(done):
            if done is not None and done != last[0]:
                last[0] = done
                progress(done, total)
        return report
    if not sys.stderr.isatty():
        return None
    from rich.console import Console
    from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                               TimeElapsedColumn, TimeRemainingColumn)
    bar = Progress(TextColumn("frames"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                   TimeRemainingColumn(), console=Console(stderr=True), transient=True)
    task = bar.add_task("frames", total=total)
    bar.start()

    def report(done):
        if done is None:
            bar.stop()
        else:
            bar.update(task, completed=done)
    return report
