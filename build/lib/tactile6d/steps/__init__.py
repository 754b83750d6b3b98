"""The estimator's four steps, one module each, so that a pipeline stage imports only the step it runs.

1. ``encode``: tactile images (L, 320, 240, 3) uint8 RGB -> latent angles (L,) rad (the autoencoder);
2. ``select``: database point tuples (T, L) whose latent angles (method ``ours``) and pairwise
   distances match the sensors' (``tactile6d.selection``); method ``baseline`` skips the angles;
3. ``optimize``: one or 15 poses per tuple (``tactile6d.optimize``, solver ``fast`` or ``gd``);
4. ``rank``: the top-k distinct poses by loss + deepest sensor penetration (``tactile6d.collision``,
   ``tactile6d.ranking``), optionally refined against the surface (``tactile6d.refine``).

``tactile6d.estimator.Estimator`` chains them for one object; the select_tuples, optimize and rank
stages call the same functions, so an offline run and an online estimate of the same input agree.
Each step module also holds the loaders of the artifacts only it needs.
"""
