"""The virtual mirror: real-time reshaping of a person in Kinect RGB-D video (Real-time Reshaping of Humans).

The pipeline, in the paper's order:

1. Input (§3): Kinect frames (colour 640x480, depth, the SDK's player mask and tracked joints) from a
   session (:mod:`bodystudio.mirror.frames`); synthetic mirror sessions with the ground truth of the
   edits come from :mod:`bodystudio.mirror.synthetic`.
2. Initialisation (§4, :mod:`~bodystudio.mirror.init`): the actor's point cloud is brought to the default
   pose (bone scaling, IK down the chains, closest-vertex correspondences, inverse LBS), the statistical
   model's coefficients are fitted (Eq. 2) over several frames and averaged, the skeleton refitted (Eq. 3).
3. Per frame (§5): pose by IK against the Kinect joints (§5.2, :mod:`~bodystudio.mirror.track`); the target
   body by Eq. 4 with the semantic directions, changed gradually (:mod:`~bodystudio.mirror.reshape`); the
   foreground by a graph cut in a band around the player mask (§5.3, :mod:`~bodystudio.mirror.foreground`);
   the image warp by moving least squares on a 160x120 grid from projected source/target vertex pairs
   (Eq. 5, :mod:`~bodystudio.mirror.warp`); the composition of the warped person over a background model
   learned where the person was not (§5.5, :mod:`~bodystudio.mirror.compose`).
4. Output: :func:`bodystudio.mirror.run.run_mirror` writes the video and the per-frame results that
   :func:`bodystudio.mirror.evaluate.evaluate_mirror` scores against the synthetic ground truth.

The stage imports only ``body``, ``geometry``, ``capture``, ``errors``, ``fileio`` and ``runfolder``.
"""
