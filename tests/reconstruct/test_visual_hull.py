"""Visual hull (Rapid Skin Sec. IV, contribution 4): carving, coverage of the body, volume, virtual depth."""

import numpy as np
import pytest

from bodystudio.errors import InputError

VOXEL_M = 0.015


@pytest.fixture(scope="module")
def hull_capture():
    """A 2k subject in an arms-raise frame seen by 8 ring cameras at 320x240, and its visual hull."""
    from bodystudio.body import build_body
    from bodystudio.body.population import sample_subject
    from bodystudio.capture.motion import motion_sequence
    from bodystudio.capture.render import render
    from bodystudio.geometry.camera import ring_rig
    from bodystudio.reconstruct.visual_hull import visual_hull

    phenotype, local = sample_subject(23)
    body = build_body(phenotype, local, resolution="2k")
    pose = motion_sequence("arms_raise", 16, body.skeleton, seed=1)[4]
    V, _ = body.pose(pose)
    rig = ring_rig(8, 320, 240)
    masks = {cam.name: render(V, body.faces, cam).mask for cam in rig}
    return {"V": V, "F": body.faces, "rig": rig, "masks": masks,
            "hull": visual_hull(rig, masks, voxel_m=VOXEL_M)}


def test_hull_contains_ground_truth_surface(hull_capture):
    """Measured 98.9-99.2% (320x240, 1.5 cm voxels); the misses are finger tips thinner than a voxel."""
    from bodystudio.reconstruct.visual_hull import hull_coverage

    hull = hull_capture["hull"]
    assert hull_coverage(hull, hull_capture["V"], dilate_voxels=1) >= 0.98
    # without the dilation, about half the surface vertices fall in empty voxels next to the hull:
    # the one-voxel dilation is what the bound needs, not slack
    assert hull_coverage(hull, hull_capture["V"], dilate_voxels=0) < 0.9


def test_hull_volume_bounds_ground_truth(hull_capture):
    """The hull is a superset of the body: measured 1.04 (arms raise) to 1.11 (walk) x the GT volume."""
    from bodystudio.body.measure import enclosed_volume

    gt = enclosed_volume(hull_capture["V"], hull_capture["F"])
    ratio = hull_capture["hull"].volume_m3 / gt
    assert 0.98 <= ratio <= 1.25, ratio
    # the marching-cubes surface encloses the same volume as the voxels, within the half-voxel shell
    surf = enclosed_volume(hull_capture["hull"].vertices, hull_capture["hull"].faces)
    assert abs(surf / hull_capture["hull"].volume_m3 - 1.0) < 0.15


def test_coarse_to_fine_carving_loses_no_voxel(hull_capture):
    """The conservative coarse levels give exactly the brute-force voxel-centre carving."""
    from bodystudio.reconstruct.visual_hull import carve_occupancy

    V = hull_capture["V"]
    bounds = (V.min(0) - 0.1, V.max(0) + 0.1)
    fine, o1 = carve_occupancy(hull_capture["rig"], hull_capture["masks"], bounds, 0.02, levels=3)
    brute, o2 = carve_occupancy(hull_capture["rig"], hull_capture["masks"], bounds, 0.02, levels=0)
    np.testing.assert_allclose(o1, o2)
    assert brute.sum() > 1000
    # the coarse grid rounds the box up to whole coarse cells; on the common box both agree exactly
    nx, ny, nz = brute.shape
    assert np.array_equal(fine[:nx, :ny, :nz], brute)


def test_allowing_a_missing_view_only_adds_voxels(hull_capture):
    from bodystudio.reconstruct.visual_hull import visual_hull

    masks = dict(hull_capture["masks"])
    name = hull_capture["rig"].names[0]
    masks[name] = masks[name].copy()
    masks[name][:, : masks[name].shape[1] // 2 + 5] = False  # half of one silhouette lost
    strict = visual_hull(hull_capture["rig"], masks, voxel_m=VOXEL_M)
    tolerant = visual_hull(hull_capture["rig"], masks, voxel_m=VOXEL_M, max_missing_views=1)
    from bodystudio.reconstruct.visual_hull import hull_coverage

    assert hull_coverage(strict, hull_capture["V"], 1) < 0.8  # the damaged view carves away the body
    assert hull_coverage(tolerant, hull_capture["V"], 1) >= 0.98
    assert tolerant.volume_m3 > strict.volume_m3


def test_virtual_depth_map_is_in_front_of_the_body(hull_capture):
    """The hull's depth map from the virtual Kinect covers the body's and lies on or in front of it.

    Measured (arms raise, 1.5 cm voxels): 96.5% of the body's pixels covered (the misses are finger tips
    and the silhouette rim, where the iso-surface sits up to a voxel inside the outermost voxel centres);
    hull minus body depth: median -0.7 mm, 90th percentile 7.8 mm.
    """
    from bodystudio.capture.render import render
    from bodystudio.reconstruct.visual_hull import hull_depth_map, virtual_depth_camera

    hull = hull_capture["hull"]
    cam = virtual_depth_camera(hull)
    assert np.allclose(cam.center, hull.centroid + [0.0, 0.0, 2.5])
    depth = hull_depth_map(hull, cam)
    gt = render(hull_capture["V"], hull_capture["F"], cam).depth
    body = gt > 0
    both = body & (depth > 0)
    assert both.sum() / body.sum() >= 0.95
    # superset up to the discretisation: the hull's front surface is rarely more than a voxel behind
    assert np.quantile(depth[both] - gt[both], 0.9) <= VOXEL_M
    assert abs(np.median(depth[both] - gt[both])) < 0.005


def test_bad_masks_are_one_line_errors(hull_capture):
    from bodystudio.reconstruct.visual_hull import visual_hull

    rig, masks = hull_capture["rig"], dict(hull_capture["masks"])
    empty = dict(masks, **{rig.names[1]: np.zeros_like(masks[rig.names[1]])})
    with pytest.raises(InputError, match="empty"):
        visual_hull(rig, empty)
    with pytest.raises(InputError, match="no mask"):
        visual_hull(rig, {k: v for k, v in masks.items() if k != rig.names[2]})
    with pytest.raises(InputError, match="is \\(10, 10\\)"):
        visual_hull(rig, dict(masks, **{rig.names[0]: np.ones((10, 10), bool)}))
