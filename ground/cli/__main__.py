"""``python -m ground.cli``: the ``ivfm`` command (and, forked by the process loader,
contracts/zygote.py, a run's logger)."""

import os
import sys
from pathlib import Path

from contracts.process_main import PROFILE_ENV, end_with_command, exit_process, profiled
from ground.cli.main import main


def preload() -> None:
    """What the logger of a run imports, loaded once by the process loader."""
    import ground.cli.ground_log  # noqa: F401
    from ground.telemetry.foxglove_view import warm_up

    warm_up()


if __name__ == "__main__":
    if sys.argv[1:3] == ["ground", "log"]:  # a run's logger, started by its command itself
        end_with_command()
    if os.environ.get(PROFILE_ENV) and sys.argv[1:3] == ["ground", "log"]:  # a run's logger
        exit_process(profiled("logger", main, Path(os.environ[PROFILE_ENV])))
    exit_process(main(start_loader_first=True))
