"""The basics every stage shares (no ROS): ternary grids and their validation, grid geometry
(metres <-> cells), the camera and sensor model, one :class:`~nbv_prob_cnn.basics.datasets.DatasetSpec`
per data set, the string-valued modes, and the process-wide OpenCL device."""
