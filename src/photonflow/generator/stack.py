"""``Stack``: the live particles of one kind during transport (``transport.py``), as a
struct of arrays (positions and path lengths cm, times ns, kinetic energies MeV)."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class Stack:
    """Live particles of one kind (struct of arrays; cm, ns, MeV)."""

    species: np.ndarray
    position: np.ndarray
    direction: np.ndarray
    energy: np.ndarray
    time: np.ndarray
    track: np.ndarray
    path: np.ndarray

    @property
    def size(self) -> int:
        return self.energy.size

    def select(self, mask: np.ndarray) -> Stack:
        return Stack(*(getattr(self, f.name)[mask] for f in dataclasses.fields(self)))

    @staticmethod
    def join(stacks: list[Stack]) -> Stack:
        return Stack(
            *(
                np.concatenate([getattr(s, f.name) for s in stacks])
                for f in dataclasses.fields(Stack)
            )
        )

    @staticmethod
    def empty() -> Stack:
        return Stack(
            np.empty(0, np.int64),
            np.empty((0, 3)),
            np.empty((0, 3)),
            np.empty(0),
            np.empty(0),
            np.empty(0, np.int64),
            np.empty(0),
        )

