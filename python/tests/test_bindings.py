"""The small bound classes (BeamGeometry, HoleFillingElement, FrameClip, VolumeGrid): keyword
construction, checks by the library's validate() naming the field, readable reprs, the dicts users
pass today; and interpolation= as the one keyword (interp= deprecated)."""
import math
import os
import warnings

import numpy as np
import pytest

import sonoslice
from conftest import small_probe
from sonoslice import _sonoslice as ext
from sonoslice import fanslicer


# ---- BeamGeometry ------------------------------------------------------------------------------------
def test_beam_geometry_keywords_positions_defaults_and_repr():
    g = sonoslice.BeamGeometry(r0_mm=3, dr_mm=0.4, azimuth0_deg=-20, dazimuth_deg=5, elevation0_deg=-8,
                               delevation_deg=4, apex_offset_mm=2)
    assert (g.r0_mm, g.dr_mm, g.azimuth0_deg, g.dazimuth_deg, g.elevation0_deg, g.delevation_deg,
            g.apex_offset_mm) == (3, 0.4, -20, 5, -8, 4, 2)
    assert sonoslice.BeamGeometry(3, 0.4, -20, 5, -8, 4, 2) == g  # the dataclass's field order
    assert sonoslice.BeamGeometry() == sonoslice.BeamGeometry(0, 1, 0, 1, 0, 1, 0)  # BeamGeometry.h's defaults
    assert repr(g) == ("BeamGeometry(r0_mm=3.0, dr_mm=0.4, azimuth0_deg=-20.0, dazimuth_deg=5.0, "
                       "elevation0_deg=-8.0, delevation_deg=4.0, apex_offset_mm=2.0)")
    assert eval(repr(g), {"BeamGeometry": sonoslice.BeamGeometry}) == g
    g.dr_mm = 0.5  # writable, as the dataclass's fields were
    assert g.dr_mm == 0.5 and g != sonoslice.BeamGeometry(3, 0.4, -20, 5, -8, 4, 2)


@pytest.mark.parametrize("field, value, message", [
    ("dr_mm", 0.0, "sample spacing dr_mm must be positive"),
    ("r0_mm", -1.0, "first sample depth r0_mm must not be negative"),
    ("apex_offset_mm", math.nan, "beam geometry apex_offset_mm is not finite"),
    ("azimuth0_deg", 90.0, r"beam angles must stay within ±90 degrees \(azimuth0_deg 90"),
    ("elevation0_deg", -95.0, r"beam angles must stay within ±90 degrees \(elevation0_deg -95"),
])
def test_beam_geometry_is_checked_when_built_naming_the_field(field, value, message):
    with pytest.raises(ValueError, match="^BeamGeometry: " + message):
        sonoslice.BeamGeometry(**{field: value})


def test_beam_geometry_from_dicts_paths_and_objects_gives_the_same_reconstruction(tmp_path):
    d = dict(r0_mm=3, dr_mm=0.4, azimuth0_deg=-20, dazimuth_deg=5, elevation0_deg=-8, delevation_deg=4)
    g = sonoslice.BeamGeometry.of(d)
    assert isinstance(g, sonoslice.BeamGeometry) and g == sonoslice.BeamGeometry(**d)
    g.save(tmp_path / "beams.json")
    assert sonoslice.BeamGeometry.of(tmp_path / "beams.json") == g
    assert sonoslice.BeamGeometry.from_file(str(tmp_path / "beams.json")) == g
    frames = np.random.default_rng(5).uniform(1, 100, (5, 9, 30)).astype(np.float32)
    pose = np.eye(4)
    volumes = []
    for geometry in (d, g, tmp_path / "beams.json"):
        c = sonoslice.Compounder.around_beams(pose, g, frames.shape, 0.8, interpolation="nearest")
        volumes.append(c.add_beams(frames, pose, geometry).volume().array)
    assert volumes[0].any()
    assert all(v.tobytes() == volumes[0].tobytes() for v in volumes)
    with pytest.raises(ValueError, match=r"beam geometry: unknown key\(s\) \['r0'\]; expected apex_offset_mm"):
        sonoslice.BeamGeometry.of(dict(r0=1))


