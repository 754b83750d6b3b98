"""The simulated world: the DIGIT renderer (``render``), superquadric presses for training (``superquadrics``),
meshes and their collision pieces (``meshes``), a user's mesh file read in its declared units and checked
(``mesh_import``), points on an object's surface (``surface_sampling``), contact
types (``contact_types``), the press a pose predicts on a gel (``gel_press``), the rendered databases
(``database``), scene sets (``scenes``), what a real set-up does to them (``perturb``: light drift, sensor
pose error) and tracking sequences, an object in a moving grasp frame by frame (``sequences``).

Layer 4 of 8: imports ``core``, ``data`` and ``runtime``.
"""
