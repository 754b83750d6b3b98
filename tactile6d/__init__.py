"""tactile6d: 6D object pose from several DIGIT tactile sensors (Caddeo et al., ICRA 2023, rebuilt).

The library is eight subpackages in layers, lowest first; a module imports only from its own layer and
lower ones (``tests/test_layers.py``):

- ``core``: geometry, errors, configuration and settings, the DIGIT's geometry, pose-error metrics;
- ``data``: HDF5 artifacts, where they live, third-party files, loading one object's artifacts;
- ``runtime``: the executor, the CPU pin, what every pipeline stage shares;
- ``sim``: renderer, meshes, surface samples, contact types, databases, scenes and their perturbations;
- ``perception``: autoencoder, contact patches, contacts from images, light alignment, input checks;
- ``estimation``: the estimator (select, optimize, rank, refine, render-and-compare), confidence,
  identification;
- ``evaluation``: scoring, contact and identification accuracy, studies, fidelity, plots;
- ``cli``: the ``tactile6d`` command.
"""

__version__ = "0.1.0"
