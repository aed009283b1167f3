"""The `appdgen` command line: thin click commands over the library, one module per family of commands."""
from appdgen.cli import analyses, dataset, detect, geometry  # noqa: F401  (importing registers the commands)
from appdgen.cli.base import main

__all__ = ["main"]
