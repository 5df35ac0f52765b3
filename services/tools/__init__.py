"""The ``shepherd`` command (``cli``) and the operator tools behind its verbs: ``echo``,
``recorder`` (record/replay), ``bench`` (one module per subject), ``experiments``, ``soak``,
``calibrate``, ``sim_snapshot``, ``kernels`` (compile), ``pretty`` (readable messages).
Imported on demand by the command; nothing in a service imports them."""

__all__ = ["cli"]
