"""Shared mesh and camera maths used by every stage: ``Mesh`` and mesh I/O (``mesh``), the OpenCV
pinhole ``Camera`` / ``CameraRig`` and studio/Kinect presets (``camera``), and cotangent Laplacian
delta coordinates (``laplacian``)."""
