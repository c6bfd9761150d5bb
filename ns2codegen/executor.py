"""One way to run many independent jobs (planning trials, replays, trainings,
simulated flights): an ordered map on one of three backends, with the same results
on each (every job is seeded by its arguments):

* in this process (one worker and no scheduler);
* ``local``: forked worker processes on this machine (the default with workers > 1):
  they inherit the parent's memory (data sets, built C libraries), nothing but the
  arguments and results is pickled;
* ``dask``: the workers of a Dask distributed cluster (``distributed`` of the
  ``cluster`` extra), the scheduler's address from ``--scheduler`` or NS2_SCHEDULER;
  ``local-cluster`` starts a ``LocalCluster`` of ``workers`` processes here (a trial
  of the cluster path on one machine).

Every worker process runs one torch thread and, with ``setup=(fn, args)``, calls
``fn(*args)`` once before its first job (loading its own model or data: the job's
function reads what it left in its module); a second setup of the same function with
other arguments replaces the first.  The functions and their arguments must be
importable and picklable on the workers (a module of an installed package)."""
from __future__ import annotations

import os
import pickle
import sys
import threading
from concurrent.futures import Future

SCHEDULER_ENV = "NS2_SCHEDULER"
LOCAL_CLUSTER = "local-cluster"     # --scheduler local-cluster: a LocalCluster on this machine

_SETUP_DONE: dict = {}              # this process's setups: (module, name) -> repr of the arguments last run
_SETUP_LOCK = threading.Lock()
_THREADS_SET = False


def scheduler_address(option: str | None = None) -> str | None:
    """The scheduler to use: ``option`` (a --scheduler), else NS2_SCHEDULER, else None
    (this machine's processes); "local" and "" also mean this machine's processes."""
    s = option if option is not None else os.environ.get(SCHEDULER_ENV)
    return None if s in (None, "", "local") else s


def use_scheduler(option: str) -> None:
    """A command's --scheduler: every executor of this process (and of its children) uses it."""
    os.environ[SCHEDULER_ENV] = option


def _setup_key(fn) -> tuple:
    return getattr(fn, "__module__", ""), getattr(fn, "__qualname__", repr(fn))


def ensure_setup(setup) -> None:
    """Run ``setup`` = (fn, args) in this process unless its last run had these arguments."""
    if setup is None:
        return
    fn, args = setup
    key, val = _setup_key(fn), repr(args)
    with _SETUP_LOCK:
        if _SETUP_DONE.get(key) != val:
            fn(*args)
            _SETUP_DONE[key] = val


def _worker_start(setup) -> None:
    """A worker process before its first job: one torch thread (two workers on two cores;
    and a forked child must not enter the parent's OpenMP pool, which hangs), its setup."""
    global _THREADS_SET
    if not _THREADS_SET:
        if "torch" in sys.modules:
            sys.modules["torch"].set_num_threads(1)
        else:                               # read when torch (its OpenMP) is first loaded
            os.environ["OMP_NUM_THREADS"] = "1"
        _THREADS_SET = True
    ensure_setup(setup)


def _task(setup, fn, args):
    """One job on a worker: the worker's start (once), then fn(*args); an error that cannot
    be pickled back (a cffi error) comes back as a RuntimeError with its type and message."""
    _worker_start(setup)
    try:
        return fn(*args)
    except Exception as e:
        try:
            pickle.loads(pickle.dumps(e))
        except Exception:
            msg = f"{type(e).__module__}.{type(e).__qualname__}: {e}"
        else:
            raise
    raise RuntimeError(msg)                 # outside the handler: nothing unpicklable attached


class _Deferred(Future):
    """A job of the in-process backend: run when its result is first asked for (in the
    order the caller consumes them, as a plain loop would)."""

    def __init__(self, setup, fn, args):
        super().__init__()
        self._job = (setup, fn, args)

    def result(self, timeout=None):
        if self._job is not None:
            setup, fn, args = self._job
            self._job = None
            try:
                ensure_setup(setup)
                self.set_result(fn(*args))
            except Exception as e:         # kept for result() to raise, as a pool's future does
                self.set_exception(e)
        return super().result(timeout)


