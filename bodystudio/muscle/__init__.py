"""Arm-muscle capture with a depth camera (Robertini et al. 2013): model-filtered non-rigid ICP for arm
sequences, its ground truth, and the statistical arm deformation model.

* :mod:`bodystudio.muscle.arm` - the shoulder-arm template and four-part kinematics (§6.1, Eq. 12).
* :mod:`bodystudio.muscle.synthetic` - ground-truth muscle bulges, arm subjects, Kinect arm sessions.
* :mod:`bodystudio.muscle.model` - the statistical deformation model (§6.1, Eq. 6-10, 12).
"""
