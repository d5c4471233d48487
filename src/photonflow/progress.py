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
    unit: str | None = None,
) -> Iterator[Item]:
    """Yield ``items`` while a transient rich progress bar labelled ``label`` counts them
    on standard error (``total`` items, default ``len(items)`` where it exists; the bar
    starts at ``completed``, e.g. for a resumed run). ``unit`` (e.g. "events") adds the
    rate, items of this run per second. With ``show=False`` the items pass through
    untouched and rich is not imported."""
    if not show:
        yield from items
        return
    from rich.console import Console
    from rich.progress import Progress

    if total is None and hasattr(items, "__len__"):
        total = len(items)
    columns = (*Progress.get_default_columns(), _rate_column(unit)) if unit else ()
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(label, total=total, completed=completed)
        for item in items:
            yield item
            bar.advance(task)


def _rate_column(unit: str):
    """A rich column of this run's rate: "3.2 events/s", or "41 s/event" below one per
    second (rich's own speed column counts bytes)."""
    from rich.progress import ProgressColumn
    from rich.text import Text

    single = unit[:-1] if unit.endswith("s") else unit

    class Rate(ProgressColumn):
        def render(self, task) -> Text:
            speed = task.speed
            if not speed:
                shown = f"? {unit}/s"
            elif speed >= 1.0:
                shown = f"{speed:.3g} {unit}/s"
            else:
                shown = f"{1.0 / speed:.3g} s/{single}"
            return Text(shown, style="progress.data.speed")

    return Rate()
