"""Reading tactile images: the autoencoder and its latent angle (``autoencoder``), the contact patch read from
an image and its calibration (``contact_patch``), where each sensor touches (``contacts``), light alignment
against the no-contact image (``photometric``), checks of the user's inputs (``inputs``), and the encode step
that turns a scene's images into contacts and angles (``encode``).

Layer 5 of 8: imports ``core``, ``data``, ``runtime`` and ``sim``.
"""
