"""The one error type users see: a message naming the file (or option) and the problem."""


class AppdgenError(Exception):
    """Bad input or an impossible request; the CLI prints it as one line and exits 2."""