class Executor:
    """Jobs on ``workers`` processes here (forked) or on a Dask cluster (``scheduler``:
    an address, LOCAL_CLUSTER, or None for NS2_SCHEDULER / this machine).  ``setup``:
    (fn, args) run once in every worker before its jobs; with ``setup_here`` it is run
    in this process before the forked workers start, and they inherit what it loaded.
    Use as a context manager (the pool or the client is closed at the end)."""

    def __init__(self, workers: int = 1, scheduler: str | None = None, setup=None, setup_here: bool = False):
        self.workers = max(1, int(workers))
        self.scheduler = scheduler_address(scheduler)
        self.setup, self.setup_here = setup, setup_here
        self._pool = self._client = self._cluster = None
        self._pending = 0                   # when_done callbacks not run yet (close waits for them)
        self._callback_error = None
        self._deferred: list = []           # the inline backend's jobs
        self._watched: list = []            # the jobs of when_done
        self._callbacks = threading.Condition()

    @property
    def backend(self) -> str:
        """"dask", "local" (forked processes) or "inline" (this process)."""
        return "dask" if self.scheduler is not None else "local" if self.workers > 1 else "inline"

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(wait=exc_type is None)

    def close(self, wait: bool = True) -> None:
        """Wait for every job and its when_done callback (``wait``; else drop the jobs not
        started: an error or an interrupt), then close the pool or the client."""
        for f in self._deferred:
            f.cancel()                      # never asked for: never run
        if not wait:                        # the jobs not finished are dropped (their callbacks see it)
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=True)
            if self._client is not None:
                self._client.cancel([f for f in self._watched if not f.done()])
        with self._callbacks:               # every finished job's callback has run
            self._callbacks.wait_for(lambda: self._pending == 0)
        self._deferred, self._watched = [], []
        if self._pool is not None:
            self._pool.shutdown()
        if self._client is not None:
            self._client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._pool = self._client = self._cluster = None
        err, self._callback_error = self._callback_error, None
        if err is not None and wait:
            raise err

    def _dask(self):
        if self._client is None:
            try:
                from distributed import Client, LocalCluster
            except ImportError as e:
                raise RuntimeError(f"--scheduler {self.scheduler}: the Dask backend needs `distributed` "
                                   "(pip install 'ns2codegen[cluster]')") from e
            if self.scheduler == LOCAL_CLUSTER:
                self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                             dashboard_address=":0")
                self._client = Client(self._cluster)
            else:
                self._client = Client(self.scheduler)
        return self._client

    def _local(self):
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor

            if self.setup_here:
                ensure_setup(self.setup)
            self._pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("fork"),
                                             initializer=_worker_start, initargs=(self.setup,))
        return self._pool

    def submit(self, fn, *args, inline: bool = False) -> Future:
        """fn(*args) as a future (``result()``, ``add_done_callback``); ``inline`` or the
        inline backend: run in this process when its result is asked for."""
        backend = "inline" if inline else self.backend
        if backend == "dask":
            return self._dask().submit(_task, self.setup, fn, args, pure=False)
        if backend == "local":
            return self._local().submit(_task, self.setup, fn, args)
        self._deferred.append(_Deferred(self.setup, fn, args))
        return self._deferred[-1]

    def when_done(self, future: Future, fn) -> None:
        """fn(result) as soon as ``future`` finishes without an error (in a pool's or the
        client's thread; keep a finished job at once, in any order); close() waits for it."""
        with self._callbacks:
            self._pending += 1
        self._watched.append(future)

        def done(f) -> None:
            try:
                if not f.cancelled() and f.exception() is None:
                    fn(f.result())
            except Exception as e:          # raised again by close(): a result that could not be kept
                self._callback_error = self._callback_error or e
            finally:
                with self._callbacks:
                    self._pending -= 1
                    self._callbacks.notify_all()

        future.add_done_callback(done)

    def map(self, fn, args: list, progress=None, on_done=None) -> list:
        """[fn(*a) for a in args] in this order; ``on_done(i, result)`` as each job
        finishes (when_done: in any order, in a pool's thread; all of them have run when
        the executor is closed), ``progress(1)`` as each result is taken in order.  One
        job alone on the local backend runs in this process."""
        inline = self.backend == "local" and len(args) <= 1
        futures = [self.submit(fn, *a, inline=inline) for a in args]
        if on_done is not None:
            for i, f in enumerate(futures):
                self.when_done(f, lambda r, i=i: on_done(i, r))
        out = []
        for f in futures:
            out.append(f.result())
            if progress is not None:
                progress(1)
        return out


def run_map(fn, args: list, workers: int = 1, progress=None, scheduler: str | None = None, setup=None,
            setup_here: bool = True, on_done=None) -> list:
    """Executor(workers, scheduler, setup, setup_here).map(fn, args, progress, on_done)."""
    with Executor(workers, scheduler, setup, setup_here) as ex:
        return ex.map(fn, args, progress, on_done)
