"""The one base class of every expected error (bad input file or field, missing tool,
failed build).  The CLI turns an ``Ns2Error`` into one line and exit status 1; anything
else is a bug and keeps its traceback.  ``Ns2Warning``: the same for a warning (one
line, the command goes on)."""


class Ns2Error(Exception):
    """An expected failure, with a message that names the file and field."""


class Ns2Warning(UserWarning):
    """Something the user should know that does not stop the command (the CLI prints
    it as one line ``Warning: ...``)."""
