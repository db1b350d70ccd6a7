"""The earlier name of :mod:`sonoslice.datasets.writer` (``write_dataset``, ``load_spec``, ...),
kept importable: this module is that one."""
import sys

from .datasets import writer

sys.modules[__name__] = writer
