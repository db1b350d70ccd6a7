"""Datasets (docs/datasets.md): :mod:`sonoslice.datasets.writer` makes one from a SPEC (YAML or
JSON) as WebDataset shards plus a manifest (``sonoslice dataset SPEC --out DIR`` runs it);
:mod:`sonoslice.datasets.reader` streams the shards into PyTorch for training (it needs torch,
so it is not imported here)."""
