"""Event files: ``Event``/``Truth`` records and their HDF5 storage.

Modules: ``events`` (the records), ``hdf5`` (the on-disk layout, see
``docs/file-format.md``), ``writer`` (crash-safe streaming writes, with
``event_chunks`` adding events in chunks and ``partial_files`` the temporary and
checkpoint files a resumed run continues), ``reader`` (lazy reads) and ``summary``
(statistics for ``photonflow info``).
"""

from typing import TYPE_CHECKING

from ..lazy_names import lazy_names
from .events import Event, Truth, make_event

#: Names imported when first used, by module: they need h5py, which events in memory
#: (``Event``, ``Truth``) do not.
_LAZY = {"FORMAT": "hdf5", "FORMAT_VERSION": "hdf5", "EventFile": "reader",
         "read_events": "reader", "format_summary": "summary",
         "summarize_events": "summary", "EventWriter": "writer", "write_events": "writer"}

if TYPE_CHECKING:  # what static tools (type checkers, the API reference) see of them
    from .hdf5 import FORMAT, FORMAT_VERSION
    from .reader import EventFile, read_events
    from .summary import format_summary, summarize_events
    from .writer import EventWriter, write_events

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "Event",
    "EventFile",
    "EventWriter",
    "Truth",
    "format_summary",
    "make_event",
    "read_events",
    "summarize_events",
    "write_events",
]


__getattr__, __dir__ = lazy_names(__name__, _LAZY)
