"""How the workcell's parts refer back to the workcell that owns them: weakly.

The workcell holds its parts (``physics``, ``collateral``, ``motion``) and each part calls back into the
workcell.  Held strongly, those back references would make every workcell a reference cycle, freed only by the
cyclic garbage collector's next pass -- which counts Python allocations, not the hundreds of MB a compiled
mesh scene holds in MuJoCo, so a loop of ``make``/``close`` grew without bound.  Held weakly, a workcell and
its parts are freed the moment the last outside reference goes.
"""

from __future__ import annotations

import weakref
from typing import Any, Generic, TypeVar

Owner = TypeVar("Owner")


class OwnerReference(Generic[Owner]):
    """A descriptor for a part's attribute naming its owner: set with the owner, read back as the owner, held
    by a weak reference.  Reading it after the owner is gone raises ``ReferenceError``."""

    def __set_name__(self, part_class: type, name: str) -> None:
        self._slot = f"_{name}_weakref"

    def __get__(self, part: Any, part_class: type | None = None) -> Owner:
        if part is None:
            return self  # type: ignore[return-value]  # read on the class: the descriptor itself
        owner = getattr(part, self._slot)()
        if owner is None:
            raise ReferenceError(f"the owner of this {type(part).__name__} was freed")
        return owner

    def __set__(self, part: Any, owner: Owner) -> None:
        setattr(part, self._slot, weakref.ref(owner))
