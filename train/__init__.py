"""A thin torch trainer for APPD regression on appdgen's WebDataset shards.

torch is an optional extra (`pip install -e .[train]`); nothing here imports it at package import.
"""
from train.errors import TrainError

__all__ = ["TrainError"]