# ---- HoleFillingElement ------------------------------------------------------------------------------
def test_hole_filling_element_keywords_defaults_and_repr():
    e = sonoslice.HoleFillingElement("gaussian", size=5, stdev=1.5, minimum_known_ratio=0.25)
    assert (e.type, e.size, e.stdev, e.minimum_known_ratio) == ("gaussian", 5, 1.5, 0.25)
    d = sonoslice.HoleFillingElement()  # PLUS's default element (CompoundSettings.h)
    assert (d.type, d.size, d.stdev, d.minimum_known_ratio, d.stick_length_limit, d.sticks_to_use) == \
        ("gaussian", 3, 0.6667, 0.5, 9, 1)
    assert repr(e) == "HoleFillingElement(type='gaussian', size=5, stdev=1.5, minimum_known_ratio=0.25)"
    stick = sonoslice.HoleFillingElement("STICK", stick_length_limit=5)  # PLUS's spelling too
    assert repr(stick) == "HoleFillingElement(type='stick', stick_length_limit=5, sticks_to_use=1)"
    nearest = sonoslice.HoleFillingElement("nearest_neighbor", size=7)
    assert repr(nearest) == "HoleFillingElement(type='nearest_neighbor', size=7, minimum_known_ratio=0.5)"
    for element in (e, stick, nearest):
        assert eval(repr(element), {"HoleFillingElement": sonoslice.HoleFillingElement}) == element
    assert e != d


@pytest.mark.parametrize("kwargs, message", [
    (dict(size=4), "size 4 must be odd, 3 to 31 voxels"),
    (dict(stdev=0.0), "stdev .* must be positive"),
    (dict(type="gaussian_accumulation", stdev=math.inf), "stdev .* must be positive"),
    (dict(minimum_known_ratio=1.0), r"minimum_known_ratio must be in \[0, 1\)"),
    (dict(type="stick", stick_length_limit=2), "stick_length_limit 2 must be between 3 and 255"),
    (dict(type="stick", sticks_to_use=14), "sticks_to_use 14 must be between 1 and 13"),
])
def test_hole_filling_element_is_checked_when_built_naming_the_field(kwargs, message):
    with pytest.raises(ValueError, match="^HoleFillingElement: " + message):
        sonoslice.HoleFillingElement(**kwargs)


def test_hole_filling_element_type_names():
    with pytest.raises(ValueError, match="hole filling type 'bogus'"):
        sonoslice.HoleFillingElement("bogus")
    e = sonoslice.HoleFillingElement()
    with pytest.raises(ValueError, match="hole filling type 'cubic'"):
        e.type = "cubic"
    e.type = "distance_weight_inverse"
    assert e.type == "distance_weight_inverse"


def holey(**settings):
    """A 5-slice grid filled on slices 0, 2 and 4 only: slices 1 and 3 are holes."""
    frames = np.random.default_rng(7).uniform(10, 200, (3, 8, 8)).astype(np.float32)
    mats = np.stack([np.diag([1.0, 1.0, 1.0, 1.0]) for _ in range(3)])
    mats[:, 2, 3] = (0, 2, 4)
    c = sonoslice.Compounder(shape=(5, 8, 8), spacing=1.0, interpolation="nearest", **settings)
    return c.add(frames, mats)


def test_hole_filling_dicts_short_and_long_names_and_elements_agree():
    dicts = [dict(type="gaussian", size=5, stdev=1.0, min_ratio=0.2), dict(type="stick", length_limit=7, sticks=2)]
    long_names = [dict(type="gaussian", size=5, stdev=1.0, minimum_known_ratio=0.2),
                  dict(type="stick", stick_length_limit=7, sticks_to_use=2)]
    elements = [sonoslice.HoleFillingElement("gaussian", size=5, stdev=1.0, minimum_known_ratio=0.2),
                sonoslice.HoleFillingElement("stick", stick_length_limit=7, sticks_to_use=2)]
    results = [holey(hole_filling=h) for h in (dicts, long_names, elements)]
    assert all(c.fill_holes and c.hole_filling == dicts for c in results)
    volumes = [c.volume().array for c in results]
    assert all(v.tobytes() == volumes[0].tobytes() for v in volumes)
    assert (holey().volume().array[1] == 0).all() and (volumes[0][1] > 0).all()  # the holes were filled
    # The default, one Gaussian 3³ needing half its cube known, leaves the rim of the holes empty.
    default = holey(fill_holes=True).volume().array
    assert (default[1] > 0).any() and (default[1] == 0).any()


def test_a_bad_hole_filling_dict_is_named_by_its_place_in_the_list():
    with pytest.raises(ValueError, match="hole filling element 2: sticks_to_use 20 must be between 1 and 13"):
        sonoslice.Compounder(shape=(4, 4, 4), spacing=1.0, hole_filling=[dict(type="gaussian"),
                                                                          dict(type="stick", sticks=20)])


# ---- FrameClip ---------------------------------------------------------------------------------------
CLIP_DICT = dict(rect=(5, 2, 40, 30), fan=dict(angles_deg=(-30, 30), origin_px=(25, -10), radius_px=(15, 45)))


