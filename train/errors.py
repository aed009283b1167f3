"""The trainer's one user-facing error type."""


class TrainError(Exception):
    """Bad input or an impossible request; the CLI prints it as one line and exits 2."""
