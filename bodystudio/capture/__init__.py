"""Capture stage: synthetic studio and Kinect capture of a posed body.

- ``render``: numba z-buffer rasteriser (silhouette, depth, triangle ids, barycentrics, Lambert RGB)
  and deterministic background plates per camera, so background subtraction can be tested.
- ``kinect``: Kinect depth-noise simulation after Khoshelham & Elberink (2012) (axial noise,
  disparity quantisation, projector shadow, flying pixels, holes) and a body-tracker joint simulator.
- ``motion``: ground-truth pose sequences from joint-angle keyframes (a_pose, t_pose, arms_raise,
  walk, turn, arm_flex).

Cameras, rigs and RGB-D sensor layouts live in :mod:`bodystudio.geometry.camera`.
"""
