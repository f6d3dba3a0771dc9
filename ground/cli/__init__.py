"""The ``ivfm`` command: one module per subcommand, holding its parser and its handler.

``main.py`` lists the subcommands (``SUBCOMMANDS``: name, module, one line of help) and
imports only the module of the command named on the command line, so ``ivfm ground log``
starts without the vehicle's compiled code. A subcommand module defines ``add_arguments``
and ``handle`` (and may define ``DESCRIPTION``); a group (``ivfm ground ...``) defines
its own ``SUBCOMMANDS`` instead. Adding a subcommand: one new module here, one line in
the list. The top layer of ``ground/``: it may import every other package.
"""
