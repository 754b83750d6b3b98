"""Where things are and how they are stored: the HDF5 artifacts and their schemas (``hdf5``, ``schemas``),
where each artifact lives (``layout``), the third-party files and their manifest (``third_party``), and
every loader of one object's artifacts, with the one cache they share (``object_artifacts``), and the
formats of streams in and poses out: numbered scene folders (``sequence_dirs``), ROS 2 bags (``rosbag_io``)
and BOP result files (``bop``).

Layer 2 of 8: imports only ``core``.
"""
