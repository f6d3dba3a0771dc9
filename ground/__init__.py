"""Ground-station side: scenarios, runs, metrics, reports and the ``ivfm`` command.

Packages by job, in layers (each imports only the layers below it; pyproject.toml's
import-linter contract 6 checks it):

    cli                                   the ivfm command, one module per subcommand
    rehearsal                             go / no-go before a first flight
    check | campaign                      regression checks | campaigns and comparisons
    run                                   flying a scenario (processes, in process)
    report | identify | telemetry | uplink | ulog
    record                                the run folder, its log, timeline and events
    scenario                              scenario files, expectations, ground station
"""
