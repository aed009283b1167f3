"""The package's version, at the ground so that any stage may record it (build.json, --version)."""

__version__ = "0.3.0"
