"""Calibration stage: ChArUco boards and their detection (``board``), rendered board views (``render``),
synthetic calibration captures (``synthetic``), per-camera intrinsics, camera-graph initialisation and
one bundle adjustment over all cameras and board poses (``calibrate``), the calibration's own
uncertainty, coverage and verdict (``uncertainty``), the floor-board world frame (``world``),
depth-camera extrinsics (``depth``), EasyMocap YAML and COLMAP I/O (``io``), scores against ground truth
(``evaluate``) and the chained ``cv2.stereoCalibrate`` baseline (``baseline``). See docs/calibration.md."""
