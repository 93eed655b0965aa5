"""Arm-muscle capture with a depth camera (Robertini et al. 2013): model-filtered non-rigid ICP for arm
sequences. Not started: no issue has asked for it yet."""
