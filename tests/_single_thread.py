"""Run a function in a fresh process whose BLAS uses one thread (tests with many small identifications).

The identification's tall SVDs are many times slower with a multithreaded BLAS on a busy machine (every core
already has work: the threads wait for each other); the thread count is fixed when numpy loads, so a test that
runs dozens of identifications runs them in a spawned child started with ``OPENBLAS_NUM_THREADS=1``.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from typing import Any

_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def run_single_threaded(func: Callable[..., Any], *args: Any) -> Any:
    """``func(*args)`` in a spawned process with one BLAS thread (``func`` must be importable: module level)."""
    saved = {k: os.environ.get(k) for k in _VARIABLES}
    os.environ.update(dict.fromkeys(_VARIABLES, "1"))
    try:
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
            future = pool.submit(func, *args)
            for k, v in saved.items():  # the child has started with them; the parent keeps its own
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
            return future.result(timeout=600)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
