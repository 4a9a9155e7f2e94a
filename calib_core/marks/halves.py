"""A frame's per-Mark compiled work in two halves: one on a helper thread, one on the
caller's, where there is a second core and enough work to pay for the hand-over (about
50 us). The compiled functions release the GIL, so the halves run at once."""
from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import numpy as np


def run_in_halves(work: Callable[[np.ndarray], None], load: np.ndarray, above: float) -> None:
    """Calls ``work(indices)`` so that every item's index is passed once: the items' first
    half by ``load`` (per item, any unit) on this thread and the rest on the helper, when
    their total load is above ``above``; else all of them here."""
    total = np.cumsum(load)
    helper = _helper(os.getpid())
    if len(total) < 2 or total[-1] <= above or helper is None:
        work(np.arange(len(total)))
        return
    half = int(np.searchsorted(total, total[-1] / 2)) + 1
    if half == len(total):  # one item outweighs the others
        work(np.arange(len(total)))
        return
    other = helper.submit(work, np.arange(half, len(total)))
    work(np.arange(half))
    other.result()


@functools.cache
def _helper(process: int) -> ThreadPoolExecutor | None:
    """The one helper thread, made on first use in each ``process`` (a child forked after
    it was made has the executor but not its thread); None on a single core."""
    return ThreadPoolExecutor(1, 'marks') if len(os.sched_getaffinity(0)) > 1 else None
