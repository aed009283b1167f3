"""The old path of appdgen.sources.files.list_images, kept for the README's Python example only (the coordinator
moves that example to appdgen.sources.files; then this file goes)."""
from appdgen.sources.files import list_images

__all__ = ["list_images"]
