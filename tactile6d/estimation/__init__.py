"""From contacts to poses: the ``Estimator`` (``estimator``) and its steps, each algorithm in one module with
the step that calls it: ``select`` (tuples of database points), ``optimize`` (pose hypotheses), ``rank``
(collision-aware ranking, re-scored by ``refine`` and ``render_and_compare``; penetrations from
``collision``); the confidence of an estimate (``confidence``); which object it is (``identifier``, with its
score model in ``identity_model``); the pose followed over frames (``tracker``); and how the per-run stages
store their outputs (``run_storage``).

Layer 6 of 8: imports every layer below it (``core`` to ``perception``).
"""
