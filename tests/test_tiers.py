"""The tiers' guard (tests/tiers.py): a test outside the process tier cannot start a
process, one in it can."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.tiers import ProcessOutsideTierError


def test_a_logic_test_that_starts_a_process_is_told_to_mark_itself():
    with pytest.raises(ProcessOutsideTierError, match="mark this test `process`"):
        subprocess.run([sys.executable, "-c", "pass"], check=True)
    for name in ("fork", "forkpty", "system"):  # multiprocessing, pexpect, shells
        # Wrapped (else calling it would fork this test run), and the wrapper refuses.
        assert hasattr(getattr(os, name), "__wrapped__"), name
        with pytest.raises(ProcessOutsideTierError, match=rf"os\.{name}"):
            getattr(os, name)(*(["true"] if name == "system" else []))


@pytest.mark.process
def test_a_process_test_starts_processes():
    assert subprocess.run([sys.executable, "-c", "pass"], check=True).returncode == 0
