"""The foundations every other layer stands on: rigid-body geometry (``geometry``), the project's error
types (``errors``), the configuration tree and its typed views (``config``, ``settings``), the DIGIT's own
geometry (``sensor``: frames, gel, body) and the pose-error metrics, defined once (``metrics``: positional
error, ADI, AUC, AUROC).

Layer 1 of 8 (core < data < runtime < sim < perception < estimation < evaluation < cli): it imports no
other tactile6d layer; ``tests/test_layers.py`` checks the order.
"""
