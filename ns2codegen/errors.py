"""The one base class of every expected error of ns2codegen (bad input files,
impossible parameters, unusable output locations): the CLI turns any of them into
a one-line message naming the file and the field, and exit status 1."""


class Ns2Error(Exception):
    """An expected error with a one-line, user-facing message."""
