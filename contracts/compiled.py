"""A numba-compiled function called in a loop without numba typing every argument each call.

Why: on every call numba's dispatcher types each argument to pick the compiled code. An
array or a number takes ~0.1 us, but a namedtuple is typed in Python, ~1.2 us, and a
tuple of them more: the plant's integrator takes the airframe (1.7 us of dispatch a
call), the controller's step its airframe and gains (7 us of its 13). A loop passes the
same kinds of arguments every time, so ``Resolved`` types them on its first call and
later calls the compiled code chosen then directly, as long as each argument is still
what it was: the very same tuple (a tuple cannot change, and typing tuples is what
costs), anything else of the same numba fingerprint (its type, as numba's dispatcher
itself caches it: ~0.05 us). Any other call goes through the dispatcher, and its types
become the ones looked for; if that happens often (kinds that keep changing), or the
compiled code cannot be found, every call goes through the dispatcher from then on.
"""

from __future__ import annotations

import operator
from collections.abc import Callable, Sequence
from typing import Any

try:  # numba's own fingerprint of an argument's type (its dispatcher caches types by it)
    from numba._dispatcher import compute_fingerprint
except ImportError:  # a numba without it: every call goes through the dispatcher
    compute_fingerprint = None

# Typing the arguments again sooner than this many calls after the last time: the kinds
# keep changing, and the dispatcher is the cheaper way.
MIN_CALLS_BETWEEN_TYPINGS = 100


def _items(indices: Sequence[int]) -> Callable[[tuple], tuple]:
    """A getter of ``args``' items at ``indices``, always as a tuple."""
    if len(indices) > 1:
        return operator.itemgetter(*indices)
    if indices:
        index = indices[0]
        return lambda args: (args[index],)
    return lambda args: ()


class Resolved:
    """``function`` (a numba dispatcher) called positionally, through the compiled code
    its last dispatched call chose while the arguments keep their kinds."""

    def __init__(self, function: Any) -> None:
        self.function = function
        self._entry: Callable[..., Any] | None = None
        self._dispatch_only = compute_fingerprint is None
        self._calls = MIN_CALLS_BETWEEN_TYPINGS  # since the arguments were last typed
        self._count = -1
        self._tuples: Callable[[tuple], tuple] = _items(())
        self._same: tuple = ()
        self._others: Callable[[tuple], tuple] = _items(())
        self._fingerprints: list = []

    def __reduce__(self) -> tuple:
        return Resolved, (self.function,)  # resolved anew where it goes

    def __call__(self, *args: Any) -> Any:
        if self._entry is not None and len(args) == self._count and \
                all(map(operator.is_, self._tuples(args), self._same)) and \
                list(map(compute_fingerprint, self._others(args))) == self._fingerprints:
            self._calls += 1
            return self._entry(*args)
        if self._dispatch_only:
            return self.function(*args)
        return self._dispatch(args)

    def _dispatch(self, args: tuple) -> Any:
        """The call through the dispatcher; then the compiled code it chose, for the
        calls after it."""
        result = self.function(*args)
        self._entry = None
        if self._calls < MIN_CALLS_BETWEEN_TYPINGS:
            self._dispatch_only = True
            return result
        self._calls = 0
        compiled = self.function.overloads.get(
            tuple(self.function.typeof_pyval(a) for a in args))
        tuples = [i for i, a in enumerate(args) if isinstance(a, tuple)]
        others = [i for i, a in enumerate(args) if not isinstance(a, tuple)]
        try:
            fingerprints = [compute_fingerprint(args[i]) for i in others]
        except (NotImplementedError, TypeError, ValueError):  # a kind it does not know
            compiled = None
        if compiled is None or not callable(getattr(compiled, "entry_point", None)):
            self._dispatch_only = True
            return result
        self._count = len(args)
        self._tuples, self._same = _items(tuples), tuple(args[i] for i in tuples)
        self._others, self._fingerprints = _items(others), fingerprints
        self._entry = compiled.entry_point
        return result
