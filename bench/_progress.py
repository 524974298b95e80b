"""Progress lines for long benchmarks: a bench that runs for minutes says how far it is."""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")


def with_progress(items: Iterable[T], total: int, what: str, steps: int = 10) -> Iterator[T]:
    """Yield `items`, printing `  what: done/total (share), elapsed s` about `steps` times."""
    started = time.perf_counter()
    every = max(1, total // steps)
    for done, item in enumerate(items, start=1):
        yield item
        if done % every == 0 or done == total:
            print(f"  {what}: {done}/{total} ({done / max(total, 1):.0%}), {time.perf_counter() - started:.0f} s",
                  flush=True)
