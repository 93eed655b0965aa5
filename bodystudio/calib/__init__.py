"""Calibration stage: ChArUco boards and their detection (``board``), synthetic calibration captures
(``synthetic``), per-camera intrinsics, camera-graph initialisation and one bundle adjustment over all
cameras and board poses (``calibrate``), the floor-board world frame (``world``), depth-camera
extrinsics (``depth``), EasyMocap YAML and COLMAP I/O (``io``), scores against ground truth
(``evaluate``) and the chained ``cv2.stereoCalibrate`` baseline (``baseline``). See docs/calibration.md."""
