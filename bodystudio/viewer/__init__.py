"""Viewer, HTML export and reports: look at meshes, scans, avatars and capture sessions.

- :mod:`bodystudio.viewer.scene`: ``add_*`` functions that put meshes, error maps, skeletons, skin weights,
  camera frusta and point clouds on a PyVista plotter; offscreen screenshots that refuse an empty scene.
- :mod:`bodystudio.viewer.views`: what ``bodystudio view`` shows for a session, mesh, scan or avatar.
- :mod:`bodystudio.viewer.webgl`: standalone HTML (inline WebGL, no server, no network) of a scene.
- :mod:`bodystudio.viewer.report`: the self-contained HTML report of a run or session.
"""
