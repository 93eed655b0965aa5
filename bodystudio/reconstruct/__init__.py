"""Reconstruction stage, Rapid Skin (Straka et al. 2012): pose initialisation from joints (§IV.A,
``pose_init``), rim-vertex contour matching (``silhouette``), Kinect depth constraints (``depth``), the
Gauss-Seidel constraint solver and its Jacobi/Cholesky/CG counterparts (§III, ``solver``), one frame's
deformation (``rapid_skin``), sequences (``sequence``), joints from the visual hull (``visual_hull``,
``articulated_fit``) and the evaluation against ground truth (``evaluate``). See docs/reconstruct.md."""
