"""The two test tiers and the guard that keeps them honest.

The logic tier (``pytest -m "not process"``) runs in one process: real sockets and Zenoh
sessions are fine, child processes are not. The process tier (``pytest -m process``) holds
every test that starts a process: the simulator, the autopilot, the logger, ``ivfm`` as a
command, MAVProxy, or the processes a MAVSDK test flies.

While a test without the ``process`` marker runs (its setup, call and teardown, so module
fixtures it is the first to use count too), starting a process raises
:class:`ProcessOutsideTierError`. The guard is installed once per session; per test it
costs one marker look-up.
"""

from __future__ import annotations

import functools
import os
import subprocess

import pytest

MARKER = "process"


class ProcessOutsideTierError(RuntimeError):
    """A test outside the process tier started a process."""


class _State:
    allowed = True  # outside tests (collection, reporting) processes may start
    test = ""


_STATE = _State()
_ORIGINALS: list[tuple[object, str, object]] = []


def _refuse(how: str) -> None:
    raise ProcessOutsideTierError(
        f"{_STATE.test} starts a process ({how}) but is not in the process tier: mark this "
        f"test `process` (@pytest.mark.process, or `pytestmark = pytest.mark.process` after "
        f"the imports of a module whose tests all start processes); see tests/tiers.py")


def _guarded_popen_init(original):
    @functools.wraps(original)
    def init(self, args, *rest, **kwargs):
        if not _STATE.allowed:
            _refuse(f"subprocess.Popen({args!r})")
        return original(self, args, *rest, **kwargs)
    return init


def _guarded(name: str, original):
    @functools.wraps(original)
    def guarded(*args, **kwargs):
        if not _STATE.allowed:
            _refuse(f"os.{name}")
        return original(*args, **kwargs)
    return guarded


def install() -> None:
    """Wrap every way of starting a process: subprocess (and what is built on it:
    subprocess.run, asyncio's subprocesses), os.fork (multiprocessing), os.forkpty (pexpect),
    os.posix_spawn, os.system."""
    if _ORIGINALS:
        return
    # Libraries that start a process once, when first imported (numpy.testing runs lscpu
    # to probe the CPU; scipy imports it; matplotlib's font manager runs fc-list to build
    # its font cache on a fresh machine): imported here, before the guard, so that the
    # first test to import them lazily is not refused for it.
    import matplotlib.font_manager  # noqa: F401
    import numpy.testing  # noqa: F401

    _ORIGINALS.append((subprocess.Popen, "__init__", subprocess.Popen.__init__))
    subprocess.Popen.__init__ = _guarded_popen_init(subprocess.Popen.__init__)
    for name in ("fork", "forkpty", "posix_spawn", "posix_spawnp", "system"):
        original = getattr(os, name, None)
        if original is not None:
            _ORIGINALS.append((os, name, original))
            setattr(os, name, _guarded(name, original))


def uninstall() -> None:
    while _ORIGINALS:
        owner, name, original = _ORIGINALS.pop()
        setattr(owner, name, original)


def pytest_configure(config: pytest.Config) -> None:
    install()


def pytest_unconfigure(config: pytest.Config) -> None:
    uninstall()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    _STATE.allowed = item.get_closest_marker(MARKER) is not None
    _STATE.test = item.nodeid
    try:
        return (yield)
    finally:
        _STATE.allowed = True
        _STATE.test = ""
