"""Registration stage, Avatar Reshaping §4 (Feng et al. 2015): scan input and clean-up (``scan``),
synthetic scans with ground truth (``synthetic``), automatic initial pose (§4.3, ``initial_pose``) and
the alternating pose/shape fit of the statistical model (eq. 5, ``fit``). See docs/rigging.md."""
