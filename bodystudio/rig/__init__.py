"""Rigging stage, Avatar Reshaping §4.2 and §5: skeleton transfer by mean value coordinates
(``skeleton_transfer``), harmonic skin-weight transfer (``weights``), reshaping by deformation
transfer (``reshape``), glTF/BVH/JSON export (``export``), the scan-to-avatar pipeline (``pipeline``)
and its evaluation (``evaluate``). See docs/rigging.md."""
