"""Plant the session readers' mutants that mutmut cannot make (``Frame``'s and ``Session``'s ``cached_property`` /
``property`` readers: mutmut does not mutate decorated functions) by hand in a scratch copy and run the session
format's fast tests against each."""
# usage (from the repository root): [PLANT_ONLY="name;name"] python docs/mutation/capture-session-plant.py [TEST_FILE ...]
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from plant import replay  # noqa: E402

work = os.environ.get("PLANT_WORK", "/work/wt-mutCC-work/session-plant")
S = "bodystudio/capture/session.py"
mutants = [
    ('lambda rel: self.session.read_image(rel, False) > 127)\n\n    @cached_property\n    def gt_masks',
     'lambda rel: self.session.read_image(rel, False) > 0)\n\n    @cached_property\n    def gt_masks',
     "masks: > 0 for > 127"),
    ('_LazyFiles(self.session, "rgb", self.frame_id, lambda rel: self.session.read_image(rel, True))',
     '_LazyFiles(self.session, "rgb", self.frame_id, lambda rel: self.session.read_image(rel, False))',
     "images: read as one channel"),
    ('return _LazyFiles(self.session, "gt_mask", self.frame_id,', 'return _LazyFiles(self.session, "mask", self.frame_id,',
     "gt_masks: the mask stream"),
    ('_LazyFiles(self.session, "gt_layers", self.frame_id,', '_LazyFiles(self.session, "gt_target_layers", self.frame_id,',
     "gt_layers: the target's layers"),
    ('return _LazyFiles(self.session, "gt_target_layers", self.frame_id,',
     'return _LazyFiles(self.session, "gt_layers", self.frame_id,', "gt_target_layers: the frame's layers"),
    ('        return raw.astype(np.float64) / DEPTH_MM_PER_M', '        return raw.astype(np.float64) / 1024.0',
     "kinect_depth_m: 1024 per metre"),
    ('        return raw.astype(np.float64) / DEPTH_MM_PER_M', '        return raw.astype(np.float32) / DEPTH_MM_PER_M',
     "kinect_depth_m: float32"),
    ('        if raw.dtype != np.uint16:', '        if raw.dtype == np.uint8 and False:', "kinect_depth_m: 8-bit accepted"),
    ('        return None if rel is None else self.session.read_image(rel, True)\n\n    @cached_property\n'
     '    def kinect_player', '        return None if rel is None else self.session.read_image(rel, False)\n\n'
     '    @cached_property\n    def kinect_player', "kinect_rgb: one channel"),
    ("        if mask.dtype != np.uint8 or mask.max(initial=0) > MAX_PLAYERS:",
     "        if mask.dtype != np.uint8 or mask.max(initial=0) > MAX_PLAYERS + 1:", "kinect_player: 7 accepted"),
    ("        if mask.dtype != np.uint8 or mask.max(initial=0) > MAX_PLAYERS:",
     "        if mask.max(initial=0) > MAX_PLAYERS:", "kinect_player: 16-bit accepted"),
    ('            if len(set(players)) != len(players):', '            if False:', "kinect_bodies: repeated players"),
    ('            if not isinstance(data["bodies"], list):', '            if isinstance(data["bodies"], str):',
     "kinect_bodies: 'bodies' not a list"),
    ('        if not isinstance(data, dict):\n            raise SessionError(f"{source}: malformed joints (top',
     '        if isinstance(data, str):\n            raise SessionError(f"{source}: malformed joints (top',
     "kinect_bodies: top level not an object"),
    ('        return [_parse_body({**data, "player": 1}, source, data.get("joint_set"))]',
     '        return [_parse_body(data, source, data.get("joint_set"))]', "kinect_bodies: old layout's player kept"),
    ('        return [_parse_body({**data, "player": 1}, source, data.get("joint_set"))]',
     '        return [_parse_body({**data, "player": 1}, source, None)]', "kinect_bodies: old layout's joint set"),
    ('bodies = [_parse_body(b, source, data.get("joint_set")) for b in data["bodies"]]',
     'bodies = [_parse_body(b, source, None) for b in data["bodies"]]', "kinect_bodies: the file's joint set"),
    ('        first = min(bodies, key=lambda b: b["player"])', '        first = bodies[-1]', "kinect_joints: last body"),
    ('        first = min(bodies, key=lambda b: b["player"])', '        first = max(bodies, key=lambda b: b["player"])',
     "kinect_joints: highest player"),
    ('        if not bodies:\n            return None\n        first', '        if bodies is None:\n            return None\n'
     '        first', "kinect_joints: nobody tracked"),
    ('        return self._optional_labels("gt_person")', '        return self._optional_labels("gt_target_person")',
     "gt_person: the target's labels"),
    ('        return self._optional_labels("gt_target_person")', '        return self._optional_labels("gt_person")',
     "gt_target_person: the input's labels"),
    ('        rel = self._optional("gt_target_rgb")\n        return None if rel is None else self.session.read_image(rel, True)',
     '        rel = self._optional("gt_target_rgb")\n        return None if rel is None else self.session.read_image(rel, False)',
     "gt_target_rgb: one channel"),
    ('        return self._optional_mesh("gt_arm_mesh")', '        return self._optional_mesh("gt_mesh")',
     "gt_arm_mesh: the body mesh"),
    ('"tails": np.asarray(data["tails"], dtype=np.float64)}', '"tails": np.asarray(data["heads"], dtype=np.float64)}',
     "gt_joints: heads for tails"),
    ('        bones = tuple(data.get("bone_names") or self.gt_joints["bone_names"])',
     '        bones = tuple(self.gt_joints["bone_names"])', "gt_pose: the pose's own bone names"),
    ('        return self.manifest["files"]', '        return dict(self.manifest["files"], **{"x": "y"})',
     "Session.files: an extra entry"),
    ('        return list(self.manifest["cameras"])', '        return sorted(self.manifest["cameras"], reverse=True)',
     "Session.camera_names: reordered"),
    ('        return self.manifest.get("source", "unknown")', '        return self.manifest.get("source", "import")',
     "Session.source: default"),
    ('        return self.manifest.get("metadata", {})', '        return {}', "Session.metadata: dropped"),
    ('        self.read_bytes(CAMERAS_JSON)  # checksum check before parsing', '        pass',
     "Session.cameras: no checksum check"),
    ("        if KINECT_CALIBRATION not in self.files:\n            return None",
     "        if KINECT_CALIBRATION in self.files:\n            return None", "Session.kinect: inverted"),
    ('        return self._gt_albedo("albedo")', '        return self._gt_albedo("appearance")',
     "Session.gt_albedo: the appearance"),
    ('        return self._gt_albedo("appearance")', '        return self._gt_albedo("albedo")',
     "Session.gt_appearance_albedo: the skin albedo"),
    ('        return self.read_json(GT_LIGHTING) if GT_LIGHTING in self.files else None',
     '        return self.read_json(GT_GARMENT) if GT_GARMENT in self.files else None', "Session.gt_lighting: garment"),
    ('        return parse_npz_bytes(self.read_bytes(GT_MIRROR_ACTORS), str(self.path / GT_MIRROR_ACTORS))',
     '        return {}', "Session.gt_mirror_actors: empty"),
    ('        return list(self.manifest["frames"])', '        return sorted(set(self.manifest["frames"]) | {0})',
     "Session.frame_ids: frame 0 added"),
]
tests = sys.argv[1:] or ["tests/capture/test_session_format_mutants.py", "tests/capture/test_session_writer_mutants.py",
                         "tests/capture/test_session.py", "tests/capture/test_session_bodies.py"]
only = [n for n in os.environ.get("PLANT_ONLY", "").split(";") if n]  # re-run these names only (";"-separated)
replay(S, [m for m in mutants if not only or m[2] in only], tests, work, unique=False, pytest_args=("-m", "not slow"))
