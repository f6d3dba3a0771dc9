"""contracts/compiled.py: a numba function called through the compiled code its first call
chose, and through the dispatcher whenever an argument is not of the kind it was."""

from __future__ import annotations

import pickle
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit

from contracts.compiled import MIN_CALLS_BETWEEN_TYPINGS, Resolved


class Gains(NamedTuple):
    k: float
    scale: np.ndarray


@njit(cache=False)
def _weighted(x, gains, offset, flag):
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = gains.k * x[i] * gains.scale[i % gains.scale.size] + offset
    return out if flag else -out


class _Counting:
    """A dispatcher stand-in that counts the calls going through it."""

    def __init__(self, function) -> None:
        self.function, self.calls = function, 0

    def __call__(self, *args):
        self.calls += 1
        return self.function(*args)

    def __getattr__(self, name):
        return getattr(self.function, name)


def test_later_calls_skip_the_dispatcher_and_give_its_results():
    counting = _Counting(_weighted)
    f = Resolved(counting)
    gains = Gains(2.0, np.array([1.0, 0.5]))
    for k in range(5):
        x = np.arange(4.0) + k
        assert np.array_equal(f(x, gains, 0.25, True), _weighted(x, gains, 0.25, True))
    assert counting.calls == 1


@pytest.mark.parametrize("changed", [
    "int array", "strided array", "read-only array", "int offset", "new tuple", "flag"])
def test_an_argument_of_another_kind_goes_through_the_dispatcher(changed):
    counting = _Counting(_weighted)
    f = Resolved(counting)
    x, gains, offset, flag = np.arange(6.0), Gains(2.0, np.array([1.0, 0.5])), 0.25, True
    for _ in range(MIN_CALLS_BETWEEN_TYPINGS + 1):
        f(x, gains, offset, flag)
    assert counting.calls == 1
    if changed == "int array":
        x = np.arange(6)
    elif changed == "strided array":
        x = np.arange(12.0)[::2]
    elif changed == "read-only array":
        x = x.copy()
        x.flags.writeable = False
    elif changed == "int offset":
        offset = 1
    elif changed == "new tuple":
        gains = Gains(3, np.array([2, 1]))  # other element types: the tuple is typed anew
    else:
        flag = np.int64(0)
    assert np.array_equal(f(x, gains, offset, flag), _weighted(x, gains, offset, flag))
    assert counting.calls == 2
    f(x, gains, offset, flag)  # its kinds are now the ones looked for
    assert counting.calls == 2


def test_kinds_that_keep_changing_go_through_the_dispatcher_for_good():
    counting = _Counting(_weighted)
    f = Resolved(counting)
    gains = Gains(2.0, np.array([1.0, 0.5]))
    for k in range(10):
        x = np.arange(4.0) if k % 2 else np.arange(4)
        assert np.array_equal(f(x, gains, 0.25, True), _weighted(x, gains, 0.25, True))
    assert counting.calls == 10


def test_another_number_of_arguments_goes_through_the_dispatcher():
    @njit(cache=False)
    def add(a, b=1.0):
        return a + b

    counting = _Counting(add)
    f = Resolved(counting)
    assert f(1.0, 2.0) == 3.0
    assert f(1.0) == 2.0 and counting.calls == 2


def test_it_pickles_as_the_function_it_calls():
    from sitl.dynamics import rk4_integrate

    f = pickle.loads(pickle.dumps(Resolved(rk4_integrate)))
    assert f.function is rk4_integrate
