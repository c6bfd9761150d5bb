"""An ordered map over forked worker processes: the workers inherit the parent's
memory (data sets, built C libraries), nothing but the arguments and results is pickled."""
from __future__ import annotations


def forked_map(fn, args: list, workers: int = 1, progress=None) -> list:
    """[fn(*a) for a in args], ``workers`` at once in forked processes when there is more
    than one job (the same results in the same order); ``progress(1)`` after each."""
    if workers > 1 and len(args) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork")) as ex:
            futures = [ex.submit(fn, *a) for a in args]
            return [_done(f.result(), progress) for f in futures]
    return [_done(fn(*a), progress) for a in args]


def _done(result, progress):
    if progress is not None:
        progress(1)
    return result
