"""`ns2` command line, the top layer: it may import every other package.

One convention for every command:
  * the config comes from the checkpoint or export folder a command is given (an
    export folder carries its ``ns2_config.toml``); commands that make a data set or
    a model from scratch take ``--config`` (default: the package's default.toml);
  * every expected error (``Ns2Error``) is one line on stderr and exit status 1;
  * human output on stdout, ``--json`` for machines;
  * progress bars on stderr for everything that takes more than a few seconds
    (off with ``--quiet`` or when stderr is not a terminal).

One module per command group (``common`` holds what they share); importing them
registers their commands on ``main``.  The experiment commands (the paper's
reproduction: ``real``, ``simexp``, ``planexp``, ``results``) are the only modules that import
ns2exp (tests/test_layers.py).
"""
from . import core, flights, fly, plan, real, sim, target  # noqa: F401  (registers the commands)
from . import planexp, results, simexp  # noqa: F401  (the experiment commands: the only modules that import ns2exp, with real)
from .common import main

__all__ = ["main"]

if __name__ == "__main__":
    main()
