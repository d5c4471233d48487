"""One progress bar for every long loop: a transient rich bar on standard error."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

Item = TypeVar("Item")


def with_progress(
    items: Iterable[Item],
    label: str,
    *,
    total: int | None = None,
    completed: int = 0,
    show: bool = True,
) -> Iterator[Item]:
    """Yield ``items`` while a transient rich progress bar labelled ``label`` counts them
    on standard error (``total`` items, default ``len(items)`` where it exists; the bar
    starts at ``completed``, e.g. for a resumed run). With ``show=False`` the items pass
    through untouched and rich is not imported."""
    if not show:
        yield from items
        return
    from rich.console import Console
    from rich.progress import Progress

    if total is None and hasattr(items, "__len__"):
        total = len(items)
    with Progress(console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(label, total=total, completed=completed)
        for item in items:
            yield item
            bar.advance(task)
