"""One least-recently-used cache within a budget, for the caches ``functools`` cannot be.

``functools.lru_cache`` keeps a number of entries, keyed by the arguments of one function. The
caches of the QP engine and of the benchmarks that use :class:`BudgetedLRU` need what it cannot
give: a budget in floats held rather than in entries (entries of very different sizes), a call
when an entry is dropped (the enumeration budget frees a family's enumeration), the entries in
order of use (:meth:`controllers.qp.QPFamily.seen`), a key that is not the arguments, and
per-object caches that pickle empty (a controller is pickled without its solver state).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Reversible
from typing import Any, Generic, TypeVar

__all__ = ["BudgetedLRU"]

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class BudgetedLRU(Generic[K, V]):
    """Values by key, kept while their total size is within ``limit``; least recently used first
    out, and the most recently used always kept (even alone above the limit).

    Parameters
    ----------
    limit : int
        Largest total size of the values kept.
    size : callable, optional
        ``size(value) -> int`` (default: 1 each, a cache of at most ``limit`` entries). It and
        ``on_drop`` must pickle (module-level functions) for the cache to pickle.
    on_drop : callable, optional
        Called with each value the budget drops (not by :meth:`clear`).

    Attributes
    ----------
    limit : int
        May be changed; it applies from the next value added.
    total : int
        Total size of the values kept.
    built : int
        Values built by :meth:`get` so far (a value dropped and needed again counts twice).

    Notes
    -----
    Not thread-safe: its owners hold a lock around it. Pickles (and deep-copies) empty: the
    limit, the functions and the attributes of a subclass are kept, the entries and ``built``
    are not.

    Examples
    --------
    >>> cache = BudgetedLRU(5, size=len)
    >>> cache.get("a", str, "aaa"), cache.get("b", str, "bb"), cache.get("a", str, "?")
    ('aaa', 'bb', 'aaa')
    >>> cache.get("c", str, "c"), list(cache.items())
    ('c', [('a', 'aaa'), ('c', 'c')])
    """

    def __init__(
        self,
        limit: int,
        size: Callable[[V], int] | None = None,
        on_drop: Callable[[V], Any] | None = None,
    ) -> None:
        self.limit = limit
        self.size = size
        self.on_drop = on_drop
        self.built = 0
        self.clear()

    def clear(self) -> None:
        """Forget every entry (``on_drop`` is not called)."""
        self._held: OrderedDict[K, V] = OrderedDict()
        self._sizes: dict[K, int] = {}
        self.total = 0

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for key in ("_held", "_sizes", "total", "built"):
            del state[key]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.built = 0
        self.clear()

    def get(self, key: K, build: Callable[..., V], *args: Any) -> V:
        """The value of ``key``, now the most recently used; on a miss ``build(*args)``, kept,
        then the least recently used others dropped while the total is above the limit."""
        held = self._held
        try:
            value = held[key]
        except KeyError:
            pass
        else:
            held.move_to_end(key)
            return value
        value = build(*args)
        self.built += 1
        size = 1 if self.size is None else self.size(value)
        held[key] = value
        self._sizes[key] = size
        self.total += size
        while self.total > self.limit and len(held) > 1:
            old_key, old = held.popitem(last=False)
            self.total -= self._sizes.pop(old_key)
            if self.on_drop is not None:
                self.on_drop(old)
        return value

    def __contains__(self, key: object) -> bool:
        return key in self._held

    def __len__(self) -> int:
        return len(self._held)

    def items(self) -> Reversible[tuple[K, V]]:
        """``(key, value)`` pairs, least recently used first (a reversible view)."""
        return self._held.items()

    def values(self) -> list[V]:
        """The values, least recently used first."""
        return list(self._held.values())
