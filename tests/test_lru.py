"""The one hand-written LRU (controllers/lru.py) behind the caches functools cannot be: eviction
order, a budget in sizes, the value in use always kept, pickles and copies empty (issue 32)."""

from __future__ import annotations

import copy
import pickle
from types import SimpleNamespace

import pytest

from controllers.lru import BudgetedLRU
from controllers.qp import EnumerationBudget


def test_the_least_recently_used_is_dropped_first():
    dropped: list[str] = []
    cache: BudgetedLRU[str, str] = BudgetedLRU(3, on_drop=dropped.append)
    for key in "abc":
        assert cache.get(key, str.upper, key) == key.upper()
    assert cache.get("a", pytest.fail, "a was kept: no build") == "A"  # a: now the most recent
    cache.get("d", str.upper, "d")
    # least recently used first out: b (a FIFO would drop a, a stack d)
    assert [k for k, _ in cache.items()] == ["c", "a", "d"] and dropped == ["B"]
    cache.get("c", str.upper, "c")
    cache.get("e", str.upper, "e")
    assert [k for k, _ in cache.items()] == ["d", "c", "e"] and dropped == ["B", "A"]
    assert [k for k, _ in reversed(cache.items())] == ["e", "c", "d"]
    assert cache.values() == ["D", "C", "E"] and len(cache) == 3 and "a" not in cache
    assert cache.built == 5  # the two hits built nothing


def test_the_budget_counts_sizes_not_entries():
    cache: BudgetedLRU[int, str] = BudgetedLRU(10, size=len)
    cache.get(1, str, "aaaa")
    cache.get(2, str, "bbbb")
    cache.get(3, str, "cc")
    assert cache.total == 10 and len(cache) == 3  # at the limit: nothing dropped
    cache.get(4, str, "d")
    assert cache.total == 7 and [k for k, _ in cache.items()] == [2, 3, 4]
    cache.limit = 3  # applies from the next value added
    assert cache.total == 7 and len(cache) == 3
    cache.get(5, str, "e")
    assert cache.total == 2 and [k for k, _ in cache.items()] == [4, 5]


def test_the_value_in_use_is_kept_even_above_the_limit():
    cache: BudgetedLRU[str, str] = BudgetedLRU(10, size=len)
    cache.get("small", str, "ab")
    big = cache.get("big", str, "x" * 25)
    assert big == "x" * 25 and cache.values() == [big] and cache.total == 25
    cache.get("next", str, "y")  # the big one goes as soon as another is in use
    assert cache.values() == ["y"] and cache.total == 1
    zero: BudgetedLRU[int, int] = BudgetedLRU(0)
    for i in range(3):
        assert zero.get(i, int, i) == i and zero.values() == [i]


def test_clear_forgets_without_calling_on_drop():
    dropped: list[str] = []
    cache: BudgetedLRU[str, str] = BudgetedLRU(5, size=len, on_drop=dropped.append)
    cache.get("a", str, "aa")
    cache.clear()
    assert len(cache) == 0 and cache.total == 0 and dropped == [] and cache.built == 1


@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_pickles_and_copies_empty(how):
    cache: BudgetedLRU[str, str] = BudgetedLRU(10, size=len)
    for key in "abc":
        cache.get(key, str, key * 3)
    clone = pickle.loads(pickle.dumps(cache)) if how == "pickle" else copy.deepcopy(cache)
    assert len(clone) == 0 and clone.total == 0 and clone.built == 0 and clone.limit == 10
    assert len(cache) == 3 and cache.total == 9 and cache.built == 3  # the original keeps all
    clone.get("x", str, "x" * 4)
    assert clone.total == 4  # the size function came along


def test_the_enumeration_budget_frees_the_least_recently_used_familys_enumeration():
    budget = EnumerationBudget(limit=10)
    families = [SimpleNamespace(enumeration_floats=4, _enum=f"E{i}") for i in range(3)]
    for fam in families[:2]:
        budget.use(fam)
    budget.use(families[0])  # the first is used again: the second is the least recent
    budget.use(families[2])
    assert [f._enum for f in families] == ["E0", None, "E2"] and budget.total == 8
    clone = pickle.loads(pickle.dumps(budget))
    assert len(clone) == 0 and clone.limit == 10
