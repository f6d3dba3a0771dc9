"""``python -m ground.cli``: the ``ivfm`` command, and the logger of a run kept warm
(``python -m ground.cli --warm``, see contracts/warm.py)."""

import os
import sys
from pathlib import Path

from contracts.process_main import PROFILE_ENV, profiled
from contracts.warm import WARM_FLAG, exit_process, serve
from ground.cli.main import main


def _preload_logger() -> None:
    """What the logger of a run imports, loaded by a warm process before its first run."""
    import ground.cli.ground_log  # noqa: F401
    from ground.telemetry.foxglove_view import warm_up

    warm_up()


if sys.argv[1:] == [WARM_FLAG]:
    exit_process(serve(main, _preload_logger))
if os.environ.get(PROFILE_ENV) and sys.argv[1:3] == ["ground", "log"]:  # the run's logger
    exit_process(profiled("logger", main, Path(os.environ[PROFILE_ENV])))
exit_process(main())
