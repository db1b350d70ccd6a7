"""The earlier name of :mod:`sonoslice.datasets.reader` (``ShardDataset``, ``read_shard``, ...),
kept importable: this module is that one."""
import sys

from .datasets import reader

sys.modules[__name__] = reader