def test_frame_clip_keywords_repr_and_the_dict_users_pass():
    c = sonoslice.FrameClip(x=5, y=2, width=40, height=30, fan_angles_deg=(-30, 30), fan_origin_px=(25, -10),
                            fan_radius_px=(15, 45))
    assert (c.x, c.y, c.width, c.height, c.fan) == (5, 2, 40, 30, True)
    assert (c.fan_angles_deg, c.fan_origin_px, c.fan_radius_px) == ((-30, 30), (25, -10), (15, 45))
    assert repr(c) == ("FrameClip(x=5, y=2, width=40, height=30, fan_angles_deg=(-30.0, 30.0), "
                       "fan_origin_px=(25.0, -10.0), fan_radius_px=(15.0, 45.0))")
    assert eval(repr(c), {"FrameClip": sonoslice.FrameClip}) == c
    assert repr(sonoslice.FrameClip()) == "FrameClip()" and not sonoslice.FrameClip().fan
    mask = sonoslice.clip_mask(CLIP_DICT, (40, 50))
    assert 0 < mask.sum() < mask.size // 2
    assert np.array_equal(sonoslice.clip_mask(c, (40, 50)), mask)
    assert np.array_equal(c.mask(50, 40), mask)
    # None in a dict's rect: to the frame's edge, as width/height -1.
    assert sonoslice.clip_mask(dict(rect=(3, 1, None, None)), (4, 6)).sum() == 3 * 3
    assert np.array_equal(sonoslice.clip_mask(dict(rect=(3, 1, None, None)), (4, 6)),
                          sonoslice.FrameClip(x=3, y=1).mask(6, 4))
    # A Compounder takes the object and the dict alike.
    frames = np.random.default_rng(1).uniform(1, 255, (4, 40, 50)).astype(np.uint8)
    mats = np.stack([np.eye(4) for _ in range(4)])
    mats[:, 2, 3] = np.arange(4)
    volumes = [sonoslice.Compounder(shape=(4, 40, 50), spacing=1.0, clip=clip).add(frames, mats).volume().array
               for clip in (CLIP_DICT, c)]
    assert volumes[0].tobytes() == volumes[1].tobytes()
    assert (volumes[0][0] > 0).sum() == mask.sum()


def test_frame_clip_masks():
    m = np.zeros((2, 3), bool)
    m[0, 1:] = True
    c = sonoslice.FrameClip(mask=m)
    assert repr(c) == "FrameClip(mask: 2 of 6 pixels go in)" and c.mask_pixels == 6
    assert np.array_equal(c.mask(3, 2), m.astype(np.uint8))
    assert np.array_equal(sonoslice.clip_mask(m, (2, 3)), m.astype(np.uint8))
    with pytest.raises(ValueError, match=r"add: the clip mask has 6 pixels but frames have 3x3"):
        sonoslice.Compounder(shape=(2, 2, 2), spacing=1.0).add(np.ones((3, 3), np.uint8), np.eye(4), clip=c)


@pytest.mark.parametrize("kwargs, message", [
    (dict(x=-1), "clip rectangle x, y = -1, 0 must not be negative"),
    (dict(height=-3), "clip rectangle width x height = -1x-3 is negative"),
    (dict(fan_angles_deg=(-95, 30)), r"fan angles \(fan_angles_deg\) must be strictly between -90 and 90"),
    (dict(fan_angles_deg=(30, -30)), r"fan angles \(fan_angles_deg\) must be given smallest first"),
    (dict(fan_angles_deg=(-30, 30), fan_origin_px=(math.nan, 0)), r"fan origin \(fan_origin_px\) must be finite"),
    (dict(fan_angles_deg=(-30, 30), fan_radius_px=(10, 5)), r"fan radii \(fan_radius_px\) must satisfy"),
    (dict(fan_origin_px=(1, 2)), "a fan needs fan_angles_deg"),
    (dict(x=1, mask=np.ones((2, 2), np.uint8)), "give a mask or a rectangle/fan, not both"),
    (dict(mask=np.ones((0, 2), np.uint8)), "the mask is empty"),
])
def test_frame_clip_is_checked_when_built_naming_the_field(kwargs, message):
    with pytest.raises(ValueError, match="^FrameClip: " + message):
        sonoslice.FrameClip(**kwargs)


def test_clip_dicts_are_checked_by_the_same_validate():
    with pytest.raises(ValueError, match="FrameClip: clip rectangle x, y = 0, -2 must not be negative"):
        sonoslice.clip_mask(dict(rect=(0, -2, 3, 3)), (4, 4))
    with pytest.raises(ValueError, match=r"FrameClip: fan radii \(fan_radius_px\)"):
        sonoslice.Compounder(shape=(2, 2, 2), spacing=1.0, clip=dict(fan=dict(angles_deg=(-1, 1), radius_px=(3, 1))))


# ---- VolumeGrid --------------------------------------------------------------------------------------
def test_volume_grid_keywords_repr_and_the_python_grid():
    grid = sonoslice.Grid((4, 6, 8), (0.5, 0.25, 2.0), (10.0, 20.0, 30.0))
    g = grid._to_ext()
    assert (g.dims, g.spacing, g.origin, g.voxel_count) == ((8, 6, 4), (0.5, 0.25, 2.0), (10.0, 20.0, 30.0), 192)
    assert g == ext.VolumeGrid(dims=(8, 6, 4), spacing=(0.5, 0.25, 2.0), origin=(10, 20, 30))
    assert repr(g) == "VolumeGrid(dims=(8, 6, 4), spacing=(0.5, 0.25, 2.0), origin=(10.0, 20.0, 30.0))"
    assert sonoslice.Grid.of(g) == grid
    swap = ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    rotated = ext.VolumeGrid(dims=(2, 3, 4), spacing=(1, 2, 3), direction=swap)
    assert rotated.direction == swap and repr(rotated).endswith(
        "direction=((0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))")
    assert np.allclose(rotated.index_to_world((1, 1, 1)), sonoslice.Grid.of(rotated).index_to_world((1, 1, 1)))
    assert np.allclose(rotated.index_to_world((1, 1, 1)), (2, 1, 3))
    # The Compounder's grid and a volume's grid are the same class.
    c = sonoslice.Compounder(grid)
    assert c.grid == grid and c._cpp.grid == g and c.volume()._cpp.grid == g


@pytest.mark.parametrize("kwargs, message", [
    (dict(dims=(2, 0, 2)), r"size along axis 1 is 0 \(must be > 0\)"),
    (dict(dims=(2, 2, 2), spacing=(1, 1, -1)), "spacing along axis 2 is -1 mm"),
    (dict(dims=(2, 2, 2), origin=(0, math.nan, 0)), "origin is not finite"),
    (dict(dims=(2, 2, 2), direction=((1, 0, 0), (1, 0, 0), (0, 0, 1))), "direction matrix is singular"),
])
def test_volume_grid_is_checked_when_built_naming_the_field(kwargs, message):
    with pytest.raises(ValueError, match="^VolumeGrid: " + message):
        ext.VolumeGrid(**kwargs)


# ---- one keyword: interpolation= -------------------------------------------------------------------
def test_interp_is_a_deprecated_spelling_of_interpolation(phantom, poses):
    ct, _ = phantom
    probe = small_probe()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no DeprecationWarning with the new keyword
        new = sonoslice.Slicer(ct, probe, interpolation="nearest")
        positional = sonoslice.Slicer(ct, probe, "cpu", "nearest")
    assert new.interpolation == positional.interpolation == "nearest" and "nearest" in repr(new)
    with pytest.warns(DeprecationWarning, match="Slicer: interp= is deprecated; use interpolation=") as record:
        old = sonoslice.Slicer(ct, probe, interp="nearest")
    assert len(record) == 1 and record[0].filename == __file__  # it points at the caller's line
    assert old.interpolation == "nearest"
    nearest = new.slice(poses)
    assert np.array_equal(old.slice(poses), nearest)
    assert not np.array_equal(sonoslice.Slicer(ct, probe).slice(poses), nearest)  # linear: the keyword counts
    with pytest.raises(TypeError, match="give interpolation= .* not both"):
        sonoslice.Slicer(ct, probe, interpolation="nearest", interp="linear")


def test_slicing_and_compounding_take_the_same_keyword(phantom):
    ct, _ = phantom
    s = ext.Slicer(ct._cpp, small_probe()._cpp, interpolation="nearest")
    settings = ext.CompoundSettings(interpolation="nearest")
    assert s.interpolation == settings.interpolation == "nearest"
    assert sonoslice.Compounder(shape=(2, 2, 2), spacing=1.0, interpolation="nearest").interpolation == "nearest"


def test_the_fanslicer_shim_uses_no_deprecated_keyword(shared):
    cfg = os.path.join(shared, "models_binary_LUS_config.json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        voxel = fanslicer.SegmentedVolume(shared, cfg, image_num=1, downsampling=4, voxel_size=2.0, device="cpu")
    assert voxel.slicer.interpolation == "nearest"
